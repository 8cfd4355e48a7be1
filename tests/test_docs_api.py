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


def test_public_api_is_documented():
    # what the generated reference renders: every public name with numpydoc sections and type hints
    from tests.api_docs import problems

    assert problems() == []


def test_api_check_finds_what_the_reference_would_miss(monkeypatch):
    from tests import api_docs

    def scale(points, factor=2.0):
        return points

    def shift(points: list, offset_m: float = 1.0) -> list:
        """Shift points.

        Parameters
        ----------
        points : list
            The points.

        Returns
        -------
        list
            The shifted points.
        """
        return points

    public = [("vogjax.scale", scale), ("vogjax.shift", shift)]
    monkeypatch.setattr(api_docs, "public_objects", lambda: public)
    assert api_docs.problems() == [
        "vogjax.scale: no docstring",
        "vogjax.shift: parameters not in its Parameters section: offset_m",
    ]
