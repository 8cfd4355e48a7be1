"""Launching the view-gain kernel (kernels/view_gain.py): voxels first seen per group of views.

Each group's hash set gets a segment sized from a guess (a fan's rays share most voxels near
the sensor, so the distinct voxels are far fewer than the voxels its rays cross). A set whose
insertions probe too long is counted again in a second pass, in a set twice the size of every
voxel its rays cross, which cannot fill up. Counts are exact either way. A caller may count
only some states (the planner: the unknown voxels), whose voxels alone go into the sets.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.kernels import hashing
from vogjax.kernels import view_gain as kernels
from vogjax.maps import parallel
from vogjax.maps.blockmap import FREE, OCCUPIED, UNKNOWN
from vogjax.planner.source import Source
from vogjax.sensors import RangeSensor
from vogjax.validation import within_key_range

# Hash-set entries allocated per launch: 64 MiB on the CPU, 1 GiB on a GPU.
TABLE_BUDGET = {"cpu": 8 << 20, "cuda": 128 << 20}
# First pass: a set for a quarter of the voxels the rays cross (a fan shares most), and
# insertions give up after this many probes.
FIRST_GUESS = 4
FIRST_PROBES = 64
# The states a view's voxels are counted by, as the counts' columns: unknown, free, occupied.
ALL_STATES = (UNKNOWN, FREE, OCCUPIED)


def group_counts(
    source: Source,
    poses: np.ndarray,
    groups: np.ndarray,
    num_groups: int,
    sensor: RangeSensor,
    max_range: float,
    region,
    frontier: bool = False,
    states: tuple[int, ...] = ALL_STATES,
) -> tuple[np.ndarray, int]:
    """Voxels of each state (unknown, free, occupied) first seen by each group of views, and of
    the unknown ones those on the frontier (a FREE face neighbour; counted only with
    `frontier`, else 0): poses (V,4,4) sorted by their group (V,) in [0, num_groups). Only
    the `states` listed are counted: the others' columns hold -1 (not counted, never a zero
    that reads as none seen). Returns (num_groups, 4) int64 and the rays cast."""
    directions = sensor.beam_directions().reshape(-1, 3).astype(np.float64)
    if not states or not set(states) <= set(ALL_STATES):
        raise ValueError(f"states must be a non-empty subset of {ALL_STATES}, got {states!r}")
    mask = sum(1 << int(state) for state in set(states))
    if len(poses) == 0:
        return _uncounted(np.zeros((num_groups, 4), np.int64), states), 0
    groups = np.asarray(groups, np.int64)
    if np.any(np.diff(groups) < 0):
        raise ValueError("groups must be sorted")
    s = source.config.voxel_size
    if max_range > MAX_RANGE_VOXELS * s:  # as for a map's beams: rays of bounded cost
        raise ValueError(
            f"max_range_m: {max_range:g} m is more than {MAX_RANGE_VOXELS} voxels of "
            f"{s:g} m, the longest ray a view casts"
        )
    origins = np.ascontiguousarray(poses[:, :3, 3])
    within_key_range("T_world_sensor", np.abs(origins) + max_range, s, hashing.VOXEL_KEY_LIMIT)
    # voxels each view's rays cross, at most (sizes the sets only: counts are exact either way);
    # a batched matmul and in-place steps, as this runs once per round of the planner's tree
    steps = directions @ poses[:, :3, :3].transpose(0, 2, 1)
    steps *= max_range
    steps += origins[:, None, :]
    steps /= s
    np.floor(steps, out=steps)
    steps -= np.floor(origins / s)[:, None, :]
    crossed = np.abs(steps, out=steps).sum(axis=(1, 2)) + 3 * len(directions)
    bound = np.bincount(groups, weights=crossed, minlength=num_groups)
    first_view = np.searchsorted(groups, np.arange(num_groups))
    anchors = np.floor(origins[np.minimum(first_view, len(origins) - 1)] / s).astype(np.int64)
    reach = np.abs(np.floor(origins / s) - anchors[groups]).max(initial=0) + max_range / s + 2
    if reach >= kernels.OFFSET_LIMIT:
        raise ValueError("max_range_m: views of one group reach too far for the voxel size")
    counts, overflowed = _launch(
        source,
        poses,
        groups,
        anchors,
        directions,
        sensor.min_range_m,
        max_range,
        region,
        _pow2(np.maximum(bound / FIRST_GUESS, 32)),
        FIRST_PROBES,
        frontier,
        mask,
    )
    retry = np.flatnonzero(overflowed)
    if len(retry):
        views = np.isin(groups, retry)
        renumbered = np.searchsorted(retry, groups[views])
        counts[retry], _ = _launch(
            source,
            poses[views],
            renumbered,
            anchors[retry],
            directions,
            sensor.min_range_m,
            max_range,
            region,
            _pow2(2 * bound[retry] + 1),
            None,
            frontier,
            mask,
        )
    return _uncounted(counts, states), len(poses) * len(directions)


def _uncounted(counts: np.ndarray, states) -> np.ndarray:
    """-1 in the columns of the states not counted (the frontier's too, unknown voxels left out)."""
    for state in set(ALL_STATES) - set(states):
        counts[:, state] = -1
    if UNKNOWN not in states:
        counts[:, 3] = -1
    return counts


def _pow2(values: np.ndarray) -> np.ndarray:
    return (2 ** np.ceil(np.log2(np.maximum(values, 16)))).astype(np.int64)


def _launch(
    source: Source,
    poses,
    groups,
    anchors,
    directions,
    min_range,
    max_range,
    region,
    capacity,
    max_probes,
    frontier,
    mask,
) -> tuple[np.ndarray, np.ndarray]:
    """One pass: counts (G,4) and whether each group's set overflowed (its counts are then void)."""
    device = source.device
    num_groups = len(capacity)
    origins = np.ascontiguousarray(poses[:, :3, 3])
    offsets, candidates = source.candidates(origins - max_range, origins + max_range)
    d = [
        wp.array(origins, dtype=wp.vec3d, device=device),
        wp.array(np.ascontiguousarray(poses[:, :3, :3]), dtype=wp.mat33d, device=device),
        wp.array(groups.astype(np.int32), dtype=wp.int32, device=device),
        wp.array(directions, dtype=wp.vec3d, device=device),
    ]
    region_lo, region_hi = region if region is not None else np.zeros((2, 3))
    d_anchors = wp.array(anchors.astype(np.int32), dtype=wp.vec3i, device=device)
    view_ranges = np.searchsorted(groups, np.arange(num_groups + 1))
    counts = np.zeros((num_groups, 4), np.int64)
    overflowed = np.zeros(num_groups, bool)
    for g0, g1 in _chunks(capacity, TABLE_BUDGET["cuda" if device.is_cuda else "cpu"]):
        table_offsets = np.zeros(num_groups + 1, np.int64)
        table_offsets[g0 : g1 + 1] = np.concatenate([[0], np.cumsum(capacity[g0:g1])])
        tables = wp.full(int(table_offsets[g1]), -1, dtype=wp.int64, device=device)
        d_offsets = wp.array(table_offsets, dtype=wp.int64, device=device)
        out = wp.zeros((num_groups, 4), dtype=wp.int32, device=device)
        overflow = wp.zeros(num_groups, dtype=wp.int32, device=device)
        v0, v1 = int(view_ranges[g0]), int(view_ranges[g1])
        parts = _parts(view_ranges, g0, g1, parallel.num_parts(device, (v1 - v0) * len(directions)))

        def launch(
            part: int, _lo: int, _hi: int, parts=parts, tables=tables, d_offsets=d_offsets, out=out, overflow=overflow
        ) -> None:
            first, last = parts[part]
            wp.launch(
                kernels.count_seen_voxels,
                dim=(last - first, len(directions)),
                inputs=[
                    first,
                    *d,
                    np.float64(max_range),
                    np.float64(min_range),
                    int(region is not None),
                    wp.vec3d(*region_lo),
                    wp.vec3d(*region_hi),
                    source.access,
                    offsets,
                    candidates,
                    d_offsets,
                    d_anchors,
                    tables,
                    -1 if max_probes is None else int(max_probes),
                    int(frontier),
                    int(mask),
                ],
                outputs=[out, overflow],
                device=device,
            )

        parallel.split_launch(launch, len(parts), len(parts))
        counts[g0:g1] = out.numpy()[g0:g1]
        overflowed[g0:g1] = overflow.numpy()[g0:g1] > 0
    if max_probes is None and overflowed.any():
        raise RuntimeError("view gain: a voxel set sized for every crossed voxel overflowed")
    return counts, overflowed


def _chunks(capacity: np.ndarray, budget: int):
    """Consecutive group ranges whose sets fit the budget (a group larger than it goes alone)."""
    first, total = 0, 0
    for g, size in enumerate(capacity):
        if g > first and total + size > budget:
            yield first, g
            first, total = g, 0
        total += int(size)
    if first < len(capacity):
        yield first, len(capacity)


def _parts(view_ranges: np.ndarray, g0: int, g1: int, parts: int) -> list[tuple[int, int]]:
    """View ranges of up to `parts` runs of whole groups with about equal numbers of views (two
    threads never write one group's set or counts: CPU atomics are not atomic across threads)."""
    v0, v1 = int(view_ranges[g0]), int(view_ranges[g1])
    boundaries = view_ranges[g0 : g1 + 1]
    cuts = boundaries[np.searchsorted(boundaries, np.linspace(v0, v1, parts + 1)[1:-1])]
    edges = sorted({v0, v1, *(int(c) for c in cuts)})
    return list(zip(edges[:-1], edges[1:]))
