"""A small analytic underwater scene and a profiling-sonar sweep over it, in NumPy.

The scene is a pier: a flat seabed, vertical piles (cylinders) and a moored hull (a box). Ray
intersections are closed-form, so it doubles as ground truth in tests and as the data of
`vogjax demo` and the benchmarks without any mesh or download.

Examples
--------
>>> import numpy as np
>>> scene = pier()
>>> float(scene.cast(np.array([[8.0, 0.0, 2.0]]), np.array([[0.0, 0.0, -1.0]]))[0])  # down to the seabed
2.0
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt


@dataclasses.dataclass(frozen=True)
class AnalyticScene:
    """A scene of closed-form primitives: a seabed plane, vertical piles and boxes.

    Attributes
    ----------
    seabed_z_m : float
        Height of the seabed plane, metres.
    piles : (P, 4) ndarray of float
        Vertical cylinders standing on the seabed: x_m, y_m, radius_m, top_z_m.
    boxes : (B, 6) ndarray of float
        Axis-aligned boxes: min x, y, z and max x, y, z, metres.
    bounds : (2, 3) ndarray of float
        The region worth mapping: min and max corner, metres.
    """

    seabed_z_m: float
    piles: npt.NDArray[np.float64]
    boxes: npt.NDArray[np.float64]
    bounds: npt.NDArray[np.float64]

    def cast(self, origins: npt.ArrayLike, directions: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Cast rays: the distance to the first surface along each.

        Parameters
        ----------
        origins : (R, 3) array_like of float
            Ray origins, metres.
        directions : (R, 3) array_like of float
            Unit directions.

        Returns
        -------
        (R,) ndarray of float64
            Distance to the first surface hit, metres; inf where the ray hits none.
        """
        o = np.asarray(origins, np.float64)
        d = np.asarray(directions, np.float64)
        best = np.full(o.shape[0], np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.seabed_z_m - o[:, 2]) / d[:, 2]
            best = np.where((t > 0) & (d[:, 2] < 0), np.minimum(best, t), best)
            for x, y, radius, top in self.piles:
                best = np.minimum(best, _cylinder(o, d, x, y, radius, self.seabed_z_m, top))
            for box in self.boxes:
                best = np.minimum(best, _box(o, d, box[:3], box[3:]))
        return best


def _cylinder(o, d, x, y, radius, bottom, top):
    px, py = o[:, 0] - x, o[:, 1] - y
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (px * d[:, 0] + py * d[:, 1])
    c = px**2 + py**2 - radius**2
    disc = b**2 - 4 * a * c
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
    z = o[:, 2] + t * d[:, 2]
    ok = (disc >= 0) & (a > 0) & (t > 0) & (z >= bottom) & (z <= top)
    return np.where(ok, t, np.inf)


def _box(o, d, lo, hi):
    t1 = (lo - o) / d
    t2 = (hi - o) / d
    t_near = np.nanmax(np.minimum(t1, t2), axis=1)
    t_far = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((t_near <= t_far) & (t_near > 0), t_near, np.inf)


def pier() -> AnalyticScene:
    """The pier: a flat seabed, two rows of unevenly spaced piles and a hull beside them.

    Returns
    -------
    AnalyticScene
        Seabed at z = 0, ten piles 5 m tall, one barge hull; mapped region 18 x 14 x 5 m.
    """
    xs = np.array([-6.0, -3.4, -0.5, 2.2, 5.5])
    piles = np.concatenate(
        [
            np.stack([xs, np.full(5, -3.0), np.full(5, 0.35), np.full(5, 5.0)], 1),
            np.stack([xs + 0.7, np.full(5, 3.0), np.full(5, 0.3), np.full(5, 5.0)], 1),
        ]
    )
    boxes = np.array([[-4.0, -1.2, 0.0, 3.5, 1.2, 1.6]])  # a barge hull resting on the seabed
    bounds = np.array([[-9.0, -7.0, 0.0], [9.0, 7.0, 5.0]])
    return AnalyticScene(seabed_z_m=0.0, piles=piles, boxes=boxes, bounds=bounds)


@dataclasses.dataclass(frozen=True)
class SonarSweep:
    """Scans of a profiling sonar, ready for `VoxelMap.integrate_scans`.

    S scans of B beams each, beams stored scan by scan.

    Attributes
    ----------
    origins : (S, 3) ndarray of float32
        Sonar position of each scan, metres.
    points : (S*B, 3) ndarray of float32
        Beam endpoints, metres. Misses end past max_range, so they clear free space up to it and
        mark nothing occupied.
    scan_index : (S*B,) ndarray of int
        The scan of each beam.
    hit : (S*B,) ndarray of bool
        Whether the beam returned within max_range.
    """

    origins: npt.NDArray[np.float32]
    points: npt.NDArray[np.float32]
    scan_index: npt.NDArray[np.int_]
    hit: npt.NDArray[np.bool_]


def orbit_sweep(
    scene: AnalyticScene,
    num_scans: int,
    beams: int = 96,
    fov_deg: float = 29.0,
    max_range_m: float = 11.0,
    radius_m: float = 8.5,
    depths_m: Sequence[float] = (3.5, 2.5),
    tilt_deg: float = -25.0,
    range_noise_m: float = 0.0,
    seed: int = 0,
) -> SonarSweep:
    """Simulate a sonar orbiting the scene at a few depths, its vertical fan looking at the centre.

    The orbit is an ellipse (`radius_m` in x, 0.8 `radius_m` in y), one lap per depth, the scans
    spread evenly over the laps.

    Parameters
    ----------
    scene : AnalyticScene
        The scene.
    num_scans : int
        S, scans over the whole sweep.
    beams : int, optional
        B, beams per scan, spread over `fov_deg`.
    fov_deg : float, optional
        Angle the fan spans, degrees.
    max_range_m : float, optional
        The sonar's reach, metres: farther surfaces give no return.
    radius_m : float, optional
        The orbit's semi-axis in x, metres.
    depths_m : sequence of float, optional
        Height of each lap, metres, in the order flown.
    tilt_deg : float, optional
        Angle of the fan's centre above the horizontal, degrees (negative: looking down).
    range_noise_m : float, optional
        Standard deviation of Gaussian noise added to returned ranges, metres.
    seed : int, optional
        Seed of the noise.

    Returns
    -------
    SonarSweep
        The scans.
    """
    rng = np.random.default_rng(seed)
    k = np.arange(num_scans)
    laps = len(depths_m)
    angle = 2 * np.pi * laps * k / num_scans
    z = np.asarray(depths_m, float)[np.minimum(k * laps // num_scans, laps - 1)]
    origins = np.stack([radius_m * np.cos(angle), 0.8 * radius_m * np.sin(angle), z], axis=1)
    inward = -origins[:, :2] / np.linalg.norm(origins[:, :2], axis=1, keepdims=True)
    elevation = np.deg2rad(tilt_deg + np.linspace(-fov_deg / 2, fov_deg / 2, beams))
    directions = np.concatenate(
        [
            np.repeat(inward, beams, axis=0) * np.tile(np.cos(elevation), num_scans)[:, None],
            np.tile(np.sin(elevation), num_scans)[:, None],
        ],
        axis=1,
    )
    starts = np.repeat(origins, beams, axis=0)
    ranges = scene.cast(starts, directions)
    hit = ranges <= max_range_m
    ranges = np.where(hit, ranges + range_noise_m * rng.standard_normal(ranges.shape), max_range_m + 1.0)
    points = starts + directions * ranges[:, None]
    return SonarSweep(origins.astype(np.float32), points.astype(np.float32), np.repeat(k, beams), hit)
