"""blurtrack package."""
