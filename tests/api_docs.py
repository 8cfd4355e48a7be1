"""What the API reference needs from the code: every public name documented, numpydoc style.

`problems()` lists, for every name in `vogjax.__all__` and its subpackages' `__all__`, what the
generated reference would miss: a class, function, method or property without a docstring; a
parameter missing from its `Parameters` section; a return value without a `Returns` section; a
public signature without type hints. Settings classes (dataclasses) document their fields in
`Parameters` or `Attributes`.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import inspect

import griffe

import vogjax as vj

SUBPACKAGES = [f"vogjax.{name}" for name in vj._SUBPACKAGES if name != "kernels"]
# Members every class gets from Python or a base class documented elsewhere.
INHERITED_OK = {"__init__"}


def public_objects():
    """(qualified name, object) for each public class and function, each once."""
    seen, out = set(), []
    for module_name in ["vogjax", *SUBPACKAGES]:
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if inspect.ismodule(obj) or id(obj) in seen:
                continue
            if inspect.isclass(obj) or inspect.isfunction(obj):
                seen.add(id(obj))
                out.append((f"{module_name}.{name}", obj))
    return out


def sections(doc: str) -> dict[str, list]:
    parsed = griffe.Docstring(doc, parser="numpy").parse(warnings=False)
    found: dict[str, list] = {}
    for section in parsed:
        kind = section.kind.value
        if kind in ("parameters", "attributes", "other parameters"):
            found.setdefault("parameters", []).extend(item.name for item in section.value)
        elif kind in ("returns", "yields"):
            found.setdefault("returns", []).extend(section.value)
        else:
            found.setdefault(kind, [])
    return found


def function_problems(where: str, fn, skip_first: bool) -> list[str]:
    doc = inspect.getdoc(fn)
    if not doc:
        return [f"{where}: no docstring"]
    problems = []
    try:
        signature = inspect.signature(fn)
    except (TypeError, ValueError):
        return problems
    params = list(signature.parameters.values())[1 if skip_first else 0 :]
    params = [p for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    found = sections(doc)
    documented = set(found.get("parameters", []))
    missing = [p.name for p in params if p.name not in documented]
    if missing:
        problems.append(f"{where}: parameters not in its Parameters section: {', '.join(missing)}")
    unannotated = [p.name for p in params if p.annotation is inspect.Parameter.empty]
    if unannotated:
        problems.append(f"{where}: parameters without type hints: {', '.join(unannotated)}")
    returns = signature.return_annotation
    if fn.__name__ != "__init__":
        if returns is inspect.Signature.empty:
            problems.append(f"{where}: no return type hint")
        elif returns not in (None, "None") and "returns" not in found:
            problems.append(f"{where}: no Returns section")
    return problems


def class_problems(where: str, cls) -> list[str]:
    doc = inspect.getdoc(cls) if cls.__doc__ else None
    if not doc or (dataclasses.is_dataclass(cls) and doc.startswith(f"{cls.__name__}(")):
        return [f"{where}: no docstring"]
    problems = []
    if issubclass(cls, enum.Enum):
        return problems
    if dataclasses.is_dataclass(cls):
        documented = set(sections(doc).get("parameters", []))
        missing = [f.name for f in dataclasses.fields(cls) if f.init and f.name not in documented]
        if missing:
            problems.append(f"{where}: fields not in its Parameters/Attributes section: {', '.join(missing)}")
    else:
        init = cls.__dict__.get("__init__")
        if init is not None:
            # numpydoc documents __init__'s parameters in the class docstring
            params = list(inspect.signature(init).parameters.values())[1:]
            params = [p for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
            documented = set(sections(doc).get("parameters", []))
            missing = [p.name for p in params if p.name not in documented]
            if missing:
                problems.append(f"{where}: constructor parameters not in its Parameters section: {', '.join(missing)}")
            unannotated = [p.name for p in params if p.annotation is inspect.Parameter.empty]
            if unannotated:
                problems.append(f"{where}: constructor parameters without type hints: {', '.join(unannotated)}")
    for name, member in vars(cls).items():
        if name.startswith("_"):
            continue
        member_where = f"{where}.{name}"
        if isinstance(member, property):
            if not member.__doc__:
                problems.append(f"{member_where}: no docstring")
            elif inspect.signature(member.fget).return_annotation is inspect.Signature.empty:
                problems.append(f"{member_where}: no return type hint")
        elif isinstance(member, staticmethod):
            problems += function_problems(member_where, member.__func__, skip_first=False)
        elif isinstance(member, classmethod):
            problems += function_problems(member_where, member.__func__, skip_first=True)
        elif inspect.isfunction(member):
            problems += function_problems(member_where, member, skip_first=True)
    return problems


def problems() -> list[str]:
    out = []
    for where, obj in public_objects():
        if inspect.isclass(obj):
            out += class_problems(where, obj)
        else:
            out += function_problems(where, obj, skip_first=False)
    return out


if __name__ == "__main__":
    found = problems()
    print("\n".join(found))
    print(f"{len(found)} problems")
