"""EdgeRegNet as its authors' code computes it (ESRSchao/EdgeRegNet), written from that code in this package's own
structure: the SuperPoint image encoder (superpoint.py), the PointNet++ point encoder (pointnet2.py), the tied
SuperGlue attention (attention.py), the match assignment and loss (matching.py), the import of their checkpoint
(importer.py) and the forward on a reference folder (reference.py): the method's `official` variant.
docs/edgeregnet.md ("paper text vs authors' code vs i2pbench") lists every difference kept."""
