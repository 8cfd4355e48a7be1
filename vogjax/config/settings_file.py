"""A settings file written from the rules: every setting of a Config with its value, what it
accepts and its unit, each table headed by its class's description, in TOML that
`Config.from_toml` reads back to the same Config.

    print(settings_toml(JobConfig(), "vogjax map"))

Units come from the settings' names (`_m`, `_s`, `_rad`, ... : the project's unit suffixes)
or a field's `doc` ("in m"); bounds from its Rule.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import textwrap

from vogjax.config.schema import Config, Rule, rule_of

# name suffix -> unit, longest first where one ends another
UNITS = (
    ("_m_per_rad", "m/rad"),
    ("_m2", "m^2"),
    ("_m3", "m^3"),
    ("_rad2", "rad^2"),
    ("_mps", "m/s"),
    ("_rps", "rad/s"),
    ("_hz", "Hz"),
    ("_deg", "degrees"),
    ("_rad", "rad"),
    ("_m", "m"),
    ("_s", "s"),
)
WIDTH = 100


def unit_of(field: dataclasses.Field) -> str:
    """What a setting's line says after the rule: its field's `doc` (e.g. "in m" for a name
    without a unit suffix), else the unit of its name's suffix ("in m/s"), else "".

    Parameters
    ----------
    field : dataclasses.Field
        A setting of a Config.

    Returns
    -------
    str
        E.g. "in m", "in rad/s" or "".
    """
    if field.metadata.get("doc"):
        return field.metadata["doc"]
    return next((f"in {unit}" for suffix, unit in UNITS if field.name.endswith(suffix)), "")


def accepts(rule: Rule) -> str:
    """What a setting accepts, in a settings file's spelling (None as its `none_spelled` word).

    Parameters
    ----------
    rule : Rule
        The setting's rule.

    Returns
    -------
    str
        E.g. 'a positive number', '"covariance" or a positive integer >= 2'.
    """
    words = dataclasses.replace(rule, none_spelled=None).describe()
    for option in rule.options:  # TOML's strings in double quotes
        words = words.replace(repr(option), json.dumps(option))
    return words if rule.none_spelled is None else f"{json.dumps(rule.none_spelled)} or {words}"


def toml_value(rule: Rule, value) -> str:
    """A setting's value as TOML that reads back to the same value.

    Parameters
    ----------
    rule : Rule
        The setting's rule.
    value : bool, int, float, str or None
        The value (None only where the rule spells it).

    Returns
    -------
    str
        The TOML literal.
    """
    if value is None:
        return json.dumps(rule.none_spelled)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if rule.kind == "number":
        return repr(float(value))  # shortest repr: reads back bit for bit
    return str(int(value))


def settings_toml(config: Config, command: str, commented: tuple[str, ...] = (), notes: dict | None = None) -> str:
    """Every setting of `config` as a commented TOML settings file.

    Parameters
    ----------
    config : Config
        The settings to write (a document Config: `JobConfig`, `ExploreConfig`).
    command : str
        The command that reads the file, named in its header (e.g. "vogjax map").
    commented : tuple of str
        Tables whose settings are written as comments (their defaults depend on more than
        the file: the planner's on the scene); the table itself is still there, empty.
    notes : dict or None
        Table name -> a line said under its header (why it is commented, say).

    Returns
    -------
    str
        The file's text; `type(config).from_toml` of it gives `config` back.
    """
    notes = notes or {}
    lines = [
        f"# Settings of `{command}`:",
        "# every setting, with its value, what it accepts and its unit.",
        f"# Pass it back with `{command} --config FILE`; a setting left out keeps its default.",
        "# Check a file with `vogjax config --check FILE`.",
    ]
    for table, owner, nested in _tables(config):
        _table(lines, table, owner, nested, comment=table in commented, note=notes.get(table))
    return "\n".join(lines) + "\n"


def _tables(config: Config):
    """(table name, the Config it sets, whether its sections are its sub-tables) per table."""
    for table, path in type(config).tables().items():
        owner = getattr(config, path[0])
        if len(path) == 2 and path[1]:
            owner = getattr(owner, path[1])
        yield table, owner, path[1:] != ("",)  # a flattened section's sections are tables of their own


def _table(lines: list[str], name: str, config: Config, nested: bool, comment: bool, note: str | None) -> None:
    """[name], its class's description, its plain settings; then (when `nested`) its sections."""
    lines += ["", f"[{name}]"]
    lines += _comment(inspect.cleandoc(type(config).__doc__ or ""))
    if note:
        lines += _comment(note)
    fields = dataclasses.fields(config)
    plain = [f for f in fields if rule_of(f).kind != "section"]
    width = max((len(f.name) + 3 + len(toml_value(rule_of(f), getattr(config, f.name))) for f in plain), default=0)
    for field in plain:
        rule = rule_of(field)
        setting = f"{field.name} = {toml_value(rule, getattr(config, field.name))}"
        unit = unit_of(field)
        about = accepts(rule) + (f", {unit}" if unit else "")
        line = f"{'# ' if comment else ''}{setting.ljust(width)}  # {about}"
        lines.append(line if len(line) <= WIDTH else f"{'# ' if comment else ''}{setting}  # {about}")
    if nested:
        for field in fields:
            if rule_of(field).kind == "section":
                _table(lines, f"{name}.{field.name}", getattr(config, field.name), True, comment, None)


def _comment(text: str) -> list[str]:
    """`text` as comment lines of at most WIDTH columns, paragraphs kept."""
    out = []
    for paragraph in text.split("\n\n"):
        if not paragraph.strip():
            continue
        block = paragraph.splitlines()
        if any(line.startswith((" ", "\t")) or ":  " in line for line in block[1:]):
            out += [f"# {line}".rstrip() for line in block]  # a laid-out list: kept as written
        else:
            out += [f"# {line}" for line in textwrap.wrap(" ".join(block), WIDTH - 2, break_on_hyphens=False)]
    return out


def settings_of(config: Config) -> dict[str, str]:
    """Every setting of a document Config by its place in the settings file, as TOML.

    Parameters
    ----------
    config : Config
        A document Config (`JobConfig`, `ExploreConfig`).

    Returns
    -------
    dict
        "table.key" (e.g. "loop_closure.icp.max_iterations") -> its value as a TOML literal.
    """
    out = {}

    def walk(prefix: str, owner: Config, nested: bool) -> None:
        for field in dataclasses.fields(owner):
            value = getattr(owner, field.name)
            if rule_of(field).kind != "section":
                out[f"{prefix}.{field.name}"] = toml_value(rule_of(field), value)
            elif nested:
                walk(f"{prefix}.{field.name}", value, True)

    for table, owner, nested in _tables(config):
        walk(table, owner, nested)
    return out


def differences(config: Config, base: Config) -> list[str]:
    """The settings of `config` that differ from `base`'s, as "table.key = value" (TOML values).

    Parameters
    ----------
    config, base : Config
        Two document Configs of one class.

    Returns
    -------
    list of str
        One entry per differing setting, in the file's order.
    """
    mine, theirs = settings_of(config), settings_of(base)
    return [f"{key} = {value}" for key, value in mine.items() if theirs[key] != value]
