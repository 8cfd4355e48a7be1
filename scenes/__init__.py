"""Built-in scenes: trimesh scenes from the papers' experiments (`load`), and `analytic`, a pier
of closed-form primitives with a sonar orbit over it."""

from __future__ import annotations

import functools

from . import analytic
from .builtin import BUILDERS
from .scene import FREE, INSIDE, OCCUPIED, GroundTruth, Scene

NAMES = tuple(BUILDERS)


@functools.cache
def load(name: str) -> Scene:
    """One of NAMES: "propeller", "pilings", "tank", "boxes"."""
    if name not in BUILDERS:
        raise ValueError(f"name must be one of {', '.join(NAMES)}, got {name!r}")
    return BUILDERS[name]()


__all__ = ["FREE", "INSIDE", "NAMES", "OCCUPIED", "GroundTruth", "Scene", "analytic", "load"]
