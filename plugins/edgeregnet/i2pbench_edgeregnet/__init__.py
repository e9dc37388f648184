"""i2pbench reference plugins: edgeregnet."""
