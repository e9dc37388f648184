"""The seed paper's comparison tables as presets over the methods other plugins declare."""
