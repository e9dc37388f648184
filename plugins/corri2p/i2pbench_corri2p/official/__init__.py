"""CorrI2P as its authors' code computes it (rsy6318/CorrI2P@4f4a755: network.py, pointnet2.py, layers_pc.py,
imagenet.py), written from that code in this package's own structure: the SO-Net-style point encoder (points.py),
the ResNet-34 image encoder and decoder blocks (image.py), the two-way attention exchange (exchange.py), the heads
(heads.py) and the whole network (network.py). docs/methods.md ("CorrI2P: paper vs authors' code vs i2pbench") lists
every difference kept."""
