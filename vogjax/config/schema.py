"""One way to declare, check and load settings.

A setting is a field of a frozen dataclass derived from `Config`, declared with `number`,
`integer`, `flag`, `text` or `section` (a nested Config). The declaration carries the rule;
`Config.__post_init__` checks every field against it and then calls `check()` for rules that
span fields. `from_dict` builds a Config from nested dicts (a TOML document): unknown keys and
values of the wrong type are errors naming the key's path, and nothing needs a table of its own.
A declaration's `doc` is a short note the settings file (`settings_file`) prints beside the rule:
the unit ("in m") of a setting whose name has no unit suffix.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import tomllib
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class Rule:
    """kind: "number", "integer", "flag", "text" or "section".
    low/high: bounds (None: none), low_open/high_open: whether the bound itself is excluded.
    options: strings accepted (for "text", the only values; for numbers, besides them).
    none_spelled: a number that may be None; in TOML, which has no None, this string stands for it."""

    kind: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    options: tuple = ()
    none_spelled: str | None = None

    def describe(self) -> str:
        if self.kind == "text":
            return "one of " + ", ".join(repr(o) for o in self.options)
        if self.kind == "flag":
            return "true or false"
        noun = "integer" if self.kind == "integer" else "number"
        if self.low == 0 and self.low_open and self.high is None:
            words = f"a positive {noun}"
        elif self.low == 0 and self.high == 1 and self.low_open and self.high_open:
            words = "a number strictly between 0 and 1"
        elif self.kind == "integer" and self.low == 1 and not self.low_open:
            words = "a positive integer"
            if self.high is not None:
                words += f" <= {self._bound(self.high)}"
        elif self.low is not None and self.low > 0:
            words = f"a positive {noun}"
            if self.low is not None:
                words += f" {'>' if self.low_open else '>='} {self._bound(self.low)}"
            if self.high is not None:
                words += f" and {'<' if self.high_open else '<='} {self._bound(self.high)}"
        else:
            words = f"an {noun}" if noun == "integer" else f"a finite {noun}"
            if self.low is not None:
                words += f" {'>' if self.low_open else '>='} {self._bound(self.low)}"
            if self.high is not None:
                words += (
                    f"{' and' if self.low is not None else ''} {'<' if self.high_open else '<='} "
                    f"{self._bound(self.high)}"
                )
        choices = [repr(o) for o in self.options] + (["None"] if self.none_spelled else [])
        return " or ".join(choices + [words])

    def _bound(self, value) -> str:
        return str(int(value)) if self.kind == "integer" else f"{value:g}"

    def accepts(self, value) -> bool:
        if self.none_spelled and value is None:
            return True
        if self.kind == "text" or (self.options and isinstance(value, str)):
            return value in self.options
        if self.kind == "flag":
            return isinstance(value, bool)
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.kind == "integer" and not isinstance(value, numbers.Integral):
            return False
        if not finite_real(value):
            return False
        if self.low is not None and (value < self.low or (self.low_open and value == self.low)):
            return False
        if self.high is not None and (value > self.high or (self.high_open and value == self.high)):
            return False
        return True

    def check(self, name: str, value):
        """`value` if it follows the rule, else a ValueError naming `name`."""
        if not self.accepts(value):
            raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
        return value


def finite_real(value) -> bool:
    """Whether a real number is finite as a float (an integer too large for a float is not)."""
    try:
        return math.isfinite(float(value))
    except (OverflowError, ValueError, TypeError):
        return False


def _setting(default, rule: Rule, doc: str):
    return dataclasses.field(default=default, metadata={"rule": rule, "doc": doc})


def number(
    default, *, low=None, high=None, low_open=False, high_open=False, options=(), none_spelled=None, doc: str = ""
):
    """A finite real number within the bounds (or one of `options`, or None if `none_spelled`)."""
    return _setting(default, Rule("number", low, high, low_open, high_open, tuple(options), none_spelled), doc)


def positive(default, doc: str = ""):
    return number(default, low=0, low_open=True, doc=doc)


def non_negative(default, doc: str = ""):
    return number(default, low=0, doc=doc)


def probability(default, doc: str = ""):
    return number(default, low=0, high=1, low_open=True, high_open=True, doc=doc)


def integer(default, *, low=None, high=None, none_spelled=None, doc: str = ""):
    return _setting(default, Rule("integer", low, high, none_spelled=none_spelled), doc)


def flag(default: bool, doc: str = ""):
    return _setting(default, Rule("flag"), doc)


def text(default: str, options, doc: str = ""):
    return _setting(default, Rule("text", options=tuple(options)), doc)


def section(default: Config, *, flatten: bool = False, doc: str = ""):
    """A nested Config. `flatten`: in a settings file its own sections sit at the top level
    beside it, and its plain settings in a table named after the field."""
    return dataclasses.field(
        default_factory=lambda: default, metadata={"rule": Rule("section"), "flatten": flatten, "doc": doc}
    )


def rule_of(field: dataclasses.Field) -> Rule:
    return field.metadata["rule"]


def check_setting(cls, name: str, value):
    """`value` checked against the rule of setting `name` of Config class `cls` (for functions
    that take a setting as an argument); a ValueError naming `name` otherwise."""
    field = next(f for f in dataclasses.fields(cls) if f.name == name)
    return rule_of(field).check(name, value)


@dataclasses.dataclass(frozen=True)
class Config:
    """Base of every settings dataclass: fields checked on construction."""

    def __post_init__(self):
        where = type(self).__name__
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            rule = rule_of(field)
            if rule.kind == "section":
                if not isinstance(value, type(field.default_factory())):
                    raise ValueError(
                        f"{where}.{field.name} must be a {type(field.default_factory()).__name__}, "
                        f"got {type(value).__name__}"
                    )
            else:
                rule.check(f"{where}.{field.name}", value)
                # NumPy scalars, Fractions and the like stored as plain float/int: they compare,
                # hash and serialise (a map file's JSON header) like the values they stand for
                if rule.kind in ("number", "integer") and value is not None and not isinstance(value, str):
                    object.__setattr__(self, field.name, float(value) if rule.kind == "number" else int(value))
        self.check()

    def check(self) -> None:
        """Rules spanning several fields; raise ValueError naming them."""

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def replace(self, **changes) -> Config:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, values: dict, where: str | None = None):
        """This Config with `values` (nested dicts for sections) over the defaults."""
        return _replaced(cls(), values, where or cls.__name__)

    @classmethod
    def from_toml(cls, path, base: Config | None = None):
        """This Config from a TOML file (see `from_document`)."""
        path = Path(path)
        try:
            document = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"config {str(path)!r} does not exist") from None
        except (tomllib.TOMLDecodeError, UnicodeDecodeError, IsADirectoryError, PermissionError) as error:
            raise ValueError(f"config {str(path)!r} is not valid TOML: {error}") from None
        except RecursionError:  # tomllib recurses into nested arrays and tables
            raise ValueError(f"config {str(path)!r} nests too deeply to be a settings file") from None
        return cls.from_document(document, base)

    @classmethod
    def tables(cls) -> dict[str, tuple[str, ...]]:
        """The top-level tables of this Config's settings file, in order: table name -> the
        path of fields to the Config it sets; ("pipeline", "") for a flattened section's own
        plain settings, ("pipeline", "map") for one of its sections, ("report",) otherwise.

        Returns
        -------
        dict
            Table name -> tuple of field names.
        """
        tables = {}
        for field in dataclasses.fields(cls):
            if field.metadata.get("flatten"):
                tables[field.name] = (field.name, "")
                inner = type(field.default_factory())
                for sub in dataclasses.fields(inner):
                    if rule_of(sub).kind == "section":
                        tables[sub.name] = (field.name, sub.name)
            elif rule_of(field).kind == "section":
                tables[field.name] = (field.name,)
        return tables

    @classmethod
    def from_document(cls, document: dict, base: Config | None = None):
        """From a settings document: one table per section (`[map]`, `[loop_closure.icp]`, ...),
        each setting given replacing that of `base` (default: the defaults)."""
        tables = cls.tables()  # table name -> (path of fields to the Config it sets)
        unknown = sorted(set(document) - set(tables))
        if unknown:
            raise ValueError(
                f"unknown config table(s) {', '.join(unknown)}{_did_you_mean(unknown[0], tables)} "
                f"(known: {', '.join(tables)})"
            )
        config = cls() if base is None else base
        for table, path in tables.items():
            if table not in document:
                continue
            values = document[table]
            if path[-1] == "":  # the flattened section's own plain settings
                owner = getattr(config, path[0])
                if not isinstance(values, dict):
                    raise ValueError(f"{table} must be a table of settings, got {values!r}")
                sections = {f.name for f in dataclasses.fields(owner) if rule_of(f).kind == "section"}
                nested = sorted(set(values) & sections)
                if nested:
                    raise ValueError(f"{table}.{nested[0]}: write it as the table [{nested[0]}]")
                config = config.replace(**{path[0]: _replaced(owner, values, table)})
            elif len(path) == 2:
                owner = getattr(config, path[0])
                owner = owner.replace(**{path[1]: _replaced(getattr(owner, path[1]), values, table)})
                config = config.replace(**{path[0]: owner})
            else:
                config = config.replace(**{path[0]: _replaced(getattr(config, path[0]), values, table)})
        return config


_TYPE_NAMES = {"number": "float", "integer": "int", "flag": "bool", "text": "str"}


def _replaced(config: Config, values, where: str) -> Config:
    """`config` with `values` replacing its fields, each checked and named `where.key`."""
    if not isinstance(values, dict):
        raise ValueError(f"{where} must be a table of settings, got {values!r}")
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for key, value in values.items():
        name = f"{where}.{key}"
        if key not in fields:
            raise ValueError(f"unknown setting {name}{_did_you_mean(key, fields)} (known: {', '.join(sorted(fields))})")
        rule = rule_of(fields[key])
        if rule.kind == "section":
            changes[key] = _replaced(getattr(config, key), value, name)
            continue
        if rule.none_spelled is not None and value == rule.none_spelled:
            value = None
        elif rule.kind == "number" and isinstance(value, int) and not isinstance(value, bool):
            if not finite_real(value):  # an integer too large for a float
                raise ValueError(f"{name} must be {rule.describe()}, got an integer of {len(str(abs(value)))} digits")
            value = float(value)
        if value is not None and not (isinstance(value, str) and rule.options) and not _has_type(rule, value):
            raise ValueError(f"{name} must be {_TYPE_NAMES[rule.kind]}, got {value!r}")
        changes[key] = rule.check(name, value)
    try:
        return config.replace(**changes)
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None


def _did_you_mean(name, known) -> str:
    """ ", did you mean X?" for the known name closest to a misspelt one, or ""."""
    close = difflib.get_close_matches(str(name), list(known), n=1, cutoff=0.6)
    return f", did you mean {close[0]}?" if close else ""


def _has_type(rule: Rule, value) -> bool:
    if rule.kind == "flag":
        return isinstance(value, bool)
    if rule.kind == "text":
        return isinstance(value, str)
    if isinstance(value, bool):
        return False
    return isinstance(value, int) if rule.kind == "integer" else isinstance(value, float)
