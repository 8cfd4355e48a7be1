"""Survey patterns (waypoints x, y, z, yaw) that revisit places, so loop closures happen."""

from __future__ import annotations

import numpy as np


def orbit(centre, radius_m: float, depths_m, points_per_lap: int = 16) -> np.ndarray:
    """(W,4) waypoints circling `centre` (x, y) at each depth, facing the centre."""
    angles = np.linspace(0, 2 * np.pi, points_per_lap, endpoint=False)
    rows = []
    for z in depths_m:
        for a in angles:
            x, y = centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a)
            rows.append([x, y, z, np.arctan2(centre[1] - y, centre[0] - x)])
        rows.append(rows[-len(angles)])  # close the lap where it began
    return np.asarray(rows)


def lawnmower(bounds: np.ndarray, heading: float, depths_m, lanes: int = 3) -> np.ndarray:
    """(W,4) passes along x across the box at each depth, `lanes` lines in y, fixed heading."""
    rows = []
    ys = np.linspace(bounds[0, 1] + 0.5, bounds[1, 1] - 0.5, lanes)
    for z in depths_m:
        for lane, y in enumerate(ys):
            xs = (bounds[0, 0] + 0.5, bounds[1, 0] - 0.5)
            for x in xs if lane % 2 == 0 else xs[::-1]:
                rows.append([x, y, z, heading])
    return np.asarray(rows)
