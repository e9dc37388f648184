"""An example third-party i2pbench plugin: `harris` image corners and `curvature` LiDAR points."""
