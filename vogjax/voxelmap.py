"""VoxelMap: a log-odds occupancy map of hashed voxel blocks, integrated and queried in Warp."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import warp as wp

from vogjax import _warp, parallel
from vogjax.blocks import BLOCK_VOXELS, BlockStore, pack_blocks, unpack_blocks, voxel_offsets
from vogjax.config import MapConfig
from vogjax.io import read_map_file, write_map_file
from vogjax.kernels import hashing, integration, queries
from vogjax.validation import float_array, index_array, positive_range, within_key_range

UNKNOWN = 0
FREE = 1
OCCUPIED = 2

# Scans integrated per pass: each voxel a pass touches carries two bits per scan.
SCANS_PER_PASS = 64
# Bound on the per-pass mark scratch; a pass above it is split in two.
MARK_BUDGET_BYTES = 256 << 20


@dataclasses.dataclass(frozen=True)
class RaycastResult:
    """Per ray: `hit` (R,) bool, an OCCUPIED voxel was met before `max_range`;
    `distance` (R,) float32, where the ray enters that voxel, else `max_range`;
    `num_unknown`, `num_free` (R,) int32, voxels of each state passed before it."""

    hit: np.ndarray
    distance: np.ndarray
    num_unknown: np.ndarray
    num_free: np.ndarray


class VoxelMap:
    """Occupancy map with OctoMap's update rule on dense 8x8x8 blocks in a hash table.

    config: MapConfig (voxel size, sensor model, thresholds, clamping, max range)
    device: Warp device; None picks CUDA when available, else the CPU

    Writes (integration, loading) must not run concurrently with anything else on the same map;
    read-only queries may run from several threads.
    """

    def __init__(self, config: MapConfig | None = None, device=None):
        if config is not None and not isinstance(config, MapConfig):
            raise ValueError(f"config must be a vj.MapConfig, got {type(config).__name__}")
        self.config = config or MapConfig()
        self.device = _warp.resolve_device(device)
        self._store = BlockStore(self.device, {"log_odds": (wp.float32, math.nan)})

    # ---------------------------------------------------------------- integration
    def integrate_scan(self, origin, points) -> None:
        """Integrate one scan: `origin` (3,) sensor position, `points` (N,3) beam endpoints."""
        origin = float_array("origin", origin, (3,))
        points = float_array("points", points, (-1, 3))
        self._check_extent(origin[None], points)
        self._integrate(origin[None], points, np.zeros(points.shape[0], dtype=np.int32))

    def integrate_scans(self, origins, points, scan_index) -> None:
        """Integrate a batch of scans; the same map, bit for bit, as `integrate_scan` in order.

        origins (S,3): sensor position per scan; points (N,3): beam endpoints;
        scan_index (N,): the scan each point belongs to, in [0, S).
        """
        origins = float_array("origins", origins, (-1, 3))
        points = float_array("points", points, (-1, 3))
        scan_index = index_array("scan_index", scan_index, points.shape[0], origins.shape[0])
        self._check_extent(origins, points)
        if np.any(np.diff(scan_index) < 0):
            order = np.argsort(scan_index, kind="stable")
            points, scan_index = points[order], scan_index[order]
        bounds = np.searchsorted(scan_index, np.arange(0, origins.shape[0] + SCANS_PER_PASS,
                                                       SCANS_PER_PASS))
        for first in range(0, origins.shape[0], SCANS_PER_PASS):
            lo, hi = bounds[first // SCANS_PER_PASS], bounds[first // SCANS_PER_PASS + 1]
            last = min(first + SCANS_PER_PASS, origins.shape[0])
            self._integrate(origins[first:last], points[lo:hi], scan_index[lo:hi] - first)

    def _check_extent(self, origins: np.ndarray, points: np.ndarray) -> None:
        within_key_range("origins", origins, self.config.voxel_size, hashing.VOXEL_KEY_LIMIT)
        within_key_range("points", points, self.config.voxel_size, hashing.VOXEL_KEY_LIMIT)

    def _integrate(self, origins: np.ndarray, points: np.ndarray, ray_scan: np.ndarray) -> None:
        """One pass over at most SCANS_PER_PASS scans (ray_scan indexes `origins`)."""
        if points.shape[0] == 0:
            return
        cfg, device, store = self.config, self.device, self._store
        resolution = np.float64(cfg.voxel_size)
        inv_resolution = np.float64(1.0 / cfg.voxel_size)
        lengths = np.linalg.norm(points - origins[ray_scan], axis=1)
        longest = min(float(lengths.max()), cfg.max_range)
        # A segment of length L meets at most 1 + sum_i(|d_i| / B + 1) blocks of edge B.
        max_blocks = int(math.ceil(math.sqrt(3.0) * longest / (hashing.BLOCK_EDGE * cfg.voxel_size))) + 6
        d_origins = wp.array(origins, dtype=wp.vec3f, device=device)
        d_points = wp.array(points, dtype=wp.vec3f, device=device)
        d_scan = wp.array(ray_scan, dtype=wp.int32, device=device)
        num_rays = points.shape[0]
        parts = parallel.num_parts(device, num_rays)

        def beams(lo, hi):
            return [d_origins, d_points[lo:hi], d_scan[lo:hi], np.float64(cfg.max_range),
                    resolution, inv_resolution]

        # 1. the blocks every beam touches, then allocate them
        while True:
            block_keys = wp.full((num_rays, max_blocks), hashing.EMPTY_KEY, dtype=wp.int64, device=device)
            counts = wp.empty(num_rays, dtype=wp.int32, device=device)
            parallel.split_launch(lambda part, lo, hi: wp.launch(
                integration.list_ray_blocks, dim=hi - lo, inputs=beams(lo, hi),
                outputs=[block_keys[lo:hi], counts[lo:hi]], device=device), num_rays, parts)
            most = int(counts.numpy().max())
            if most <= max_blocks:
                break
            max_blocks = most  # round-off made a beam longer than the bound: list again
        keys = block_keys.flatten()
        store.ensure_blocks(keys)

        # 2. number the blocks this pass touches, for a compact mark scratch
        touched_slots = wp.empty(keys.shape[0], dtype=wp.int32, device=device)
        num_touched = wp.zeros(1, dtype=wp.int32, device=device)
        wp.launch(integration.claim_touched_blocks, dim=keys.shape[0],
                  inputs=[keys, store.table_keys, store.table_slots, store.touch_index],
                  outputs=[touched_slots, num_touched], device=device)
        touched = int(num_touched.numpy()[0])
        words = (origins.shape[0] + integration.SCANS_PER_WORD - 1) // integration.SCANS_PER_WORD
        marks_size = touched * BLOCK_VOXELS * words
        if parts * marks_size * 8 > MARK_BUDGET_BYTES and origins.shape[0] > 1:
            wp.launch(integration.release_touched_blocks, dim=touched, inputs=[touched_slots],
                      outputs=[store.touch_index], device=device)
            half = origins.shape[0] // 2
            split = int(np.searchsorted(ray_scan, half))
            self._integrate(origins[:half], points[:split], ray_scan[:split])
            self._integrate(origins[half:], points[split:], ray_scan[split:] - half)
            return

        # 3. mark free/occupied per scan and voxel (each CPU thread into its own copy)
        marks = wp.zeros((parts, marks_size), dtype=wp.uint64, device=device)
        tables = [store.table_keys, store.table_slots, store.touch_index, words]
        parallel.split_launch(lambda part, lo, hi: wp.launch(
            integration.mark_ray_voxels, dim=hi - lo, inputs=[*beams(lo, hi), *tables],
            outputs=[marks[part]], device=device), num_rays, parts)

        # 4. replay the scans in order per voxel
        apply_inputs = [marks, words, cfg.log_hit, cfg.log_miss, cfg.log_clamp_min, cfg.log_clamp_max]
        voxels = touched * BLOCK_VOXELS
        parallel.split_launch(lambda part, lo, hi: wp.launch(
            integration.apply_marks, dim=hi - lo, inputs=[touched_slots, lo, *apply_inputs],
            outputs=[store.layers["log_odds"]], device=device),
            voxels, parallel.num_parts(device, voxels))
        wp.launch(integration.release_touched_blocks, dim=touched, inputs=[touched_slots],
                  outputs=[store.touch_index], device=device)

    # ---------------------------------------------------------------- point queries
    def _lookup(self, points) -> np.ndarray:
        """Stored log-odds at each point, NaN where never observed."""
        points = float_array("points", points, (-1, 3))
        values = wp.empty(points.shape[0], dtype=wp.float32, device=self.device)
        if points.shape[0]:
            wp.launch(queries.lookup_log_odds, dim=points.shape[0],
                      inputs=[wp.array(points, dtype=wp.vec3f, device=self.device),
                              np.float64(1.0 / self.config.voxel_size),
                              self._store.table_keys, self._store.table_slots,
                              self._store.layers["log_odds"]],
                      outputs=[values], device=self.device)
        return values.numpy()

    def log_odds(self, points) -> np.ndarray:
        """(M,) float32 log-odds of the voxels holding `points` (M,3); 0.0 where unknown."""
        return np.nan_to_num(self._lookup(points), nan=0.0)

    def probability(self, points) -> np.ndarray:
        """(M,) float32 occupancy probability; 0.5 where unknown."""
        return probability_from_log_odds(self.log_odds(points))

    def state(self, points) -> np.ndarray:
        """(M,) int8: UNKNOWN (never observed, or between the thresholds), FREE or OCCUPIED."""
        return classify(self._lookup(points), self.config)

    # ---------------------------------------------------------------- ray queries
    def raycast(self, origins, directions, max_range) -> RaycastResult:
        """First OCCUPIED voxel along each ray, within `max_range` (float or (R,)) metres.

        origins (R,3), directions (R,3) (any nonzero length; normalised here).
        """
        origins = float_array("origins", origins, (-1, 3), np.float64)
        directions = float_array("directions", directions, (origins.shape[0], 3), np.float64)
        norms = np.linalg.norm(directions, axis=1)
        if np.any(norms == 0):
            raise ValueError("directions must be nonzero")
        ranges = positive_range("max_range", max_range, origins.shape[0])
        count = origins.shape[0]
        device = self.device
        d = {
            "origins": wp.array(origins, dtype=wp.vec3d, device=device),
            "directions": wp.array(directions / norms[:, None], dtype=wp.vec3d, device=device),
            "ranges": wp.array(ranges, dtype=wp.float64, device=device),
        }
        out = {
            "hit": wp.empty(count, dtype=wp.bool, device=device),
            "distance": wp.empty(count, dtype=wp.float32, device=device),
            "num_unknown": wp.empty(count, dtype=wp.int32, device=device),
            "num_free": wp.empty(count, dtype=wp.int32, device=device),
        }
        cfg, store = self.config, self._store

        def launch(part: int, lo: int, hi: int) -> None:
            wp.launch(queries.cast_rays, dim=hi - lo,
                      inputs=[d["origins"][lo:hi], d["directions"][lo:hi], d["ranges"][lo:hi],
                              np.float64(cfg.voxel_size), np.float64(1.0 / cfg.voxel_size),
                              store.table_keys, store.table_slots, store.layers["log_odds"],
                              cfg.log_occupied, cfg.log_free],
                      outputs=[a[lo:hi] for a in out.values()], device=device)

        parallel.split_launch(launch, count, parallel.num_parts(device, count))
        return RaycastResult(**{name: a.numpy() for name, a in out.items()})

    def line_query(self, starts, ends) -> tuple[np.ndarray, np.ndarray]:
        """Log-odds of every voxel from the voxel of each start to that of its end, inclusive.

        Returns values (R,S) float32 (0.0 where unknown, NaN past each line's end) and
        lengths (R,) int32, the number of voxels of each line.
        """
        starts = float_array("starts", starts, (-1, 3))
        ends = float_array("ends", ends, (starts.shape[0], 3))
        self._check_extent(starts, ends)
        count, device = starts.shape[0], self.device
        if count == 0:
            return np.zeros((0, 0), np.float32), np.zeros(0, np.int32)
        resolution = np.float64(self.config.voxel_size)
        inv_resolution = np.float64(1.0 / self.config.voxel_size)
        d_starts = wp.array(starts, dtype=wp.vec3f, device=device)
        d_ends = wp.array(ends, dtype=wp.vec3f, device=device)
        lengths = wp.empty(count, dtype=wp.int32, device=device)
        wp.launch(queries.count_line_voxels, dim=count,
                  inputs=[d_starts, d_ends, resolution, inv_resolution], outputs=[lengths],
                  device=device)
        lengths_host = lengths.numpy()
        values = wp.full((count, int(lengths_host.max())), math.nan, dtype=wp.float32, device=device)
        wp.launch(queries.fill_line_values, dim=count,
                  inputs=[d_starts, d_ends, resolution, inv_resolution, self._store.table_keys,
                          self._store.table_slots, self._store.layers["log_odds"]],
                  outputs=[values], device=device)
        return values.numpy(), lengths_host

    # ---------------------------------------------------------------- contents
    def voxels(self) -> tuple[np.ndarray, np.ndarray]:
        """Observed voxels: centres (K,3) float64 and log-odds (K,) float32, sorted by voxel key."""
        keys, layers = self._store.host_blocks()
        values = layers["log_odds"]
        block_index, local = np.nonzero(~np.isnan(values))
        voxel = unpack_blocks(keys)[block_index] * hashing.BLOCK_EDGE + voxel_offsets()[local]
        return (voxel + 0.5) * self.config.voxel_size, values[block_index, local]

    @property
    def num_blocks(self) -> int:
        return self._store.num_blocks

    def memory_bytes(self) -> int:
        """Bytes of device memory the map holds (table, block pool, per-block scratch)."""
        return self._store.memory_bytes()

    def __repr__(self) -> str:
        return (f"VoxelMap(voxel_size={self.config.voxel_size}, blocks={self.num_blocks}, "
                f"device={self.device}, memory={self.memory_bytes() / 2**20:.1f} MiB)")

    # ---------------------------------------------------------------- files
    def save(self, path) -> None:
        """Write the map (config included) to one file, atomically."""
        keys, layers = self._store.host_blocks()
        write_map_file(path, "VoxelMap", {"config": self.config.to_dict()},
                       {"block_keys": keys, "log_odds": layers["log_odds"]})

    @classmethod
    def load(cls, path, device=None) -> "VoxelMap":
        metadata, arrays = read_map_file(path, "VoxelMap")
        try:
            config = MapConfig.from_dict(metadata["config"])
            keys, values = arrays["block_keys"], arrays["log_odds"]
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"path {str(path)!r} has invalid map contents: {error}") from None
        if keys.dtype != np.int64 or values.dtype != np.float32 or \
                values.shape != (keys.shape[0], BLOCK_VOXELS) or len(np.unique(keys)) != len(keys):
            raise ValueError(f"path {str(path)!r} has invalid map contents")
        vmap = cls(config, device)
        vmap._store = BlockStore.from_host(vmap.device, vmap._store.layer_specs, keys,
                                           {"log_odds": values})
        return vmap


def probability_from_log_odds(log_odds: np.ndarray) -> np.ndarray:
    return (1.0 - 1.0 / (1.0 + np.exp(log_odds.astype(np.float64)))).astype(np.float32)


def classify(values: np.ndarray, config: MapConfig) -> np.ndarray:
    """States of stored log-odds values (NaN: never observed)."""
    state = np.full(values.shape, UNKNOWN, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        state[values >= config.log_occupied] = OCCUPIED
        state[values <= config.log_free] = FREE
    return state
