"""Weights: checkpoints with identity, loaded, checked, applied and imported from other code bases (`checkpoints`)."""
