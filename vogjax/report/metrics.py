"""Measures of maps: ROC/AUC of occupancy against ground truth (Sodhi et al., Fig. 10),
reconstruction RMSE after registration (Ho, Table 4.3), and agreement between two maps."""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from vogjax.config import IcpConfig
from vogjax.maps import OCCUPIED
from vogjax.slam import correlative_xyh, icp
from vogjax.slam.icp import MIN_POINTS
from vogjax.validation import real_array


@dataclasses.dataclass(frozen=True)
class Roc:
    """false_positive_rate, true_positive_rate (T,) from the highest threshold down; auc."""

    false_positive_rate: np.ndarray
    true_positive_rate: np.ndarray
    thresholds: np.ndarray
    auc: float


def roc(scores: np.ndarray, occupied: np.ndarray) -> Roc:
    """ROC of `scores` (occupancy probability per voxel) against truth `occupied` (bool).

    Ties share a threshold, so an uninformative map (all 0.5) gets AUC 0.5 exactly. `occupied`
    may also hold numbers that are exactly 0 or 1; NaN scores are refused (they sort anywhere)."""
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
    points: np.ndarray, surface: np.ndarray, config: IcpConfig | None = None, search_radius_m: float = 3.0
) -> np.ndarray:
    """T_surface_points (4, 4) registering `points` to the true `surface` points: a correlative
    x-y-yaw search within `search_radius_m` (a drifted map can sit farther off than ICP
    reaches), then point-to-plane ICP."""
    config = config or IcpConfig(max_correspondence_m=0.5)
    seed = correlative_xyh(points, surface, np.eye(4), search_radius_m, yaw_radius_rad=0.05)
    return icp(points, surface, seed.T_target_source, config=config).T_target_source


def reconstruction_rmse(
    points: np.ndarray, surface: np.ndarray, config: IcpConfig | None = None, search_radius_m: float = 3.0
) -> float | None:
    """RMSE (m) of `points` (a map's occupied voxel centres) to the true `surface` points, after
    registering them to it (`register_to_surface`); None (not measurable) when there are fewer
    points than registration needs (MIN_POINTS, ICP's): a map with next to nothing occupied."""
    if len(points) < MIN_POINTS:
        return None
    T = register_to_surface(points, surface, config, search_radius_m)
    distance, _ = cKDTree(surface).query(points @ T[:3, :3].T + T[:3, 3], workers=-1)
    return float(np.sqrt(np.mean(distance**2)))


def misclassified(states_a: np.ndarray, states_b: np.ndarray) -> dict:
    """How many voxels two maps classify differently, and how many of those are occupied in one."""
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
