"""Planning with the confidence-rich map (Agha-mohammadi, Sec. V-A and VI): the inconsistency
of a map's confidence with its error (Eq. 28) and the variance-aware collision cost of a path,
optionally on the map predicted along the path from the most likely future readings
(Eqs. 29-35).

    risk = collision_risk(crm, points)                     # (M,) mean + variance per point
    edge = edge_risk(crm, starts, ends)                    # (E,) summed over each segment's voxels
    cost = path_cost(crm, waypoints)                       # cost.total: J of Eq. 31
    cost = path_cost(crm, waypoints, T_world_sensor=poses, sensor=vj.SonarConfig())
    best, costs = choose_path(crm, [path_a, path_b])       # Eq. 35
    inconsistency(mean, variance, truth)                   # I_c, Eq. 28
"""

from __future__ import annotations

import dataclasses

import numpy as np
import warp as wp

from vogjax.geometry import rigid_poses
from vogjax.kernels import confidence_queries, hashing
from vogjax.maps.blockmap import ray_arguments
from vogjax.maps.confidence import ConfidenceMap, check_walk_length
from vogjax.validation import float_array, within_key_range

# Beams without a likely cause end this far past the range (like vogjax.sensors.world_rays).
_NO_RETURN_SCALE = 1.05


@dataclasses.dataclass(frozen=True)
class PathCost:
    """total: J, the sum of the one-step costs (Eq. 31); per waypoint (W,) float64: step_cost
    = mean + variance of the occupancy level of the voxel the waypoint is in (Eq. 34), and
    those mean and variance (of the predicted map when sensor poses were given)."""

    total: float
    step_cost: np.ndarray
    mean: np.ndarray
    variance: np.ndarray


def inconsistency(mean, variance, truth) -> float:
    """I_c (Eq. 28): sum over voxels of max(0, |mean - truth| - 2 sqrt(variance)), the part of the
    error the map's own confidence does not cover. mean, variance, truth: (V,) arrays (truth 0
    or 1, or an occupancy level). For a log-odds map pass its probability and p (1 - p)."""
    mean = float_array("mean", mean, (-1,), np.float64)
    variance = float_array("variance", variance, (mean.shape[0],), np.float64)
    truth = float_array("truth", truth, (mean.shape[0],), np.float64)
    if np.any(variance < 0):
        raise ValueError("variance must be non-negative")
    return float(np.maximum(np.abs(mean - truth) - 2.0 * np.sqrt(variance), 0.0).sum())


def collision_risk(crm: ConfidenceMap, points) -> np.ndarray:
    """(M,) float64 expected one-step cost at `points` (M,3): E[m + (m - mean)^2] = mean +
    variance of the voxel's occupancy level (Eqs. 33-34). Never-observed voxels cost the prior's
    0.5 + variance, so unknown space is riskier than known free space but safer than walls."""
    _check_map(crm)
    return crm.mean(points).astype(np.float64) + crm.variance(points).astype(np.float64)


