"""CoFiI2P (Kang, Liao et al., IEEE RA-L 2024) as i2pbench plugins: a two-stream encoder-decoder (ResNet-34 image
branch, KPConv-FPN point branch), a coarse transformer matching super-points to super-pixels, fine matching of points
to pixels inside the matched 4 x 4 patches, and EPnP-RANSAC."""
