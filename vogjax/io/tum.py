"""Trajectories in the TUM RGB-D format, which evo (`evo_traj tum`, `evo_ape tum`) and most SLAM
tools read: one line per pose, `timestamp tx ty tz qx qy qz qw` (seconds, metres, a unit
quaternion with its scalar last), space-separated, `#` comments.

    vogjax.io.tum.save_tum("optimized.tum", result.scan_time_s, result.scan_poses("optimized"))
"""

from __future__ import annotations

from os import PathLike
from pathlib import Path

import numpy as np
import numpy.typing as npt

from vogjax.geometry import quaternions_from_rotations, rigid_poses, rotations_from_quaternions
from vogjax.io.atomic import AtomicPath
from vogjax.validation import real_array


def save_tum(path: str | PathLike, times_s: npt.ArrayLike, poses: npt.ArrayLike, comment: str = "") -> None:
    """Write a trajectory as a TUM file, published atomically.

    Quaternions are written with w >= 0 (one sign per rotation); times with 9 decimals, the
    other columns with 9 significant digits.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced if it exists).
    times_s : (N,) array_like of float
        Time of each pose, seconds: finite and strictly increasing.
    poses : (N, 4, 4) array_like of float
        Rigid poses ``T_world_body``.
    comment : str, optional
        A line added to the `#` header after the column names.

    Raises
    ------
    ValueError
        If `times_s` is not finite and strictly increasing, `poses` are not N rigid transforms,
        or `path` cannot be written.
    """
    times = real_array("times_s", times_s)
    if times.ndim != 1 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError("times_s must be a finite, strictly increasing 1-D array")
    poses = rigid_poses("poses", poses, len(times))
    q = quaternions_from_rotations(poses[:, :3, :3])  # w, x, y, z
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)  # one sign per rotation: w >= 0
    table = np.column_stack([times, poses[:, :3, 3], q[:, 1:], q[:, :1]])
    header = "timestamp tx ty tz qx qy qz qw" + (f"\n{comment}" if comment else "")
    with AtomicPath(Path(path)) as temporary:
        np.savetxt(temporary, table, fmt=["%.9f"] + ["%.9g"] * 7, header=header, comments="# ")


def load_tum(path: str | PathLike) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Read a TUM trajectory file.

    Parameters
    ----------
    path : str or os.PathLike
        A TUM file: lines of ``timestamp tx ty tz qx qy qz qw``, `#` comments.

    Returns
    -------
    times_s : (N,) ndarray of float64
        Time of each pose, seconds.
    poses : (N, 4, 4) ndarray of float64
        The poses ``T_world_body``.

    Raises
    ------
    ValueError
        If the file cannot be read, a line is not 8 finite numbers, timestamps do not strictly
        increase, or a quaternion's norm is off 1 by 1e-3 or more (naming the pose).
    """
    try:
        table = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as error:
        raise ValueError(f"path {str(path)!r} is not a readable TUM trajectory: {error}") from None
    if table.shape[1:] != (8,) or not np.all(np.isfinite(table)):
        raise ValueError(f"path {str(path)!r} is not a TUM trajectory (8 finite numbers per line)")
    if np.any(np.diff(table[:, 0]) <= 0):
        line = int(np.argmax(np.diff(table[:, 0]) <= 0)) + 2
        raise ValueError(f"path {str(path)!r}: timestamps must increase (pose {line} does not)")
    norms = np.linalg.norm(table[:, 4:], axis=1)
    if not np.all(np.abs(norms - 1.0) < 1e-3):  # written with 9 digits, a unit quaternion is within 1e-8
        line = int(np.argmax(np.abs(norms - 1.0) >= 1e-3)) + 1
        raise ValueError(
            f"path {str(path)!r}: pose {line} has a quaternion of norm {norms[line - 1]:.6g}, not a unit quaternion"
        )
    poses = np.tile(np.eye(4), (len(table), 1, 1))
    poses[:, :3, :3] = rotations_from_quaternions(table[:, [7, 4, 5, 6]])
    poses[:, :3, 3] = table[:, 1:4]
    return table[:, 0], poses
