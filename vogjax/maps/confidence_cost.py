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
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax.geometry import rigid_poses
from vogjax.kernels import confidence_queries, hashing
from vogjax.maps.blockmap import ray_arguments
from vogjax.maps.confidence import ConfidenceMap, check_walk_length
from vogjax.validation import float_array, within_key_range

if TYPE_CHECKING:
    from vogjax.config import SonarConfig
    from vogjax.sensors import RangeSensor

# Beams without a likely cause end this far past the range (like vogjax.sensors.world_rays).
_NO_RETURN_SCALE = 1.05


@dataclasses.dataclass(frozen=True)
class PathCost:
    """The collision cost of a path on a confidence-rich map (Eqs. 31 and 34).

    Attributes
    ----------
    total : float
        J, the sum of the one-step costs (Eq. 31).
    step_cost : (W,) ndarray of float64
        Per waypoint: mean + variance of the occupancy level of the voxel it is in (Eq. 34).
    mean : (W,) ndarray of float64
        That voxel's mean (of the predicted map when sensor poses were given).
    variance : (W,) ndarray of float64
        That voxel's variance (likewise).
    """

    total: float
    step_cost: npt.NDArray[np.float64]
    mean: npt.NDArray[np.float64]
    variance: npt.NDArray[np.float64]


def inconsistency(mean: npt.ArrayLike, variance: npt.ArrayLike, truth: npt.ArrayLike) -> float:
    """I_c (Eq. 28): the part of a map's error its own confidence does not cover.

    For a log-odds map pass its probability p as `mean` and ``p (1 - p)`` as `variance`.

    Parameters
    ----------
    mean : (V,) array_like of float
        The map's mean occupancy per voxel.
    variance : (V,) array_like of float
        Its variance per voxel, non-negative.
    truth : (V,) array_like of float
        The true occupancy: 0 or 1, or an occupancy level.

    Returns
    -------
    float
        ``sum(max(0, |mean - truth| - 2 sqrt(variance)))`` over the voxels.

    Raises
    ------
    ValueError
        If the arrays are not finite, of one length, or `variance` is negative.

    Examples
    --------
    A confident wrong voxel counts in full, an unsure one only beyond two standard deviations:

    >>> round(inconsistency([0.9, 0.5], [0.0, 0.04], [0.0, 1.0]), 6)
    1.0
    """
    mean = float_array("mean", mean, (-1,), np.float64)
    variance = float_array("variance", variance, (mean.shape[0],), np.float64)
    truth = float_array("truth", truth, (mean.shape[0],), np.float64)
    if np.any(variance < 0):
        raise ValueError("variance must be non-negative")
    return float(np.maximum(np.abs(mean - truth) - 2.0 * np.sqrt(variance), 0.0).sum())


