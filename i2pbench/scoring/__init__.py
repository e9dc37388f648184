"""Protocol cards (each paper's inputs and scoring rules, named and versioned) and scoring under them.

`rules` scores per-frame poses under one card's rules; `cards` declares the cards; `installed` finds them by name
(built-in and plugin ones, `register_protocols`) and scores records under a run's card; `table` re-scores a finished
run under every card's rules; `recall` gives registration recall at thresholds, error percentiles and the per-sequence
breakdown.
"""
