"""gamd package."""
