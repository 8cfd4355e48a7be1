"""The built-in scenes, built procedurally (no downloads). Sizes, exploration boxes and start
poses follow the papers' experiments: a ship propeller seen from the starboard side (Ho, thesis
4.4.2: about 7 x 4 x 6 m, a 12 x 7 x 3.5 m box), a pier's pilings, the test tank (thesis 4.6.1:
7 m across, 3 m deep, an aluminium box and a ladder, a 12 x 12 x 2.5 m box), and small boxes."""

from __future__ import annotations

import numpy as np
import trimesh

from vogjax.geometry import pose_from_xyz_yaw as pose

from .scene import Scene, box, cylinder_between, placed
from .surveys import lawnmower, orbit

# Faces at round coordinates would lie exactly on voxel boundaries, where "the voxel the surface
# passes through" is the water on one side; an odd offset puts every face inside a voxel.
OFF_GRID = trimesh.transformations.translation_matrix([0.0137, 0.0291, 0.0443])


def _scene(name: str, parts: list, bounds: np.ndarray, start_pose: np.ndarray, survey: np.ndarray) -> Scene:
    return Scene(name, placed(trimesh.util.concatenate(parts), OFF_GRID), bounds, start_pose, survey)


def _survey_depths(bounds: np.ndarray) -> np.ndarray:
    """Two depths through the exploration box: 40% and 80% of the way up."""
    lo, hi = bounds
    return np.linspace(lo[2] + 0.4 * (hi[2] - lo[2]), hi[2] - 0.2 * (hi[2] - lo[2]), 2)


def propeller() -> Scene:
    """A ship's propeller seen from the starboard side (Ho, thesis 4.4.2).

    Hub and shaft along x, five twisted blades, a rudder aft; the hub at the origin. About
    7 x 4 x 6 m as the thesis gives for SS Curtiss's: 7 m from rudder to shaft, blades 3.2 m
    long, their disc 6 m tall and pressed to 4 m across (y) like the thesis's model.

    Returns
    -------
    Scene
        The scene; its exploration box is 12 x 7 x 3.5 m, starboard of the propeller, flown as a
        lawnmower looking at it.
    """
    parts = [
        cylinder_between([-0.7, 0, 0], [0.7, 0, 0], 0.55),  # hub
        cylinder_between([0.7, 0, 0], [3.8, 0, 0], 0.25),  # shaft into the hull
        box([-3.2, -0.12, -2.6], [-2.2, 0.12, 2.2]),
    ]  # rudder aft of the propeller
    for k in range(5):
        blade = trimesh.creation.box(extents=[0.9, 0.08, 2.7])  # chord, thickness, span
        vertices, faces = trimesh.remesh.subdivide_to_size(blade.vertices, blade.faces, max_edge=0.3)
        radial = vertices[:, 2] + 1.35 + 0.5  # from the hub axis
        twist = 0.9 - 0.25 * radial  # pitch angle falls off along the span
        c, s = np.cos(twist), np.sin(twist)
        x, y = vertices[:, 0], vertices[:, 1]
        vertices = np.stack([c * x - s * y, s * x + c * y, radial], axis=1)
        angle = 2 * np.pi * k / 5
        rotation = trimesh.transformations.rotation_matrix(angle, [1, 0, 0])
        rotation[1, :3] *= 0.66  # the disc 4 m across, 6 m tall
        parts.append(placed(trimesh.Trimesh(vertices, faces), rotation))
    bounds = np.array([[-6.0, -10.5, -1.75], [6.0, -3.5, 1.75]])  # 12 x 7 x 3.5 m, starboard of it
    survey = lawnmower(bounds, np.pi / 2, _survey_depths(bounds))  # looking at the propeller
    return _scene("propeller", parts, bounds, pose(0.0, -7.0, 0.0, np.pi / 2), survey)


