"""Measures of maps: ROC/AUC of occupancy against ground truth (Sodhi et al., Fig. 10),
reconstruction RMSE after registration (Ho, Table 4.3), and agreement between two maps."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from vogjax.config import IcpConfig
from vogjax.maps import OCCUPIED
from vogjax.slam import correlative_xyh, icp
from vogjax.slam.icp import MIN_POINTS
from vogjax.validation import float_array, real_array


@dataclasses.dataclass(frozen=True)
class Roc:
    """A receiver operating characteristic curve of occupancy scores against ground truth.

    Points run from the highest threshold down, starting at (0, 0).

    Attributes
    ----------
    false_positive_rate : (T,) ndarray of float64
        Fraction of the free voxels scored at or above each threshold.
    true_positive_rate : (T,) ndarray of float64
        Fraction of the occupied voxels scored at or above each threshold.
    thresholds : (T,) ndarray of float64
        The thresholds, decreasing: inf, then each distinct score.
    auc : float
        Area under the curve (trapezoidal): 1 separates perfectly, 0.5 is chance.
    """

    false_positive_rate: npt.NDArray[np.float64]
    true_positive_rate: npt.NDArray[np.float64]
    thresholds: npt.NDArray[np.float64]
    auc: float


def roc(scores: npt.ArrayLike, occupied: npt.ArrayLike) -> Roc:
    """The ROC curve of occupancy scores against the truth (Sodhi et al., Fig. 10).

    Ties share a threshold, so an uninformative map (all 0.5) gets AUC 0.5 exactly.

    Parameters
    ----------
    scores : (N,) array_like of float
        Occupancy probability (or any score) per voxel; no NaN (it would sort anywhere).
    occupied : (N,) array_like of bool
        Whether each voxel is truly occupied: booleans, or numbers exactly 0 or 1. Both classes
        must occur.

    Returns
    -------
    Roc
        The curve and its AUC.

    Raises
    ------
    ValueError
        If the arrays are not 1-D of one length, `scores` holds NaN, `occupied` holds other
        numbers than 0 and 1, or only one class.

    Examples
    --------
    >>> roc([0.9, 0.8, 0.3, 0.1], [True, False, True, False]).auc
    0.75
    """
    scores = real_array("scores", scores)
    occupied = _labels("occupied", occupied)
    if scores.shape != occupied.shape or scores.ndim != 1:
        raise ValueError("scores and occupied must be 1-D arrays of the same length")
    if np.isnan(scores).any():
        raise ValueError("scores contains NaN values")
    positives, negatives = occupied.sum(), (~occupied).sum()
    if positives == 0 or negatives == 0:
        raise ValueError("occupied must hold both occupied and free voxels")
    order = np.argsort(-scores, kind="stable")
    s, o = scores[order], occupied[order]
    last_of_tie = np.r_[np.flatnonzero(np.diff(s)), len(s) - 1]
    tp = np.cumsum(o)[last_of_tie]
    fp = np.cumsum(~o)[last_of_tie]
    tpr = np.r_[0.0, tp / positives]
    fpr = np.r_[0.0, fp / negatives]
    return Roc(fpr, tpr, np.r_[np.inf, s[last_of_tie]], float(np.trapezoid(tpr, fpr)))


def _labels(name: str, value) -> np.ndarray:
    """Truth labels as bool: booleans, or numbers exactly 0 or 1 (a cast would call 0.5 true)."""
    array = np.asarray(value)
    if array.dtype == np.bool_:
        return array
    array = real_array(name, array)
    if not np.all((array == 0) | (array == 1)):
        raise ValueError(f"{name} must hold booleans (or exactly 0 and 1)")
    return array == 1


def register_to_surface(
    points: npt.ArrayLike, surface: npt.ArrayLike, config: IcpConfig | None = None, search_radius_m: float = 3.0
) -> npt.NDArray[np.float64]:
    """Register a map's points to the true surface.

    A correlative x-y-yaw search within `search_radius_m` (a drifted map can sit farther off
    than ICP reaches), then point-to-plane ICP.

    Parameters
    ----------
    points : (N, 3) array_like of float
        The map's points (occupied voxel centres), metres; at least 3.
    surface : (M, 3) array_like of float
        Points on the true surface, metres.
    config : IcpConfig or None, optional
        The ICP's settings (default: ``IcpConfig(max_correspondence_m=0.5)``).
    search_radius_m : float, optional
        Reach of the correlative search in x and y, metres.

    Returns
    -------
    (4, 4) ndarray of float64
        ``T_surface_points``.

    Raises
    ------
    ValueError
        If `points` or `surface` is not an (N, 3) array of finite points, or holds fewer than 3
        (the message names the argument).
    """
    points = float_array("points", points, (-1, 3), np.float64)
    surface = float_array("surface", surface, (-1, 3), np.float64)
    for name, cloud in (("points", points), ("surface", surface)):
        if len(cloud) < MIN_POINTS:
            raise ValueError(f"{name} must hold at least {MIN_POINTS} points to register, got {len(cloud)}")
    config = config or IcpConfig(max_correspondence_m=0.5)
    seed = correlative_xyh(points, surface, np.eye(4), search_radius_m, yaw_radius_rad=0.05)
    return icp(points, surface, seed.T_target_source, config=config).T_target_source


def reconstruction_rmse(
    points: npt.ArrayLike, surface: npt.ArrayLike, config: IcpConfig | None = None, search_radius_m: float = 3.0
) -> float | None:
    """Reconstruction RMSE of a map's points to the true surface, after registration (Ho, Table 4.3).

    Parameters
    ----------
    points : (N, 3) array_like of float
        The map's occupied voxel centres, metres.
    surface : (M, 3) array_like of float
        Points on the true surface, metres.
    config : IcpConfig or None, optional
        The registration's ICP settings (see `register_to_surface`).
    search_radius_m : float, optional
        Reach of the registration's correlative search, metres.

    Returns
    -------
    float or None
        RMS distance of the registered points to their nearest surface points, metres; None (not
        measurable) when there are fewer points than registration needs (MIN_POINTS, ICP's): a
        map with next to nothing occupied.

    Raises
    ------
    ValueError
        If `points` or `surface` cannot be registered (see `register_to_surface`).
    """
    points = float_array("points", points, (-1, 3), np.float64)
    if len(points) < MIN_POINTS:
        return None
    T = register_to_surface(points, surface, config, search_radius_m)
    distance, _ = cKDTree(surface).query(points @ T[:3, :3].T + T[:3, 3], workers=-1)
    return float(np.sqrt(np.mean(distance**2)))


def misclassified(states_a: npt.ArrayLike, states_b: npt.ArrayLike) -> dict[str, int]:
    """How many voxels two maps classify differently.

    Parameters
    ----------
    states_a, states_b : (N,) array_like of int
        The two maps' states of the same voxels: vj.UNKNOWN, vj.FREE or vj.OCCUPIED.

    Returns
    -------
    dict of str to int
        ``voxels``: N; ``misclassified``: voxels whose states differ; ``occupied_disagreements``:
        those of them that one of the maps calls occupied.

    Raises
    ------
    ValueError
        If the arrays are not 1-D of one length, or not real numbers.
    """
    states_a, states_b = real_array("states_a", states_a), real_array("states_b", states_b)
    if states_a.ndim != 1 or states_a.shape != states_b.shape:
        raise ValueError(
            f"states_a and states_b must be 1-D arrays of the same length, "
            f"got shapes {states_a.shape} and {states_b.shape}"
        )
    differ = states_a != states_b
    return {
        "voxels": int(len(states_a)),
        "misclassified": int(differ.sum()),
        "occupied_disagreements": int((differ & ((states_a == OCCUPIED) | (states_b == OCCUPIED))).sum()),
    }
