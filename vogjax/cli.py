"""The `vogjax` command: one subcommand per module of `vogjax.commands`."""

from __future__ import annotations

import argparse
import importlib
import sys

# command name -> module in vogjax.commands
COMMANDS = {
    "simulate": "simulation",
    "map": "mapping",
    "demo": "demo",
    "export": "export",
    "import": "importing",
    "view": "view",
    "explore": "explore",
}


def build_parser() -> argparse.ArgumentParser:
    """The `vogjax` parser with every subcommand (the CLI reference is generated from it)."""
    parser = argparse.ArgumentParser(prog="vogjax", description="GPU/JAX occupancy mapping")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS.values():
        importlib.import_module(f"vogjax.commands.{module}").add_parser(subparsers)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    modules = {name: importlib.import_module(f"vogjax.commands.{module}") for name, module in COMMANDS.items()}
    try:
        modules[args.command].run(args)
    except ValueError as error:
        print(f"vogjax {args.command}: error: {str(error).replace(chr(10), ' ')}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:  # Ctrl-C: outputs are published whole or not at all, so nothing to clean up
        print(f"vogjax {args.command}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except OSError as error:  # what the early checks cannot foresee: a full disk, a read-only mount
        where = f"{error.filename!r}: " if error.filename else ""
        print(f"vogjax {args.command}: error: {where}{error.strerror or error}", file=sys.stderr)
        raise SystemExit(2) from None
    return 0


if __name__ == "__main__":
    sys.exit(main())
