"""Brute-force NumPy reference of the confidence-rich map, for small worlds.

Written from the paper's equations, independently of the Warp kernels: the cone comes from
intersecting each beam with every voxel boundary plane (no stepping), and the likelihood of a
reading as a function of one voxel's level is summed over all causes directly (Eq. 19 with that
voxel's bounce probability set to the level, O(n^2) per beam), in float64.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import erfc

NOISE_CUTOFF = 8.0
SHORT_CHORD_SIGMAS = 1e-3
# A voxel is in a beam's cone when the beam spends more than this many voxel edges in it: not one
# it only touches at an edge or a corner, which rounding gives a chord of ~1e-16 m.
MIN_CHORD_EDGES = 1e-6


def beam(origin, point, cfg):
    """Float64 geometry of one beam from float32 inputs: start, unit direction, range, cone
    length, whether it returned."""
    start = np.asarray(origin, np.float32).astype(np.float64)
    offset = np.asarray(point, np.float32).astype(np.float64) - start
    z = float(np.linalg.norm(offset))
    direction = offset / z
    returned = z <= cfg.max_range
    length = min(z + cfg.cone_sigmas * cfg.range_sigma_m, cfg.max_range) if returned else cfg.max_range
    return start, direction, z, length, returned


def cone(start, direction, length, voxel_size):
    """[(voxel key, t_in, t_out)] of every voxel the segment spends more than MIN_CHORD_EDGES
    voxel edges in."""
    ts = [0.0, length]
    for axis in range(3):
        d = direction[axis]
        if d == 0:
            continue
        a, b = start[axis], start[axis] + d * length
        lo, hi = sorted((a, b))
        for k in range(math.floor(lo / voxel_size), math.floor(hi / voxel_size) + 2):
            t = (k * voxel_size - start[axis]) / d
            if 0.0 < t < length:
                ts.append(t)
    ts = sorted(ts)
    out = []
    for t0, t1 in zip(ts[:-1], ts[1:]):
        if t1 - t0 > MIN_CHORD_EDGES * voxel_size:
            mid = start + direction * (0.5 * (t0 + t1))
            key = tuple(int(math.floor(c / voxel_size)) for c in mid)
            if out and out[-1][0] == key:
                out[-1] = (key, out[-1][1], t1)
            else:
                out.append((key, t0, t1))
    return out


def _phi(u):
    """Standard normal CDF with the noise cut off beyond NOISE_CUTOFF sigma."""
    if u <= -NOISE_CUTOFF:
        return 0.0
    if u >= NOISE_CUTOFF:
        return 1.0
    return 0.5 * erfc(-u / math.sqrt(2.0))


def _density(u, sigma):
    return 0.0 if abs(u) >= NOISE_CUTOFF else math.exp(-0.5 * u * u) / (sigma * math.sqrt(2 * math.pi))


def likelihood(z, returned, key, t_in, t_out, start, cfg):
    """p(reading | voxel `key` caused it): its reading spread over the chord [t_in, t_out], or
    at the distance of its centre (cause_range "centre")."""
    sigma = cfg.range_sigma_m
    if cfg.cause_range == "centre":
        t_cause = float(np.linalg.norm((np.array(key) + 0.5) * cfg.voxel_size - start))
        return _density((z - t_cause) / sigma, sigma) if returned else 1.0 - _phi((cfg.max_range - t_cause) / sigma)
    if not returned:
        return 1.0 - _phi((cfg.max_range - 0.5 * (t_in + t_out)) / sigma)
    length = t_out - t_in
    if length < SHORT_CHORD_SIGMAS * sigma:
        return _density((z - 0.5 * (t_in + t_out)) / sigma, sigma)
    return (_phi((z - t_in) / sigma) - _phi((z - t_out) / sigma)) / length


def reading_likelihood(bounce, L, returned, cfg):
    """p(reading | bounce probabilities along the cone), Eq. 19 plus the cause at infinity and
    spurious readings; `bounce` (..., n) may carry leading axes."""
    passing = np.cumprod(np.concatenate([np.ones(bounce.shape[:-1] + (1,)), 1.0 - bounce], axis=-1), axis=-1)
    causes = bounce * passing[..., :-1]
    total = causes @ L + (0.0 if returned else passing[..., -1])
    spurious = cfg.spurious_probability / cfg.max_range if returned else 0.0
    return (1.0 - cfg.spurious_probability) * total + spurious


class ReferenceCrm:
    """cells: voxel key -> float64 distribution over cfg.bin_centres."""

    def __init__(self, cfg):
        self.cfg = cfg
        self.levels = cfg.bin_centres.astype(np.float64)
        self.cells: dict = {}

    def prior(self):
        return np.full(self.cfg.num_bins, 1.0 / self.cfg.num_bins)

    def mean_of(self, key):
        b = self.cells.get(key)
        return 0.5 if b is None else float(b @ self.levels)

    def integrate_scan(self, origin, points):
        cfg = self.cfg
        before = {}
        factors = []  # (key, f(levels)) in beam order
        for point in np.asarray(points, np.float32):
            start, direction, z, length, returned = beam(origin, point, cfg)
            voxels = cone(start, direction, length, cfg.voxel_size)
            if not voxels:
                continue
            for key, _, _ in voxels:
                before.setdefault(key, self.mean_of(key))
            means = np.array([before[key] for key, _, _ in voxels])
            L = np.array([likelihood(z, returned, key, t0, t1, start, cfg) for key, t0, t1 in voxels])
            for i, (key, _, _) in enumerate(voxels):
                bounce = np.tile(means, (len(self.levels), 1))
                bounce[:, i] = self.levels
                f = reading_likelihood(bounce, L, returned, cfg)
                factors.append((key, f / f.max() if f.max() > 0 else np.ones_like(f)))
        for key, f in factors:
            self.cells[key] = self.cells.get(key, self.prior()) * f
        for key in {key for key, _ in factors}:
            b = self.cells[key]
            b = np.maximum(b / b.sum(), cfg.bin_floor)
            self.cells[key] = b / b.sum()

    def moments(self, key):
        b = self.cells.get(key, self.prior())
        mean = float(b @ self.levels)
        return mean, float(b @ (self.levels - mean) ** 2)
