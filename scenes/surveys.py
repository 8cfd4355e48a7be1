"""Survey patterns (waypoints x, y, z, yaw) that revisit places, so loop closures happen."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt


def orbit(
    centre: Sequence[float], radius_m: float, depths_m: Sequence[float], points_per_lap: int = 16
) -> npt.NDArray[np.float64]:
    """Waypoints circling a point at each depth, facing it.

    Parameters
    ----------
    centre : sequence of float
        (x, y) of the point circled, metres.
    radius_m : float
        Radius of the circle, metres.
    depths_m : sequence of float
        Height of each lap, metres, in the order flown.
    points_per_lap : int, optional
        Waypoints per lap; each lap ends where it began.

    Returns
    -------
    (W, 4) ndarray of float64
        Waypoints (x, y, z, yaw), W = len(depths_m) * (points_per_lap + 1).
    """
    angles = np.linspace(0, 2 * np.pi, points_per_lap, endpoint=False)
    rows = []
    for z in depths_m:
        for a in angles:
            x, y = centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a)
            rows.append([x, y, z, np.arctan2(centre[1] - y, centre[0] - x)])
        rows.append(rows[-len(angles)])  # close the lap where it began
    return np.asarray(rows)


def lawnmower(
    bounds: npt.NDArray[np.floating], heading: float, depths_m: Sequence[float], lanes: int = 3
) -> npt.NDArray[np.float64]:
    """Waypoints of passes along x across a box at each depth, at a fixed heading.

    Parameters
    ----------
    bounds : (2, 3) ndarray of float
        The box: min and max corner, metres; passes keep 0.5 m inside it.
    heading : float
        Yaw held throughout, radians (the sensor looks that way, not along the pass).
    depths_m : sequence of float
        Height of each set of passes, metres.
    lanes : int, optional
        Passes per depth, evenly spaced in y, alternating in direction.

    Returns
    -------
    (W, 4) ndarray of float64
        Waypoints (x, y, z, yaw), two per pass.
    """
    rows = []
    ys = np.linspace(bounds[0, 1] + 0.5, bounds[1, 1] - 0.5, lanes)
    for z in depths_m:
        for lane, y in enumerate(ys):
            xs = (bounds[0, 0] + 0.5, bounds[1, 0] - 0.5)
            for x in xs if lane % 2 == 0 else xs[::-1]:
                rows.append([x, y, z, heading])
    return np.asarray(rows)
