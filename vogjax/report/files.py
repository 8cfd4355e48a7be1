"""Tables a run's report folder holds beside the map."""

from __future__ import annotations

import csv

import numpy as np

from vogjax.geometry import yaw_pitch_roll
from vogjax.io.tum import save_tum


def save_trajectories(result, path) -> None:
    """CSV: per submap its first scan and x, y, z, yaw of the navigation, optimised and true base poses."""
    columns = ["submap", "first_scan"]
    rows = [np.arange(len(result.navigation)), result.submap_first_scan]
    for name in ("navigation", "optimized", "truth"):
        poses = getattr(result, name)
        if poses is None or len(poses) != len(result.navigation):
            continue
        columns += [f"{name}_{c}" for c in ("x", "y", "z", "yaw")]
        rows += [poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3], yaw_pitch_roll(poses[:, :3, :3])[..., 0]]
    np.savetxt(
        path,
        np.stack(rows, axis=1),
        delimiter=",",
        header=",".join(columns),
        comments="",
        fmt=["%d", "%d"] + ["%.6f"] * (len(columns) - 2),
    )


LOOP_CLOSURE_COLUMNS = (
    "i",
    "k",
    "verdict",
    "x",
    "y",
    "z",
    "yaw",
    "fitness",
    "directions",
    "value",
    "limit",
    "error_m",
    "error_m_rigid",
)


def save_loop_closures(result, path) -> None:
    """CSV: one row per candidate pair the run judged, accepted closures first.

    Columns: the submaps i and k; verdict ("accepted" or the rejection's reason); the
    alignment's x, y, z, yaw (T_i_k; empty when it stopped before ICP); ICP's fitness (m^2);
    directions constrained (accepted only); value and limit: for a rejection the figure that
    failed and its bound, for a closure its Mahalanobis distance from the graph's estimate and
    nothing (empty when not screened); error_m and error_m_rigid: on runs with ground truth, the
    translation error against the true and the rigid-truth relative pose (m; in the directions
    a closure constrains, all three for a rejection).
    """
    metrics = result.metrics["loop_closures"]
    accepted = metrics.get("errors", [{} for _ in result.loop_closures])
    rows = []

    def number(value, spec):
        return "" if value is None or not np.isfinite(value) else format(value, spec)

    for c, e in zip(result.loop_closures, accepted):
        pose = (*c.T_i_k[:3, 3], yaw_pitch_roll(c.T_i_k[:3, :3])[0])
        directions = 6 if c.basis is None else c.basis.shape[1]
        rows.append(
            [c.i, c.k, "accepted", *(number(v, ".6f") for v in pose), number(c.fitness, ".6g"), directions]
            + [number(c.distance, ".4g"), "", number(e.get("translation_m"), ".6f")]
            + [number(e.get("translation_m_rigid"), ".6f")]
        )
    for r, e in zip(result.rejected, metrics["rejections"]):
        pose = ("",) * 4 if r.T_i_k is None else (*r.T_i_k[:3, 3], yaw_pitch_roll(r.T_i_k[:3, :3])[0])
        rows.append(
            [r.i, r.k, r.reason, *(v if v == "" else number(v, ".6f") for v in pose), number(r.fitness, ".6g"), ""]
            + [number(r.value, ".6g"), number(r.limit, ".6g"), number(e.get("translation_m"), ".6f")]
            + [number(e.get("translation_m_rigid"), ".6f")]
        )
    with open(path, "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(LOOP_CLOSURE_COLUMNS)
        writer.writerows(rows)


def save_tum_trajectories(result, folder) -> None:
    """navigation.tum, optimized.tum, (with ground truth) truth.tum and (with scan matching)
    odometry.tum, the poses as recorded: every scan's pose in TUM's format, for evo."""
    for name in ("navigation", "optimized", "truth", "odometry"):
        poses = result.scan_poses(name)
        if poses is not None:
            save_tum(folder / f"{name}.tum", result.scan_time_s, poses)
