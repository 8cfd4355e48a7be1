"""VoxelMap: a log-odds occupancy map of hashed voxel blocks, integrated and queried in Warp."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from vogjax.maps import parallel
from vogjax.maps.blockmap import BlockMap
from vogjax.maps.blocks import BLOCK_VOXELS, BlockStore
from vogjax.config import MapConfig
from vogjax.io import read_map_file, write_map_file
from vogjax.kernels import hashing, integration
from vogjax.validation import float_array, index_array

# Scans integrated per pass: each voxel a pass touches carries two bits per scan.
SCANS_PER_PASS = 64
# Bound on the per-pass mark scratch; a pass above it is split in two.
MARK_BUDGET_BYTES = 256 << 20


class VoxelMap(BlockMap):
    """Occupancy map with OctoMap's update rule on dense 8x8x8 blocks in a hash table.

    config: MapConfig (voxel size, sensor model, thresholds, clamping, max range)
    device: Warp device; None picks CUDA when available, else the CPU

    Queries may run from several threads; integration waits for them and holds them off.
    """

    def __init__(self, config: MapConfig | None = None, device=None):
        super().__init__(config, device, layers={})
        self.revision = 0  # counts integrations, so derived data (bounds, clouds) knows it is stale

    # ---------------------------------------------------------------- integration
    def integrate_scan(self, origin, points) -> None:
        """Integrate one scan: `origin` (3,) sensor position, `points` (N,3) beam endpoints."""
        origin = float_array("origin", origin, (3,))
        points = float_array("points", points, (-1, 3))
        self._check_extent(origin[None], points)
        with self._lock.writing():
            self._integrate(origin[None], points, np.zeros(points.shape[0], dtype=np.int32))
            self.revision += 1

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
        with self._lock.writing():
            for first in range(0, origins.shape[0], SCANS_PER_PASS):
                lo, hi = bounds[first // SCANS_PER_PASS], bounds[first // SCANS_PER_PASS + 1]
                last = min(first + SCANS_PER_PASS, origins.shape[0])
                self._integrate(origins[first:last], points[lo:hi], scan_index[lo:hi] - first)
            self.revision += 1

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

    # ---------------------------------------------------------------- files
    def save(self, path) -> None:
        """Write the map (config included) to one file, atomically."""
        with self._lock.reading():
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


