"""Diagnostics of data and stages: edge quality under the true pose (`edges`) and the gap between
two datasets (`domain_gap`)."""
