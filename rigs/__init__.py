"""rigs package."""
