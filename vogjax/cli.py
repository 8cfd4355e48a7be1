"""The `vogjax` command: one subcommand per module of `vogjax.commands`.

`build_parser()` returns the whole parser (every subcommand, its help and examples) without
running anything, for the command itself and for the generated CLI reference. Every error a
user can make is one line on stderr naming the flag or file, and exit status 2: argparse's
own errors too (unknown flags with a close match, bad values, missing arguments), which it
would otherwise print after the whole usage.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import importlib
import logging
import os
import re
import sys
import tempfile
import warnings

from vogjax.commands.common import HelpFormatter

# command name -> module in vogjax.commands
COMMANDS = {
    "simulate": "simulation",
    "map": "mapping",
    "demo": "demo",
    "export": "export",
    "import": "importing",
    "view": "view",
    "explore": "explore",
    "config": "settings",
}
# commands that run Warp: started before the command, so its start-up messages come first
WARP_COMMANDS = ("simulate", "map", "demo", "export", "import", "view", "explore")
# what Warp's native library prints to stderr when there is no NVIDIA driver (CPU-only machines)
CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"

DESCRIPTION = """\
GPU/JAX-accelerated batch occupancy mapping for robots whose poses get corrected by pose-graph
SLAM: local submaps anchored to the graph's nodes, one global map kept consistent after loop
closures (Sodhi et al.), the virtual map (Ho et al.), a confidence-rich map, a next-best-view
planner and a simulated underwater vehicle with a profiling sonar to make datasets.

Results go to stdout; progress bars, notes and errors to stderr. A user error is one line
naming the flag or file, with exit status 2."""

EPILOG = """\
examples:
  vogjax simulate --scene boxes --scans 600 --out boxes.h5
  vogjax map boxes.h5 --out maps
  vogjax config --defaults > settings.toml
  vogjax <command> --help"""

_NEGATIVE_NUMBER = re.compile(r"^-\d+$|^-\d*\.\d+$")  # what argparse takes for a value, not a flag


def version() -> str:
    """The installed vogjax's version, from its package metadata (pyproject.toml).

    Returns
    -------
    str
        `vogjax.__version__` ("0+unknown" when vogjax runs from a folder without being installed).
    """
    import vogjax

    return vogjax.__version__


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (`vogjax CMD: error: ...`, exit 2) that name
    the flag: an unknown flag is reported as unknown, with the closest known one suggested,
    even where argparse would first complain of a missing required one (`--outt` for `--out`);
    an invalid choice gets the closest choice suggested."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self._arguments: list[str] = []

    def parse_known_args(self, args=None, namespace=None):
        """As argparse's, remembering the arguments for the error messages."""
        self._arguments = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(args, namespace)

    def parse_args(self, args=None, namespace=None) -> argparse.Namespace:
        """As argparse's, with an argument nobody takes reported by the subcommand it was
        given to: an unknown flag as unknown (with the closest known one), anything else as
        unexpected.

        Parameters
        ----------
        args : list of str or None
            The arguments (None: the process's).
        namespace : argparse.Namespace or None
            Where to put the values.

        Returns
        -------
        argparse.Namespace
            The parsed arguments.
        """
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            command = getattr(namespace, "command", None)
            parser = _subparser(self, command) if command else self
            flags = [e for e in extras if e.startswith("-") and not _NEGATIVE_NUMBER.match(e)]
            if flags:
                parser.error(parser.unknown_message(flags[0].split("=", 1)[0]))
            parser.error(f"unexpected argument {extras[0]!r} ({parser.prog} --help lists the arguments)")
        return namespace

    def error(self, message: str):
        """Print one line naming what is wrong and exit with status 2 (never returns).

        Parameters
        ----------
        message : str
            argparse's message.
        """
        unknown = self.unknown_flags(self._arguments)
        if unknown and ("required" in message or "expected" in message or "unrecognized" in message):
            message = self.unknown_message(unknown[0])
        elif message.startswith("the following arguments are required: command"):
            message = f"no command given: one of {', '.join(COMMANDS)} ({self.prog} --help describes them)"
        else:
            message = self._suggest_choice(message)
        self.exit(2, f"{self.prog}: error: {message}\n")

    def unknown_flags(self, arguments: list[str]) -> list[str]:
        """The flags among `arguments` this parser does not know (as typed, before any `=`).

        Parameters
        ----------
        arguments : list of str
            Command-line arguments given to this parser.

        Returns
        -------
        list of str
            Unknown flags in the order given; values (negative numbers, anything after `--`)
            and unique prefixes of known flags, which argparse accepts, are not among them.
        """
        known = set(self._option_string_actions)
        commands = {
            name
            for action in self._actions
            if isinstance(action, argparse._SubParsersAction)
            for name in action.choices
        }
        unknown = []
        for argument in arguments:
            if argument == "--" or argument in commands:  # a subcommand's flags are its own
                break
            if not argument.startswith("-") or argument == "-" or _NEGATIVE_NUMBER.match(argument):
                continue
            name = argument.split("=", 1)[0]
            if name in known:
                continue
            if not name.startswith("--") and name[:2] in known:  # -qv: short flags run together
                continue
            if name.startswith("--") and self.allow_abbrev and any(k.startswith(name) for k in known):
                continue
            unknown.append(name)
        return unknown

    def unknown_message(self, flag: str) -> str:
        """ "unknown flag --outt (did you mean --out?)", or the help to read when nothing is close.

        Parameters
        ----------
        flag : str
            The unknown flag as typed.

        Returns
        -------
        str
            The message.
        """
        flags = sorted(k for k in self._option_string_actions if k.startswith("--"))
        close = difflib.get_close_matches(flag, flags, n=1, cutoff=0.6)
        hint = f"did you mean {close[0]}?" if close else f"{self.prog} --help lists the flags"
        return f"unknown flag {flag} ({hint})"

    def _suggest_choice(self, message: str) -> str:
        match = re.match(
            r"argument (?P<flag>[^:]+): invalid choice: (?P<value>'.*?'|\".*?\") \(choose from (?P<choices>.*)\)$",
            message,
        )
        if not match:
            return message
        choices = [c.strip().strip("'\"") for c in match["choices"].split(",")]
        value = match["value"][1:-1]
        close = difflib.get_close_matches(value, choices, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]}?" if close else ""
        if match["flag"] == "command":
            return f"unknown command {value!r} (one of {', '.join(choices)}{hint})"
        return f"argument {match['flag']}: invalid choice {value!r} (choose from {', '.join(choices)}{hint})"


