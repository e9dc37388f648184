"""Entry point of the classic plugins."""
