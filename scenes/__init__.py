"""Built-in scenes with ground truth: trimesh scenes from the papers' experiments (`load`), and
`analytic`, a pier of closed-form primitives with a sonar orbit over it.

Ground-truth labels: FREE (1, water), OCCUPIED (2, the surface passes through the voxel) and
INSIDE (3, within a solid: never observable, left out of evaluations).

Examples
--------
>>> scene = load("boxes")
>>> scene.name, scene.bounds.shape, scene.survey(laps=2).shape[1]
('boxes', (2, 3), 4)
"""

from __future__ import annotations

import functools

from . import analytic
from .builtin import BUILDERS as _SONAR_SCENES
from .scene import FREE, INSIDE, OCCUPIED, GroundTruth, Scene
from .warehouse import warehouse

BUILDERS = {**_SONAR_SCENES, "warehouse": warehouse}
NAMES = tuple(BUILDERS)
# scenes a ground vehicle drives (a floor at z = 0, a route on it): mapped with a spinning lidar
GROUND_SCENES = ("warehouse",)


def load(name: str) -> Scene:
    """A built-in scene by name, built once.

    Parameters
    ----------
    name : str
        One of NAMES: "propeller", "pilings", "tank", "boxes" (sonar scenes of the papers'
        experiments) or "warehouse" (a ground scene for a spinning lidar: GROUND_SCENES).

    Returns
    -------
    Scene
        The scene. Every caller gets the same Scene, so its arrays are read-only (copy one to
        change it).

    Raises
    ------
    ValueError
        If `name` is not one of NAMES.
    """
    if not isinstance(name, str) or name not in BUILDERS:
        raise ValueError(f"scene name must be one of {', '.join(NAMES)}, got {name!r}")
    return _load(name)


@functools.cache
def _load(name: str) -> Scene:
    scene = BUILDERS[name]()
    for array in (scene.bounds, scene.start_pose, scene.default_survey):
        array.flags.writeable = False
    return scene


__all__ = ["FREE", "GROUND_SCENES", "INSIDE", "NAMES", "OCCUPIED", "GroundTruth", "Scene", "analytic", "load"]
