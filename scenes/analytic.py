"""A small analytic underwater scene and a profiling-sonar sweep over it, in NumPy.

The scene is a pier: a flat seabed, vertical piles (cylinders) and a moored hull (a box). Ray
intersections are closed-form, so it doubles as ground truth in tests and as the data of
`vogjax demo` and the benchmarks without any mesh or download.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class AnalyticScene:
    """seabed_z_m: height of the seabed plane
    piles: (P,4) x_m, y_m, radius_m, top_z_m of vertical cylinders standing on the seabed
    boxes: (B,6) min xyz, max xyz of axis-aligned boxes, metres
    bounds: (2,3) the region worth mapping, metres
    """

    seabed_z_m: float
    piles: np.ndarray
    boxes: np.ndarray
    bounds: np.ndarray

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Distance to the first surface along each unit direction (R,), inf where none."""
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
    """A 16 x 12 m pier: two rows of slanted-spaced piles and a hull beside them."""
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
    """Scans of a profiling sonar: origins (S,3), endpoints (S*B,3), scan_index (S*B,),
    hit (S*B,) whether the beam returned within max_range (misses end past it, so they
    clear free space up to max_range and mark nothing occupied)."""

    origins: np.ndarray
    points: np.ndarray
    scan_index: np.ndarray
    hit: np.ndarray


def orbit_sweep(
    scene: AnalyticScene,
    num_scans: int,
    beams: int = 96,
    fov_deg: float = 29.0,
    max_range_m: float = 11.0,
    radius_m: float = 8.5,
    depths_m=(3.5, 2.5),
    tilt_deg: float = -25.0,
    range_noise_m: float = 0.0,
    seed: int = 0,
) -> SonarSweep:
    """Orbit the scene at a few depths, the sonar's vertical fan looking at the centre."""
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
