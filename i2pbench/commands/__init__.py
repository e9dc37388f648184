"""One module per `i2pbench` subcommand, each with `add_parser(sub)` and `run(args) -> int`."""
