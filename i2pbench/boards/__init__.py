"""Boards: the tables made from a run's per-frame records, and what compares them.

- `leaderboard`: one row per combination, weights and split, aggregated by the installed metrics; CSV, Markdown and
  Parquet writers; `out_stem`: what `--out STEM` names;
- `uncertainty`: a board's 95% interval columns and per-frame values, and the paired comparison of two rows;
  `stats`: the intervals and tests themselves (Wilson, bootstrap, McNemar); `crossval`: intervals that resample
  whole scenes;
- `regression_gate`: a new board against a committed baseline under per-metric tolerances (`i2pbench compare`);
- `paper_table`: a preset's rows down, one column group per dataset across (`i2pbench table`).
"""
