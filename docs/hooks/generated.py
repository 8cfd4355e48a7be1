"""MkDocs hook: the reference pages' tables come from the code, not from copies of it.

A page asks for generated content with an HTML comment on a line of its own:

- ``<!-- generated: api vogjax.maps -->``: the package's docstring, then one mkdocstrings entry
  per name of its ``__all__``, from the module that defines it (names a package imports on
  first use resolve too), and its constants with their values;
- ``<!-- generated: cli -->``: every subcommand's ``--help``, from ``vogjax.cli.build_parser()``;
- ``<!-- generated: settings JobConfig -->`` / ``settings ExploreConfig``: one table per settings
  table of a settings file, from the rules in ``vogjax/config`` and the classes' docstrings;
- ``<!-- generated: report-json -->``: the fields of report.json, from ``vogjax.report.fields``;
- ``<!-- generated: results -->``: the files under benchmarks/results with the commit and date
  each was last recorded at (from git, when the checkout has its history).

It also copies the package, laid out as installed (``kernels/`` as ``vogjax/kernels``, ``scenes/`` as
``vogjax/scenes``) under ``.cache/docs_src`` for mkdocstrings, which reads sources statically.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import os
import re
import shutil
import subprocess
from contextlib import redirect_stdout
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MARKER = re.compile(r"^<!-- generated: ([\w-]+)(?: ([\w.]+))? -->$", re.M)


def on_startup(command, dirty):
    # before any plugin's on_config: mkdocstrings drops search paths that do not exist yet, so a
    # fresh clone would resolve vogjax to the checkout's folder, which has no kernels/ or scenes/.
    # A copy, not links: griffe resolves links and would find the checkout's layout again.
    source = ROOT / ".cache" / "docs_src" / "vogjax"
    shutil.rmtree(source, ignore_errors=True)
    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "vogjax", source, ignore=skip)
    for package in ("kernels", "scenes"):
        shutil.copytree(ROOT / package, source / package, ignore=skip)


def on_files(files, config):
    # the benchmarks' plots stay where the scripts write them; the site serves them from there
    from mkdocs.structure.files import File

    for plot in sorted((ROOT / "benchmarks" / "results").glob("*.png")):
        files.append(
            File(f"benchmarks/results/{plot.name}", str(ROOT), config["site_dir"], config["use_directory_urls"])
        )
    return files


def on_page_markdown(markdown, page, config, files):
    def expand(match: re.Match) -> str:
        kind, argument = match.group(1), match.group(2)
        if kind == "cli":
            return cli_reference()
        if kind == "api":
            return api_reference(argument)
        if kind == "settings":
            return settings_reference(argument)
        if kind == "report-json":
            return report_reference()
        if kind == "results":
            return results_reference()
        raise ValueError(f"{page.file.src_path}: unknown generated block {kind!r}")

    return MARKER.sub(expand, markdown)


def api_reference(package: str) -> str:
    import importlib
    import inspect

    module = importlib.import_module(package)
    parts = [f"::: {package}\n    options:\n      members: false\n      show_root_heading: false\n"]
    constants, elsewhere = [], []
    names = getattr(module, "__all__", None)
    if names is None:  # a module without __all__: what it defines without a leading underscore
        names = [
            n
            for n, o in vars(module).items()
            if not n.startswith("_") and getattr(o, "__module__", None) == package and callable(o)
        ]
    for name in names:
        obj = getattr(module, name)
        if inspect.ismodule(obj):
            # a kernel module is documented by its docstring; any other module with its members
            members = "false" if package == "vogjax.kernels" else "true"
            parts.append(f"::: {obj.__name__}\n    options:\n      members: {members}\n      heading_level: 2\n")
        elif (inspect.isclass(obj) or inspect.isfunction(obj)) and documented_at_home(obj, package):
            # re-exported: documented once, on the page of the package that defines it
            elsewhere.append(f"[`{name}`][{obj.__module__}.{obj.__qualname__}]")
        elif inspect.isclass(obj) or inspect.isfunction(obj):
            parts.append(f"::: {obj.__module__}.{obj.__qualname__}\n")
        else:
            constants.append(f"| `{name}` | `{obj!r}` |")
    if elsewhere:
        parts.insert(1, "Also here, documented where they are defined: " + ", ".join(elsewhere) + ".\n")
    if constants:
        parts.append("## Constants\n\n| name | value |\n| --- | --- |\n" + "\n".join(constants) + "\n")
    return "\n".join(parts)


def documented_at_home(obj, package: str) -> bool:
    """Whether `obj`, listed by `package`, belongs on another package's page: the subpackage
    that defines it lists it too."""
    import importlib

    home = ".".join(obj.__module__.split(".")[:2])
    if home == package or home == "vogjax":
        return False
    return obj.__name__ in getattr(importlib.import_module(home), "__all__", ())


def cli_reference() -> str:
    from vogjax import cli

    parser = cli.build_parser()
    subcommands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    parts = ["## vogjax\n", fence(help_text(parser))]
    for name, sub in subcommands.choices.items():
        parts += [f"## vogjax {name}\n", fence(help_text(sub))]
    return "\n".join(parts)


def help_text(parser: argparse.ArgumentParser) -> str:
    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal; pages get one fixed width
    try:
        with redirect_stdout(io.StringIO()) as out:
            parser.print_help()
    finally:
        if previous is None:
            os.environ.pop("COLUMNS")
        else:
            os.environ["COLUMNS"] = previous
    return out.getvalue()


def fence(text: str) -> str:
    return f"```text\n{text.rstrip()}\n```\n"


def settings_reference(class_name: str) -> str:
    from vogjax import config as settings
    from vogjax.config import planner
    from vogjax.config.schema import rule_of
    from vogjax.config.settings_file import unit_of

    cls = getattr(settings, class_name, None) or getattr(planner, class_name)
    parts = []
    for table, instance in settings_tables(cls()):
        rows = ["| setting | default | accepted | unit | meaning |", "| --- | --- | --- | --- | --- |"]
        docs = field_docs(type(instance))
        for field in dataclasses.fields(instance):
            rule = rule_of(field)
            if rule.kind == "section":
                continue
            default = getattr(instance, field.name)
            shown = rule.none_spelled if default is None and rule.none_spelled else default
            accepted = rule.describe()
            if rule.none_spelled:  # TOML has no None: the file spells it
                accepted = accepted.replace("None", f'"{rule.none_spelled}"')
            unit = unit_of(field).removeprefix("in ")
            rows.append(
                f"| `{field.name}` | `{toml_value(shown)}` | {accepted} | {unit} | {docs.get(field.name, '')} |"
            )
        parts.append(f"### `[{table}]`\n\n`{type(instance).__name__}`\n\n" + "\n".join(rows) + "\n")
    return "\n".join(parts)


def settings_tables(config):
    """(table name, Config) for each table a settings file of `config`'s class takes, in the
    order `Config.tables()` gives the top-level ones; sections nested in a table follow it as
    ``table.section``."""
    from vogjax.config.schema import rule_of

    def nested(table: str, inner):
        yield table, inner
        for field in dataclasses.fields(inner):
            if rule_of(field).kind == "section":
                yield from nested(f"{table}.{field.name}", getattr(inner, field.name))

    for table, path in type(config).tables().items():
        inner = config
        for name in path:
            inner = getattr(inner, name) if name else inner
        if path[-1] == "":  # a flattened section's own settings
            yield table, inner
        else:
            yield from nested(table, inner)


def field_docs(cls) -> dict[str, str]:
    """Each field's description from the class's numpydoc ``Parameters`` section."""
    import griffe

    docstring = griffe.Docstring(cls.__doc__ or "", parser="numpy")
    out = {}
    for section in docstring.parse(warnings=False):
        if section.kind.value in ("parameters", "attributes"):
            for item in section.value:
                out[item.name] = " ".join(item.description.split())
    return out


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def report_reference() -> str:
    from vogjax.report.fields import FIELDS

    rows = ["| field | meaning |", "| --- | --- |"]
    rows += [f"| `{path}` | {text} |" for path, text in FIELDS.items()]
    return "\n".join(rows) + "\n"


def results_reference() -> str:
    rows = ["| file | last recorded at | date |", "| --- | --- | --- |"]
    for path in sorted((ROOT / "benchmarks" / "results").iterdir()):
        commit, date = last_commit(path)
        rows.append(f"| `{path.relative_to(ROOT)}` | `{commit}` | {date} |")
    return "\n".join(rows) + "\n"


def last_commit(path: Path) -> tuple[str, str]:
    try:
        out = subprocess.run(
            ["git", "log", "-1", "--format=%h %ad", "--date=short", "--", str(path)],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split()
    except (OSError, subprocess.CalledProcessError):
        out = []
    return (out[0], out[1]) if len(out) == 2 else ("(no git history)", "")
