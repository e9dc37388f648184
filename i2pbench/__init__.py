"""i2pbench: a plugin-based benchmark for image-to-LiDAR registration."""

__version__ = "0.1.0"
