"""Tables a run's report folder holds beside the map."""

from __future__ import annotations

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


def save_loop_closures(result, path) -> None:
    """CSV: per accepted loop closure the submaps i and k, the constraint's x, y, z, yaw
    (T_i_k), its fitness and how many directions it constrains."""
    rows = [
        (
            c.i,
            c.k,
            *c.T_i_k[:3, 3],
            yaw_pitch_roll(c.T_i_k[:3, :3])[0],
            c.fitness,
            6 if c.basis is None else c.basis.shape[1],
        )
        for c in result.loop_closures
    ]
    np.savetxt(
        path,
        np.array(rows).reshape(-1, 8),
        delimiter=",",
        header="i,k,x,y,z,yaw,fitness,directions",
        comments="",
        fmt=["%d", "%d", "%.6f", "%.6f", "%.6f", "%.6f", "%.6g", "%d"],
    )


def save_tum_trajectories(result, folder) -> None:
    """navigation.tum, optimized.tum and (with ground truth) truth.tum: every scan's pose in
    TUM's format, for evo."""
    for name in ("navigation", "optimized", "truth"):
        poses = result.scan_poses(name)
        if poses is not None:
            save_tum(folder / f"{name}.tum", result.scan_time_s, poses)
