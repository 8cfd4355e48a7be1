"""A pipeline run scored against its scene's ground truth."""

from __future__ import annotations

import numpy as np

from vogjax.report.metrics import misclassified, reconstruction_rmse, roc
from vogjax.scenes import FREE
from vogjax.scenes import OCCUPIED as TRUE_OCCUPIED


def evaluate_run(result, scene, surface_points: int = 50_000) -> tuple[dict, dict]:
    """Measures of a pipeline Result against a Scene's ground truth.

    Returns (metrics, curves): metrics holds `auc` for the online global map, the virtual map at
    the optimised poses, a full merge and the standard map; `rmse_m` for the standard map and
    the virtual map without and with loop closures; `agreement` of the online map with the full
    merge. curves holds the ROC curves (for plots).
    """
    cfg = result.config.map
    truth = scene.occupancy(cfg.voxel_size)
    full_merge, without = result.full_merge, result.navigation_merge
    maps = {"online": result.global_map, "virtual": result.vog, "full_merge": full_merge}
    if result.standard_map is not None:
        maps["standard"] = result.standard_map
    # voxels of the truth (water or surface) that some map observed
    centres = truth.centres(FREE), truth.centres(TRUE_OCCUPIED)
    centres = np.concatenate(centres)
    occupied = np.r_[np.zeros(len(truth.keys(FREE)), bool), np.ones(len(truth.keys(TRUE_OCCUPIED)), bool)]
    observed = np.zeros(len(centres), bool)
    for name in ("online", "standard"):
        if name in maps:
            observed |= maps[name].log_odds(centres) != 0  # 0.0: never observed
    centres, occupied = centres[observed], occupied[observed]
    curves = {name: roc(m.probability(centres), occupied) for name, m in maps.items()}
    surface = scene.surface_points(surface_points)

    def occupied_centres(m):
        points, values = m.voxels()
        return points[values >= cfg.log_occupied]

    rmse = {"without_loop_closures": reconstruction_rmse(occupied_centres(without), surface),
            "with_loop_closures": reconstruction_rmse(occupied_centres(result.global_map), surface)}
    if "standard" in maps:
        rmse["standard"] = reconstruction_rmse(occupied_centres(maps["standard"]), surface)
    metrics = {"auc": {name: c.auc for name, c in curves.items()}, "rmse_m": rmse,
               "agreement": misclassified(result.global_map.state(centres), full_merge.state(centres)),
               "evaluated_voxels": int(len(centres))}
    return metrics, curves
