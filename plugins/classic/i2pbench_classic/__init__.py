"""i2pbench reference plugins: classic."""