def pilings() -> Scene:
    """A pier's pilings: two rows of slanted piles at uneven spacing between a seabed and a deck.

    Returns
    -------
    Scene
        The scene; its survey goes around the pier, corner to corner.
    """
    rng = np.random.default_rng(7)
    parts = [box([-11, -8, -0.4], [11, 8, 0.0]), box([-11, -3.5, 6.0], [11, 3.5, 6.4])]
    xs = np.array([-7.5, -4.2, -0.9, 1.8, 5.6])
    for row_y in (-2.5, 2.5):
        for x in xs + rng.uniform(-0.6, 0.6, len(xs)):
            lean = rng.uniform(-0.5, 0.5, 2)  # metres of lean over the height
            parts.append(
                cylinder_between([x, row_y, -0.2], [x + lean[0], row_y + lean[1], 6.2], rng.uniform(0.25, 0.4))
            )
    bounds = np.array([[-9.0, -6.5, 1.0], [9.0, 6.5, 5.0]])
    (x0, y0, _), (x1, y1, _) = bounds[0] + 0.5, bounds[1] - 0.5
    corners = [
        [x0, y0, np.pi / 4],
        [x1, y0, 3 * np.pi / 4],
        [x1, y1, -3 * np.pi / 4],
        [x0, y1, -np.pi / 4],
        [x0, y0, np.pi / 4],
    ]
    survey = np.asarray([[x, y, z, h] for z in _survey_depths(bounds) for x, y, h in corners])  # around the pier
    return _scene("pilings", parts, bounds, pose(-8.0, -5.5, 3.0, 0.0), survey)


def tank() -> Scene:
    """The test tank (Ho, thesis 4.6.1): 7 m across and 3 m deep, an aluminium box on its floor, a ladder.

    Returns
    -------
    Scene
        The scene; its exploration box is 12 x 12 x 2.5 m, its survey circles the middle.
    """
    parts = [
        trimesh.creation.annulus(
            r_min=3.5, r_max=3.7, height=3.2, transform=trimesh.transformations.translation_matrix([0, 0, 1.5])
        ),
        trimesh.creation.cylinder(
            radius=3.7, height=0.2, transform=trimesh.transformations.translation_matrix([0, 0, -0.1])
        ),
        box([1.0, -1.6, 0.0], [2.2, -0.8, 0.8]),
    ]
    for y in (-0.25, 0.25):  # ladder rails against the wall
        parts.append(cylinder_between([-3.35, y, 0.0], [-3.35, y, 3.0], 0.03, sections=8))
    for z in np.arange(0.3, 3.0, 0.3):
        parts.append(cylinder_between([-3.35, -0.25, z], [-3.35, 0.25, z], 0.02, sections=8))
    # the thesis's box was 12 x 12 x 2.5 m around the 7 m tank; the exploration box is the
    # tank's inside (x-y within its wall, 2.5 m deep): no view sees past the wall, and gain
    # counted out there drew the planner to views that could never see it
    bounds = np.array([[-3.5, -3.5, 0.25], [3.5, 3.5, 2.75]])
    survey = orbit((0.0, 0.0), 2.4, _survey_depths(bounds))  # circle the middle
    # 1.4 m from the centre: turning in place there, the sonar (0.9 m ahead) stays over 1 m from
    # the wall, out of its 0.5 m blind distance (at 2.1 m it came within 0.44 m)
    return _scene("tank", parts, bounds, pose(-1.0, 1.0, 1.5, 0.0), survey)


def boxes() -> Scene:
    """Three boxes on a floor: a small scene for fast tests.

    Returns
    -------
    Scene
        The scene; its survey orbits the boxes.
    """
    parts = [
        box([-4, -4, -0.2], [4, 4, 0.0]),
        box([-1.5, -1.0, 0.0], [-0.3, 0.4, 1.2]),
        box([0.6, 0.5, 0.0], [1.8, 1.4, 0.7]),
        box([0.4, -1.8, 0.0], [1.0, -1.2, 1.6]),
    ]
    bounds = np.array([[-3.0, -3.0, 0.5], [3.0, 3.0, 2.0]])
    survey = orbit((0.0, 0.0), 2.5, _survey_depths(bounds))
    return _scene("boxes", parts, bounds, pose(-2.5, -2.5, 1.2, np.pi / 4), survey)


BUILDERS = {"propeller": propeller, "pilings": pilings, "tank": tank, "boxes": boxes}
