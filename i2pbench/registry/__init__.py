"""The registry: every component, dataset, corruption, preset, method, protocol card, metric and shipped checkpoint
the plugins of the `i2pbench` entry-point group register (docs/hooks.md).

- `hookspecs`: the hooks a plugin implements;
- `entry_points`: the group's entry points, found once per change of the installed distributions;
- `loading`: the plugins loaded into pluggy, as the environment variables select them;
- `table`: one generic `Table[T]` (names, owners, aliases, clashes, suggestions); `catalog`: `Registry`, one table
  per kind; `lazy`: classes registered by import path;
- `build`: `build_registry` / `default_registry`, one plugin at a time, all or nothing;
- `methods`: a learned method declared once; `listing`: what `i2pbench plugins` shows of each plugin.
"""
