"""Corruptions: the `Corruption` base and its checks (`base`), and the built-in ones (`builtin`)."""