def build_parser() -> argparse.ArgumentParser:
    """The `vogjax` parser with every subcommand, its help, defaults and examples.

    Importing and calling this runs nothing: the subcommands import their heavy modules only
    when they run.

    Returns
    -------
    argparse.ArgumentParser
        The parser; `parse_args` gives a namespace whose `command` names the subcommand.
    """
    parser = Parser(prog="vogjax", description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action="version", version=f"vogjax {version()}", help="print the version and exit")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="command", title="commands")
    for module in COMMANDS.values():
        importlib.import_module(f"vogjax.commands.{module}").add_parser(subparsers)
    return parser


def _subparser(parser: argparse.ArgumentParser, name: str) -> Parser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[name]
    raise KeyError(name)


@contextlib.contextmanager
def _native_stderr(keep: bool):
    """Collect what native libraries write to file descriptor 2 within the block (a list of
    lines, filled on exit); with `keep`, let it through instead."""
    lines: list[str] = []
    if keep:
        yield lines
        return
    sys.stderr.flush()
    with tempfile.TemporaryFile() as sink:
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines += sink.read().decode(errors="replace").splitlines()


def start_libraries(verbose: bool) -> None:
    """Start Warp (and quiet JAX's logging) before the command's first progress bar.

    Warp's native start-up prints "could not find the CUDA driver" on a machine without an
    NVIDIA driver: with `verbose` it is printed, once, on its own line, before anything else;
    without, that line is dropped (a run's report and `vogjax map`'s table name the device)
    and any other native message is passed on.

    Parameters
    ----------
    verbose : bool
        Whether the user asked for the libraries' messages (`--verbose`).
    """
    from vogjax import devices

    if not verbose:
        for name in ("jax", "jax._src.xla_bridge", "absl"):
            logging.getLogger(name).setLevel(logging.ERROR)
    if devices.init.cache_info().currsize:  # started already (an earlier command in this process)
        return
    with _native_stderr(keep=verbose) as lines:
        devices.init()
    for line in lines:
        if line.strip() and CUDA_DRIVER_WARNING not in line:
            print(line, file=sys.stderr)


@contextlib.contextmanager
def _warnings_as_lines(command: str, verbose: bool):
    """Python warnings as the command's other notes: one line on stderr (`vogjax CMD: warning:
    ...`), each message once; the libraries' own (JAX's, Matplotlib's) only with --verbose."""
    package = os.path.dirname(os.path.abspath(__file__))
    seen: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        path = os.path.abspath(filename)
        ours = path.startswith(package + os.sep)
        library = not ours and ("site-packages" in path or "dist-packages" in path or path.startswith(sys.base_prefix))
        text = " ".join(str(message).split())
        if (verbose or not library) and text not in seen:
            seen.add(text)
            print(f"vogjax {command}: warning: {text}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("always")  # each message once, by `seen`, not once per line of code
        if not verbose:  # what a developer acts on, not a user (Python hides these by default too)
            warnings.simplefilter("ignore", DeprecationWarning)
            warnings.simplefilter("ignore", PendingDeprecationWarning)
        warnings.showwarning = show
        yield


def main(argv: list[str] | None = None) -> int:
    """Run `vogjax` with `argv` (default: the process's arguments).

    Parameters
    ----------
    argv : list of str or None
        The arguments after the program name.

    Returns
    -------
    int
        0 on success; errors exit with status 2 (SystemExit), Ctrl-C with 130.
    """
    args = build_parser().parse_args(argv)
    module = importlib.import_module(f"vogjax.commands.{COMMANDS[args.command]}")
    try:
        with _warnings_as_lines(args.command, getattr(args, "verbose", False)):
            if args.command in WARP_COMMANDS:
                start_libraries(getattr(args, "verbose", False))
            module.run(args)
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
