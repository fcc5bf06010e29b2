"""Subcommands of the blurtrack CLI (one module each, see blurtrack.cli)."""