def collision_risk(crm: ConfidenceMap, points: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The expected one-step collision cost at points (Eqs. 33-34).

    ``E[m + (m - mean)^2]`` = mean + variance of the voxel's occupancy level. Never-observed
    voxels cost the prior's 0.5 + variance, so unknown space is riskier than known free space
    but safer than walls.

    Parameters
    ----------
    crm : ConfidenceMap
        The map.
    points : (M, 3) array_like of float
        Query points, metres, world frame.

    Returns
    -------
    (M,) ndarray of float64
        The cost at each point.

    Raises
    ------
    ValueError
        If `crm` is not a ConfidenceMap or `points` is not (M, 3) finite numbers.
    """
    _check_map(crm)
    return crm.mean(points).astype(np.float64) + crm.variance(points).astype(np.float64)


def edge_risk(crm: ConfidenceMap, starts: npt.ArrayLike, ends: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The collision cost of moving along straight segments.

    The one-step cost mean + variance (Eq. 34) summed over every voxel the segment passes
    (Eq. 31 with one step per voxel). A segment that passes no voxel (zero length, or shorter
    than a millionth of a voxel edge on each side of a plane) costs its start voxel. Fits the
    planner's `risk` hook: ``NbvPlanner(..., risk=functools.partial(edge_risk, crm))``.

    Parameters
    ----------
    crm : ConfidenceMap
        The map.
    starts : (E, 3) array_like of float
        Segment starts, metres, world frame.
    ends : (E, 3) array_like of float
        Segment ends, metres.

    Returns
    -------
    (E,) ndarray of float64
        The cost of each segment.

    Raises
    ------
    ValueError
        If `crm` is not a ConfidenceMap, the arrays are not (E, 3) finite numbers, lie beyond
        the key range, or a segment is longer than a confidence-map query walks (MAX_LINE_VOXELS
        voxels).
    """
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


def most_likely_ranges(
    crm: ConfidenceMap, origins: npt.ArrayLike, directions: npt.ArrayLike, max_range: float | npt.ArrayLike
) -> npt.NDArray[np.float64]:
    """The most likely reading along each ray (Eq. 29).

    Taken as the distance to the middle of the most probable cause (bounce times reach,
    Eqs. 14-16). A reading is that voxel's range when the noise is narrower than the gaps
    between causes; wider noise smears it.

    Parameters
    ----------
    crm : ConfidenceMap
        The map.
    origins : (R, 3) array_like of float
        Ray origins, metres, world frame.
    directions : (R, 3) array_like of float
        Directions, any nonzero length (normalised here).
    max_range : float or (R,) array_like of float
        The sensor's reach per ray, metres, positive.

    Returns
    -------
    (R,) ndarray of float64
        The most likely range, metres; inf where the most probable cause is "nothing within
        max_range" (no return).

    Raises
    ------
    ValueError
        If `crm` is not a ConfidenceMap, or the rays are refused as `ConfidenceMap.raycast`
        refuses them.
    """
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


def path_cost(
    crm: ConfidenceMap,
    waypoints: npt.ArrayLike,
    *,
    T_world_sensor: npt.ArrayLike | None = None,
    sensor: RangeSensor | SonarConfig | None = None,
) -> PathCost:
    """The collision cost J of a path (Eq. 31 with Eq. 34 per step).

    Without sensor poses the cost is read off the current map. With them the map is predicted
    along the path (Eq. 30): before the cost at waypoint n is read, the most likely scan from
    pose n (Eq. 29, `most_likely_ranges`; one ray per beam) is integrated into a copy of the map,
    so a path that looks at what it will pass earns the confidence it will gain. `crm` itself
    never changes.

    Parameters
    ----------
    crm : ConfidenceMap
        The map.
    waypoints : (W, 3) array_like of float
        The path, metres, world frame; at least one waypoint.
    T_world_sensor : (W, 4, 4) array_like of float or None, optional
        The sensor pose at each waypoint, rigid; given together with `sensor`.
    sensor : RangeSensor or SonarConfig or None, optional
        The sensor whose most likely scans predict the map (its reach capped at the map's
        max_range).

    Returns
    -------
    PathCost
        J and the per-waypoint costs, means and variances.

    Raises
    ------
    ValueError
        If `crm` is not a ConfidenceMap, `waypoints` is empty or not (W, 3) finite numbers, only
        one of `T_world_sensor` and `sensor` is given, the poses are not W rigid transforms, or
        `sensor` is no sensor.
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
        local = sensor.beam_axes()
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


def choose_path(
    crm: ConfidenceMap,
    paths: Sequence[npt.ArrayLike],
    *,
    T_world_sensor: Sequence[npt.ArrayLike] | None = None,
    sensor: RangeSensor | SonarConfig | None = None,
) -> tuple[int, npt.NDArray[np.float64]]:
    """The cheapest of several paths (Eq. 35), each costed by `path_cost`.

    Parameters
    ----------
    crm : ConfidenceMap
        The map.
    paths : sequence of (W_i, 3) array_like of float
        Candidate paths, at least one.
    T_world_sensor : sequence of (W_i, 4, 4) array_like of float or None, optional
        Sensor poses along each path, one array per path (or one (P, W, 4, 4) array), for the
        prediction of `path_cost`.
    sensor : RangeSensor or SonarConfig or None, optional
        The sensor of the prediction.

    Returns
    -------
    best : int
        Index of the cheapest path (the first of equals).
    costs : (P,) ndarray of float64
        Every path's total cost J.

    Raises
    ------
    ValueError
        If `paths` is empty, `T_world_sensor` is not one pose array per path, or a path is
        refused by `path_cost`.
    """
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
