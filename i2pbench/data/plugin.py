"""Entry point registering the built-in datasets."""
