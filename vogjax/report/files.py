"""Tables a run's report folder holds beside the map."""

from __future__ import annotations

import numpy as np

from vogjax.geometry import yaw_pitch_roll


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
    np.savetxt(path, np.stack(rows, axis=1), delimiter=",", header=",".join(columns), comments="",
               fmt=["%d", "%d"] + ["%.6f"] * (len(columns) - 2))
