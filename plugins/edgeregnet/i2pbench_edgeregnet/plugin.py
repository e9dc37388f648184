"""Entry point of the edgeregnet plugins."""