def edge_risk(crm: ConfidenceMap, starts, ends) -> np.ndarray:
    """(E,) float64 cost of moving along each straight segment starts (E,3) -> ends (E,3): the
    one-step cost mean + variance (Eq. 34) summed over every voxel the segment passes (Eq. 31
    with one step per voxel). A segment that passes no voxel (zero length, or shorter than a
    millionth of a voxel edge on each side of a plane) costs its start voxel. Fits the planner's
    `risk` hook: `NbvPlanner(..., risk=functools.partial(edge_risk, crm))`."""
    _check_map(crm)
    starts = float_array("starts", starts, (-1, 3), np.float64)
    ends = float_array("ends", ends, (starts.shape[0], 3), np.float64)
    cfg, device, store = crm.config, crm.device, crm.store
    within_key_range("starts", starts, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
    within_key_range("ends", ends, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
    offsets = ends - starts
    lengths = np.linalg.norm(offsets, axis=1)
    check_walk_length("ends", lengths, cfg.voxel_size)
    directions = np.where(lengths[:, None] > 0, offsets / np.maximum(lengths, 1e-300)[:, None], [1.0, 0.0, 0.0])
    out = wp.empty(starts.shape[0], dtype=wp.float64, device=device)
    with crm.reading():
        if starts.shape[0]:
            wp.launch(
                confidence_queries.sum_segment_costs,
                dim=starts.shape[0],
                inputs=[
                    wp.array(starts, dtype=wp.vec3d, device=device),
                    wp.array(directions, dtype=wp.vec3d, device=device),
                    wp.array(lengths, dtype=wp.float64, device=device),
                    np.float64(cfg.voxel_size),
                    np.float64(1.0 / cfg.voxel_size),
                    store.table_keys,
                    store.table_slots,
                    store.layers["mean"],
                    store.layers["variance"],
                    np.float32(cfg.prior_mean),
                    np.float32(cfg.prior_variance),
                ],
                outputs=[out],
                device=device,
            )
        return out.numpy()


def most_likely_ranges(crm: ConfidenceMap, origins, directions, max_range) -> np.ndarray:
    """(R,) float64: the most likely reading along each ray (Eq. 29), taken as the distance to the
    middle of the most probable cause (bounce times reach, Eqs. 14-16); inf where the most
    probable cause is "nothing within max_range" (no return). A reading is that voxel's range
    when the noise is narrower than the gaps between causes; wider noise smears it."""
    _check_map(crm)
    origins, directions, ranges = ray_arguments(origins, directions, max_range)
    cfg, device, store = crm.config, crm.device, crm.store
    within_key_range("origins", origins, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
    check_walk_length("max_range", ranges, cfg.voxel_size)
    within_key_range("max_range", origins + directions * ranges[:, None], cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
    out = wp.empty(origins.shape[0], dtype=wp.float64, device=device)
    with crm.reading():
        if origins.shape[0]:
            wp.launch(
                confidence_queries.find_likely_causes,
                dim=origins.shape[0],
                inputs=[
                    wp.array(origins, dtype=wp.vec3d, device=device),
                    wp.array(directions, dtype=wp.vec3d, device=device),
                    wp.array(ranges, dtype=wp.float64, device=device),
                    np.float64(cfg.voxel_size),
                    np.float64(1.0 / cfg.voxel_size),
                    store.table_keys,
                    store.table_slots,
                    store.layers["mean"],
                    np.float32(cfg.prior_mean),
                ],
                outputs=[out],
                device=device,
            )
        result = out.numpy()
    return np.where(result < 0, np.inf, result)


def path_cost(crm: ConfidenceMap, waypoints, *, T_world_sensor=None, sensor=None) -> PathCost:
    """Cost J of a path through `waypoints` (W,3), world frame (Eq. 31 with Eq. 34 per step).

    Without sensor poses the cost is read off the current map. With `T_world_sensor` (W,4,4),
    the sensor pose at each waypoint, and `sensor` (a vogjax.sensors.RangeSensor or a
    SonarConfig), the map is predicted along the path (Eq. 30): before the cost at waypoint n
    is read, the most likely scan from pose n (Eq. 29, `most_likely_ranges`) is integrated into
    a copy of the map, so a path that looks at what it will pass earns the confidence it will
    gain. `crm` itself never changes.
    """
    _check_map(crm)
    waypoints = float_array("waypoints", waypoints, (-1, 3), np.float64)
    count = waypoints.shape[0]
    if count == 0:  # costing nothing, it would beat every real path
        raise ValueError("waypoints must hold at least one waypoint")
    if T_world_sensor is None:
        if sensor is not None:
            raise ValueError("sensor needs T_world_sensor (the sensor pose at each waypoint)")
        mean = crm.mean(waypoints).astype(np.float64)
        variance = crm.variance(waypoints).astype(np.float64)
    else:
        from vogjax.sensors import as_sensor

        if sensor is None:
            raise ValueError("T_world_sensor needs a sensor (a RangeSensor or SonarConfig)")
        poses = rigid_poses("T_world_sensor", T_world_sensor, count)
        sensor = as_sensor(sensor)
        local = sensor.beam_directions()[:, sensor.beam_directions().shape[1] // 2]
        reach = min(sensor.max_range_m, crm.config.max_range)
        predicted = crm.copy()
        mean, variance = np.empty(count), np.empty(count)
        for n in range(count):
            origin = poses[n, :3, 3]
            directions = local @ poses[n, :3, :3].T
            ranges = most_likely_ranges(predicted, np.tile(origin, (len(directions), 1)), directions, reach)
            ranges = np.where(np.isfinite(ranges), ranges, reach * _NO_RETURN_SCALE + predicted.config.voxel_size)
            predicted.integrate_scan(origin, origin + directions * ranges[:, None])
            mean[n] = predicted.mean(waypoints[n : n + 1])[0]
            variance[n] = predicted.variance(waypoints[n : n + 1])[0]
    step_cost = mean + variance
    return PathCost(float(step_cost.sum()), step_cost, mean, variance)


def choose_path(crm: ConfidenceMap, paths, *, T_world_sensor=None, sensor=None) -> tuple[int, np.ndarray]:
    """Eq. 35: the index of the cheapest of `paths` (a sequence of (W_i,3) waypoint arrays) and
    every path's total cost. T_world_sensor (a sequence of (W_i,4,4), one per path) and
    sensor: the prediction of `path_cost`."""
    paths = list(paths)
    if not paths:
        raise ValueError("paths must hold at least one path")
    if T_world_sensor is not None:
        if isinstance(T_world_sensor, np.ndarray) and T_world_sensor.ndim == 4:
            T_world_sensor = list(T_world_sensor)
        if not isinstance(T_world_sensor, (list, tuple)) or len(T_world_sensor) != len(paths):
            raise ValueError("T_world_sensor must be a sequence of one pose array per path")
    costs = np.array(
        [
            path_cost(
                crm, path, T_world_sensor=None if T_world_sensor is None else T_world_sensor[i], sensor=sensor
            ).total
            for i, path in enumerate(paths)
        ]
    )
    return int(np.argmin(costs)), costs


def _check_map(crm) -> None:
    if not isinstance(crm, ConfidenceMap):
        raise ValueError(f"crm must be a ConfidenceMap, got {type(crm).__name__}")
