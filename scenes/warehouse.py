"""A warehouse for a ground vehicle with a spinning lidar: 40 x 40 x 6 m, racks, pillars, walls.

The hall's floor lies at z = 0 and its roof at 6 m; four rows of pallet racks run along x with
a cross aisle at x = 0 and a main aisle between the middle rows; pillars stand along the
perimeter aisle, and pallets and crates stand by the walls. Shelves hold pallets of random
heights (seeded), so no two bays look alike and a revisit is recognisable. The vehicle drives
the perimeter aisle, 3 m from the walls, counter-clockwise (`default_survey`: one lap's corners
at z = 0, the vehicle's base on the floor). Every part is a closed box or cylinder, so the
ground truth knows the solids' insides.
"""

from __future__ import annotations

import numpy as np
import trimesh

from vogjax.geometry import pose_from_xyz_yaw

from .builtin import OFF_GRID
from .scene import Scene, box, cylinder_between, placed

HALF_SIZE_M = 20.0  # the hall's inner half-width: 40 x 40 m
HEIGHT_M = 6.0
WALL_M = 0.3
RACK_ROWS_Y_M = (-13.0, -5.0, 5.0, 13.0)
RACK_DEPTH_M = 1.1
RACK_HEIGHT_M = 4.5
RACK_ENDS_X_M = ((-14.0, -1.5), (1.5, 14.0))  # a cross aisle at x = 0
BAY_M = 2.5
SHELF_LEVELS_M = (0.15, 1.6, 3.0, 4.4)
ROUTE_M = 17.0  # the perimeter aisle's centre line: |x| or |y| = 17 m


def _rack(x0: float, x1: float, y: float, rng: np.random.Generator) -> list:
    """A pallet rack between x0 and x1 centred on y: uprights at every bay, shelves, pallets."""
    parts = []
    half = RACK_DEPTH_M / 2
    edges = np.linspace(x0, x1, int(round((x1 - x0) / BAY_M)) + 1)
    for x in edges:
        for side in (-1, 1):
            parts.append(box([x - 0.05, y + side * half - 0.1, 0.0], [x + 0.05, y + side * half, RACK_HEIGHT_M]))
    for z in SHELF_LEVELS_M:
        parts.append(box([x0 - 0.05, y - half, z - 0.06], [x1 + 0.05, y + half, z]))
    for a, b in zip(edges[:-1], edges[1:]):
        for z in SHELF_LEVELS_M[:-1]:
            if rng.uniform() < 0.3:  # an empty bay
                continue
            width = rng.uniform(0.8, 1.3)
            centre = rng.uniform(a + 0.1 + width / 2, b - 0.1 - width / 2)
            height = rng.uniform(0.4, 1.2)
            parts.append(box([centre - width / 2, y - half + 0.1, z], [centre + width / 2, y + half - 0.1, z + height]))
    return parts


def warehouse() -> Scene:
    """The warehouse: 40 x 40 x 6 m of floor, walls and roof, four rows of pallet racks, pillars.

    Returns
    -------
    Scene
        The scene; its exploration box is the hall (z from the floor to the roof), its start
        pose in the south-west corner of the perimeter aisle facing east, and its survey one
        counter-clockwise lap of that aisle (corners at z = 0: the vehicle's base on the floor).
    """
    rng = np.random.default_rng(35)
    h, w = HALF_SIZE_M, WALL_M
    parts = [
        box([-h - w, -h - w, -0.2], [h + w, h + w, 0.0]),  # floor
        box([-h - w, -h - w, HEIGHT_M], [h + w, h + w, HEIGHT_M + 0.2]),  # roof
        box([-h - w, -h - w, 0.0], [h + w, -h, HEIGHT_M]),  # walls
        box([-h - w, h, 0.0], [h + w, h + w, HEIGHT_M]),
        box([-h - w, -h, 0.0], [-h, h, HEIGHT_M]),
        box([h, -h, 0.0], [h + w, h, HEIGHT_M]),
    ]
    for y in RACK_ROWS_Y_M:
        for x0, x1 in RACK_ENDS_X_M:
            parts += _rack(x0, x1, y, rng)
    # pillars between the perimeter aisle and the racks, and along the walls
    for x, y in [(15.3, -9.0), (15.3, 0.0), (15.3, 9.0), (-15.3, -9.0), (-15.3, 0.0), (-15.3, 9.0)]:
        parts.append(cylinder_between([x, y, 0.0], [x, y, HEIGHT_M], 0.3))
    for x, y in [(-8.0, 19.4), (8.0, 19.4), (-8.0, -19.4), (8.0, -19.4), (19.4, 14.0), (-19.4, -14.0)]:
        parts.append(box([x - 0.3, y - 0.3, 0.0], [x + 0.3, y + 0.3, HEIGHT_M]))
    # pallets and crates against the walls, of seeded sizes, clear of the aisle's centre line
    for _ in range(24):
        along = rng.uniform(-h + 1.5, h - 1.5)
        depth, length, height = rng.uniform(0.6, 1.2), rng.uniform(0.8, 2.0), rng.uniform(0.3, 1.8)
        side = rng.integers(4)
        lo = [along - length / 2, h - 0.05 - depth, 0.0]
        hi = [along + length / 2, h - 0.05, height]
        crate = box(lo, hi)
        parts.append(placed(crate, pose_from_xyz_yaw(0.0, 0.0, 0.0, side * np.pi / 2)))
    corners = [(-ROUTE_M, -ROUTE_M), (ROUTE_M, -ROUTE_M), (ROUTE_M, ROUTE_M), (-ROUTE_M, ROUTE_M), (-ROUTE_M, -ROUTE_M)]
    headings = [0.0, np.pi / 2, np.pi, -np.pi / 2, 0.0]
    survey = np.array([[x, y, 0.0, yaw] for (x, y), yaw in zip(corners[1:], headings[1:])])
    bounds = np.array([[-h, -h, 0.0], [h, h, HEIGHT_M]])
    mesh = placed(trimesh.util.concatenate(parts), OFF_GRID)
    return Scene("warehouse", mesh, bounds, pose_from_xyz_yaw(-ROUTE_M, -ROUTE_M, 0.0, 0.0), survey)
