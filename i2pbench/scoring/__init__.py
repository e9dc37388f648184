"""What a result is scored by: pose errors, metrics, protocol cards and their scoring rules, side by side.

- `pose`: RTE, RRE (the peers' 'xzy' Euler sum) and the geodesic angle of one estimate; success and the filter a
  board averages over, under a protocol;
- `metrics`: the `Metric` declarations, the built-in ones (`BUILTIN`) and the check of a plugin's;
- `rules`: one paper's scoring rules (`ScoringRules`); `cards`: the protocol cards declaring them;
- `score`: per-frame poses scored under a card's rules, and the one `summarize`;
- `installed`: the metrics and cards in force (built-ins, then the plugins'), records scored under a run's card;
- `protocol`: the test protocol (T_rand, the cards' seeded draws); `protocol_inputs` and `protocol_peer`: what a
  card's stages are given, and a peer card's frame built as the peers' loaders build it;
- `table`: a finished run re-scored under every card's rules; `recall`: registration recall at thresholds, error
  percentiles and the per-sequence breakdown.
"""
