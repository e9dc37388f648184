"""CorrI2P (Ren et al., IEEE TCSVT 2023) as i2pbench plugins: dense image and point features, feature exchange,
overlap scores and correspondences by descriptor similarity, trained with a circle loss and an overlap loss."""
