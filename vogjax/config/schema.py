"""One way to declare, check and load settings.

A setting is a field of a frozen dataclass derived from `Config`, declared with `number`,
`integer`, `flag`, `text` or `section` (a nested Config). The declaration carries the rule;
`Config.__post_init__` checks every field against it and then calls `check()` for rules that
span fields. `from_dict` builds a Config from nested dicts (a TOML document): unknown keys and
values of the wrong type are errors naming the key's path, and nothing needs a table of its own.

A declaration's `doc` is a short note the settings file (`settings_file`) prints beside the rule:
the unit ("in m") of a setting whose name has no unit suffix.

Examples
--------
>>> import dataclasses
>>> @dataclasses.dataclass(frozen=True)
... class Gains(Config):
...     gain: float = positive(0.5)
>>> Gains.from_dict({"gain": 2.0}).gain
2.0
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import numbers
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any, Self


@dataclasses.dataclass(frozen=True)
class Rule:
    """The rule a setting's value must follow, carried by its field's metadata.

    Built by the declaration helpers (`number`, `integer`, `flag`, `text`, `section`); read back
    with `rule_of`. The settings reference prints `describe()` in its "accepted" column.

    Attributes
    ----------
    kind : str
        "number", "integer", "flag", "text" or "section" (a nested `Config`).
    low : float or None
        Lower bound (None: unbounded below).
    high : float or None
        Upper bound (None: unbounded above).
    low_open : bool
        Whether `low` itself is excluded.
    high_open : bool
        Whether `high` itself is excluded.
    options : tuple of str
        Strings accepted: for "text" the only values, for numbers accepted besides them (such as
        "auto").
    none_spelled : str or None
        For a number that may be None: the string that stands for None in TOML, which has no
        None (None: the setting cannot be None).
    """

    kind: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    options: tuple = ()
    none_spelled: str | None = None

    def describe(self) -> str:
        """The values the rule accepts, in words.

        Returns
        -------
        str
            Such as "a positive number", "one of 'chord', 'centre'" or "None or a positive integer
            >= 2"; error messages read "NAME must be " followed by it.
        """
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

    def accepts(self, value: Any) -> bool:
        """Whether `value` follows the rule.

        Parameters
        ----------
        value : Any
            A candidate value. Booleans are not numbers; a number must be finite as a float; an
            "integer" must be an integral number.

        Returns
        -------
        bool
            True if `value` is of the rule's kind, within its bounds, or one of its options (or
            None where `none_spelled` allows it).
        """
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

    def check(self, name: str, value: Any) -> Any:
        """Return `value` if it follows the rule, else raise a ValueError naming `name`.

        Parameters
        ----------
        name : str
            The setting's name as the error message shows it (such as "MapConfig.voxel_size").
        value : Any
            The candidate value.

        Returns
        -------
        Any
            `value`, unchanged.

        Raises
        ------
        ValueError
            If `value` does not follow the rule: "NAME must be DESCRIPTION, got VALUE".
        """
        if not self.accepts(value):
            raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
        return value


def finite_real(value: Any) -> bool:
    """Whether a real number is finite as a float.

    Parameters
    ----------
    value : Any
        A number (or anything else, which is not finite).

    Returns
    -------
    bool
        True if ``float(value)`` is finite; False for inf, NaN, an integer too large for a float
        and anything `float` rejects.
    """
    try:
        return math.isfinite(float(value))
    except (OverflowError, ValueError, TypeError):
        return False


def _setting(default, rule: Rule, doc: str):
    return dataclasses.field(default=default, metadata={"rule": rule, "doc": doc})


def number(
    default: float | str | None,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    options: Iterable[str] = (),
    none_spelled: str | None = None,
    doc: str = "",
) -> Any:
    """Declare a setting that is a finite real number within bounds.

    Parameters
    ----------
    default : float or str or None
        The default value (a string only if it is one of `options`, None only with
        `none_spelled`).
    low, high : float or None, optional
        Bounds (None: unbounded on that side).
    low_open, high_open : bool, optional
        Whether the bound itself is excluded.
    options : iterable of str, optional
        Strings accepted besides numbers (such as "auto").
    none_spelled : str or None, optional
        If given, the setting may be None, written as this string in TOML.
    doc : str, optional
        A description kept in the field's metadata (the settings reference reads the class
        docstring instead).

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return _setting(default, Rule("number", low, high, low_open, high_open, tuple(options), none_spelled), doc)


