"""The names the documentation promises exist (its code blocks run in test_docs_blocks.py)."""

import importlib
import pkgutil

import pytest

import vogjax as vj


def test_subpackages_resolve_on_first_use():
    assert vj.planner.NbvPlanner is importlib.import_module("vogjax.planner").NbvPlanner
    assert vj.kernels is importlib.import_module("vogjax.kernels")
    for name in vj._SUBPACKAGES:
        assert getattr(vj, name).__name__ == f"vogjax.{name}"
    with pytest.raises(AttributeError):
        _ = vj.no_such_thing


def test_kernels_all_names_every_module():
    import vogjax.kernels as kernels

    modules = sorted(info.name for info in pkgutil.iter_modules(kernels.__path__))
    assert sorted(kernels.__all__) == modules
    for name in kernels.__all__:
        assert getattr(kernels, name).__name__ == f"vogjax.kernels.{name}"
    with pytest.raises(AttributeError):
        _ = kernels.no_such_module
