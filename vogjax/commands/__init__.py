"""The `vogjax` subcommands, one module each: `add_parser(subparsers)` declares its arguments
(cheaply: heavy imports wait for `run`), `run(args)` does the work and prints results to stdout.
A ValueError from `run` becomes a one-line error and exit status 2."""
