"""One module per `i2pbench` subcommand, each with `add_parser(sub)` and `run(args) -> int`; and the commands as Python
calls: `calls` (`i2pbench.run(...)` through the same parser) and `results` (the typed tables they return)."""