def positive(default: float, doc: str = "") -> Any:
    """Declare a number that must be greater than 0 (see `number`).

    Parameters
    ----------
    default : float
        The default value.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return number(default, low=0, low_open=True, doc=doc)


def non_negative(default: float, doc: str = "") -> Any:
    """Declare a number that must be 0 or more (see `number`).

    Parameters
    ----------
    default : float
        The default value.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return number(default, low=0, doc=doc)


def probability(default: float, doc: str = "") -> Any:
    """Declare a number strictly between 0 and 1 (see `number`).

    Parameters
    ----------
    default : float
        The default value.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return number(default, low=0, high=1, low_open=True, high_open=True, doc=doc)


def integer(
    default: int | None,
    *,
    low: int | None = None,
    high: int | None = None,
    none_spelled: str | None = None,
    doc: str = "",
) -> Any:
    """Declare a setting that is an integer within closed bounds.

    Parameters
    ----------
    default : int or None
        The default value (None only with `none_spelled`).
    low, high : int or None, optional
        Inclusive bounds (None: unbounded on that side).
    none_spelled : str or None, optional
        If given, the setting may be None, written as this string in TOML.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return _setting(default, Rule("integer", low, high, none_spelled=none_spelled), doc)


def flag(default: bool, doc: str = "") -> Any:
    """Declare a setting that is true or false (a bool, not a number).

    Parameters
    ----------
    default : bool
        The default value.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return _setting(default, Rule("flag"), doc)


def text(default: str, options: Iterable[str], doc: str = "") -> Any:
    """Declare a setting that is one of a few strings.

    Parameters
    ----------
    default : str
        The default value, one of `options`.
    options : iterable of str
        The only values accepted.
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule`.
    """
    return _setting(default, Rule("text", options=tuple(options)), doc)


def section(default: Config, *, flatten: bool = False, doc: str = "") -> Any:
    """Declare a nested Config: a table of its own in a settings file.

    Parameters
    ----------
    default : Config
        The default value; a value given must be of its class.
    flatten : bool, optional
        In a settings file, the nested Config's own sections sit at the top level beside it, and
        its plain settings in a table named after the field (`JobConfig.pipeline`: ``[pipeline]``
        beside ``[map]``, not ``[pipeline.map]``).
    doc : str, optional
        A description kept in the field's metadata.

    Returns
    -------
    dataclasses.Field
        A dataclass field whose metadata carries the `Rule` and the `flatten` flag.
    """
    return dataclasses.field(
        default_factory=lambda: default, metadata={"rule": Rule("section"), "flatten": flatten, "doc": doc}
    )


def rule_of(field: dataclasses.Field) -> Rule:
    """The rule a setting was declared with.

    Parameters
    ----------
    field : dataclasses.Field
        A field of a `Config` subclass, declared with `number`, `integer`, ...

    Returns
    -------
    Rule
        The rule in the field's metadata.
    """
    return field.metadata["rule"]


def check_setting(cls: type[Config], name: str, value: Any) -> Any:
    """Check a value against the rule of one setting, for functions that take a setting as an argument.

    Parameters
    ----------
    cls : type[Config]
        The Config class declaring the setting.
    name : str
        The setting's field name; the error message names it.
    value : Any
        The candidate value.

    Returns
    -------
    Any
        `value`, unchanged.

    Raises
    ------
    ValueError
        If `value` does not follow the setting's rule.
    """
    field = next(f for f in dataclasses.fields(cls) if f.name == name)
    return rule_of(field).check(name, value)


@dataclasses.dataclass(frozen=True)
class Config:
    """Base of every settings dataclass: every field is checked on construction.

    A subclass is a frozen dataclass whose fields are declared with `number`, `integer`, `flag`,
    `text` or `section`. Constructing it checks each field against its rule and then calls
    `check`; numbers are stored as plain `float` / `int` (NumPy scalars too), so a Config compares,
    hashes and serialises like the values it stands for.

    Raises
    ------
    ValueError
        If a field breaks its rule ("MapConfig.voxel_size must be ..., got ...") or a section is
        not of its declared class, or `check` finds settings that contradict each other.
    """

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
        """Check the rules that span several fields; subclasses override it.

        Raises
        ------
        ValueError
            Naming the fields whose values contradict each other.
        """

    def to_dict(self) -> dict:
        """The settings as nested dicts.

        Returns
        -------
        dict
            ``{field: value}``, sections as nested dicts; `from_dict` reads it back.
        """
        return dataclasses.asdict(self)

    def replace(self, **changes: Any) -> Self:
        """A copy with some settings changed, checked like a new Config.

        Parameters
        ----------
        **changes
            New values by field name.

        Returns
        -------
        Config
            A new Config of the same class.

        Raises
        ------
        ValueError
            If a new value breaks its rule.
        """
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, values: dict, where: str | None = None) -> Self:
        """This Config with `values` over the defaults.

        Parameters
        ----------
        values : dict
            ``{field: value}``, nested dicts for sections; fields not given keep their defaults.
            Integers are accepted for numbers; other types must match the setting's.
        where : str or None, optional
            The name errors give the table (default: the class's name).

        Returns
        -------
        Config
            A new Config of this class.

        Raises
        ------
        ValueError
            Naming the key's path (``where.key``) for an unknown key, a value of the wrong type or
            one out of its range.
        """
        return _replaced(cls(), values, where or cls.__name__)

    @classmethod
    def from_toml(cls, path: str | Path, base: Config | None = None) -> Self:
        """This Config from a TOML settings file (see `from_document`).

        Parameters
        ----------
        path : str or Path
            The settings file.
        base : Config or None, optional
            The settings the file's values replace (default: the class's defaults).

        Returns
        -------
        Config
            A new Config of this class.

        Raises
        ------
        ValueError
            If the file does not exist, is not valid TOML or nests too deeply, or (from
            `from_document`) holds an unknown table or key or a value that breaks its rule.
        """
        return cls.from_file_document(read_toml(path), path, base)

    @classmethod
    def from_file_document(cls, document: dict, path: str | Path, base: Config | None = None) -> Self:
        """`from_document` of a file's document (`read_toml`), a refusal naming the file.

        Parameters
        ----------
        document : dict
            The file's tables, as `read_toml` returns them.
        path : str or Path
            The file, for the message.
        base : Config or None, optional
            Settings the file overrides (default: this class's defaults).

        Returns
        -------
        Config
            This Config with the file's settings.

        Raises
        ------
        ValueError
            As `from_document` does, the message led by ``config 'PATH':``.
        """
        try:
            return cls.from_document(document, base)
        except ValueError as error:
            raise ValueError(f"config {str(path)!r}: {error}") from None

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
    def from_document(cls, document: dict, base: Config | None = None) -> Self:
        """This Config from a parsed settings document.

        The document has one table per section (``[map]``, ``[loop_closure.icp]``, ...; a
        flattened section's plain settings under its own name); each setting given replaces that
        of `base`.

        Parameters
        ----------
        document : dict
            The parsed TOML document: ``{table: {key: value}}``.
        base : Config or None, optional
            The settings the document's values replace (default: the class's defaults).

        Returns
        -------
        Config
            A new Config of this class.

        Raises
        ------
        ValueError
            For an unknown table (naming the known ones, with a close match), an unknown key, a
            value of the wrong type or out of its range (naming ``table.key``), or a table that is
            not a table.
        """
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


def read_toml(path: str | Path) -> dict:
    """A settings file's document, read once (a pipe, ``--config <(...)``, reads empty the
    second time: read it here and build from the document).

    Raises
    ------
    ValueError
        Naming the file: it does not exist, is not valid TOML, or nests too deeply.
    """
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"config {str(path)!r} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError, IsADirectoryError, PermissionError) as error:
        raise ValueError(f"config {str(path)!r} is not valid TOML: {error}") from None
    except RecursionError:  # tomllib recurses into nested arrays and tables
        raise ValueError(f"config {str(path)!r} nests too deeply to be a settings file") from None
