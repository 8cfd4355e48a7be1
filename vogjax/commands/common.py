"""What every `vogjax` subcommand shares: the help layout, `--verbose`/`--quiet`, argument
types that check a value against a settings rule (so a bad value is refused by argparse,
naming the flag the user typed), the refusal of an existing output without `--overwrite`,
and the help text of `--config`."""

from __future__ import annotations

import argparse
from pathlib import Path

from vogjax.config.schema import Rule


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs as written (paragraphs, example blocks), and each option's
    default after its help: ArgumentDefaultsHelpFormatter's "(default: X)", except where the
    help already says it, where there is none (None, a flag's False) or where it is implied."""

    def _format_action(self, action: argparse.Action) -> str:
        if isinstance(action, argparse._SubParsersAction):  # the commands, without a "command" line above
            return "".join(self._format_action(command) for command in action._get_subactions())
        return super()._format_action(action)

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        unset = action.default is None or action.default is False or action.default is argparse.SUPPRESS
        said = "(default" in text or "default:" in text
        if said or unset or action.required:  # (`is`: a default of 0 is shown)
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return f"{text} (default: %(default)s)"
        return text


def add_output_flags(parser: argparse.ArgumentParser) -> None:
    """`-v/--verbose` and `-q/--quiet`, the same on every subcommand (they exclude each other).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The subcommand's parser.
    """
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="also show what the libraries print (Warp's start-up messages, JAX's warnings), on stderr",
    )
    group.add_argument("-q", "--quiet", action="store_true", help="no progress bars or notes: results and errors only")


def ruled(kind: str, low: float | None = None, high: float | None = None, low_open: bool = False):
    """An argparse `type` that converts a string to an int ("integer") or float ("number") and
    checks it against a settings `Rule`, so a bad value reads "argument --scans: must be ...".

    Parameters
    ----------
    kind : str
        "integer" or "number".
    low, high : float or None
        Bounds (None: none), included unless `low_open`.
    low_open : bool
        Whether `low` itself is excluded.

    Returns
    -------
    callable
        str -> int or float; raises argparse.ArgumentTypeError.
    """
    rule = Rule(kind, low, high, low_open=low_open)
    convert = int if kind == "integer" else float

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule.describe()}, got {text!r}") from None
        if not rule.accepts(value):
            raise argparse.ArgumentTypeError(f"must be {rule.describe()}, got {text!r}")
        return value

    parse.__name__ = "integer" if kind == "integer" else "number"  # argparse names it in its own errors
    return parse


def refuse_existing(path: Path, overwrite: bool, flag: str = "--out", folder: bool = False) -> None:
    """A ValueError naming `flag` when `path` is the wrong kind of thing (a folder where a file
    goes, or the other way round), or exists and `overwrite` is not given (naming --overwrite).

    Parameters
    ----------
    path : Path
        The output the command would write.
    overwrite : bool
        Whether the user passed --overwrite.
    flag : str
        The flag that named `path`.
    folder : bool
        Whether the output is a folder (else a file).

    Raises
    ------
    ValueError
        When `path` exists and cannot or may not be replaced.
    """
    if path.exists() and path.is_dir() != folder:
        kind, wanted = ("a folder", "a file") if path.is_dir() else ("a file", "a folder")
        raise ValueError(f"{flag} {str(path)!r} is {kind}; {wanted} goes there")
    if path.exists() and not overwrite:
        raise ValueError(f"{flag} {str(path)!r} exists (pass --overwrite to replace it)")


def refuse_replacing_input(out: Path, source: Path, what: str) -> None:
    """Refuse an `out` that names the input `source` (the same path, a link or a hard link to
    it): it would be replaced before, or while, it is read."""
    try:
        same = out.samefile(source)
    except OSError:  # no `out` yet, or no source (its reader names that)
        same = False
    if same:
        raise ValueError(f"--out {str(out)!r} is the {what}; write it to another file")


def config_help(tables: str) -> str:
    """The help of a subcommand's `--config`: the tables it reads and where to get a full file.

    Parameters
    ----------
    tables : str
        The tables the command reads, e.g. "[map], [pipeline]".

    Returns
    -------
    str
        The help text.
    """
    return (
        f"TOML settings file: tables {tables}; every setting left out keeps its default "
        "(`vogjax config --defaults` prints them all, `vogjax config --check FILE` checks one)"
    )
