"""CoFiI2P as its authors' code computes it (WHU-USI3DV/CoFiI2P@ed90edf: model/network.py, model/imagenet.py,
model/kpconv/, model/transformer/, model/loss.py), written from that code in this package's own structure: the
image branch (image.py), the KPConv-FPN point branch (points.py, on i2pbench.layers.kpconv), the coarse transformer
and position encodings (transformer.py), the network with its coarse selection (network.py) and train.py's losses
(loss.py). docs/methods.md ("CoFiI2P: paper vs authors' code vs i2pbench") lists every difference kept."""
