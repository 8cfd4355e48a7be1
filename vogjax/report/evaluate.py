"""A pipeline run scored against its scene's ground truth."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from vogjax.maps import OCCUPIED, UNKNOWN
from vogjax.maps.confidence_cost import inconsistency
from vogjax.report.metrics import misclassified, reconstruction_rmse, roc
from vogjax.scenes import FREE
from vogjax.scenes import OCCUPIED as TRUE_OCCUPIED

if TYPE_CHECKING:
    from vogjax.pipeline import Result
    from vogjax.report.metrics import Roc
    from vogjax.scenes import Scene


def evaluate_run(result: Result, scene: Scene, surface_points: int = 50_000) -> tuple[dict, dict[str, Roc]]:
    """Score a pipeline run's maps against its scene's ground truth.

    Maps are scored over the voxels of the truth (water or surface) that the online map or the
    standard map observed.

    Parameters
    ----------
    result : Result
        A pipeline run (`vj.pipeline.run`).
    scene : Scene
        The scene the run was recorded in (its ground-truth occupancy and surface).
    surface_points : int, optional
        Points sampled on the true surface for the reconstruction RMSE.

    Returns
    -------
    metrics : dict
        ``auc``: AUC for the online global map, the virtual map at the optimised poses, a full
        merge, the standard map, the confidence-rich map (if built) and (with true poses)
        ``true_pose``, the same submaps built and placed by the truth, and ``rigid_truth``, the
        pipeline's own submaps at their rigid truths (one good placement of these rigid,
        navigation-bent submaps). ``auc_aligned``: the online, virtual and full-merge maps
        registered to the truth by the best x-y-yaw fit of the optimised base poses
        (`Result.gauge_alignment`), and ``true_pose`` and ``rigid_truth`` as they are, over the
        voxels the registered online map or the standard map observed (empty without truth, or
        when those voxels hold one class only). ``auc_vs_reference``: the same maps scored
        against the true-pose map's states instead of the mesh. ``rmse_m``: reconstruction RMSE
        (metres, None when not measurable) of the standard map and of the virtual map without
        and with loop closures. ``confidence_map``: the confidence-rich map's mean error and
        inconsistency per voxel beside the standard map's (empty without one). ``agreement``:
        `misclassified` of the online map against the full merge. ``evaluated_voxels``: how many
        voxels were scored.
    curves : dict of str to Roc
        The ROC curves by map name (for plots), the registered online map's among them.
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
    standard_seen = maps["standard"].log_odds(centres) != 0 if "standard" in maps else np.zeros(len(centres), bool)
    observed = (maps["online"].log_odds(centres) != 0) | standard_seen  # 0.0: never observed
    all_centres, all_occupied = centres, occupied
    centres, occupied = centres[observed], occupied[observed]
    if result.truth_merge is not None:
        maps["true_pose"] = result.truth_merge
    if result.rigid_truth_merge is not None:
        maps["rigid_truth"] = result.rigid_truth_merge
    # an ROC needs both kinds among the observed voxels (a coarse map may observe no free one):
    # without, the AUCs are undefined (null), not an error after all the mapping
    scorable = bool(occupied.any() and not occupied.all())
    curves = {name: roc(m.probability(centres), occupied) for name, m in maps.items()} if scorable else {}
    confidence = {}
    if result.confidence_map is not None and scorable:  # Agha-mohammadi's map beside the standard one
        crm = result.confidence_map
        mean, variance = crm.mean(centres), crm.variance(centres)
        curves["confidence"] = roc(mean, occupied)
        truth_level = occupied.astype(np.float64)
        confidence = {
            "mean_error": float(np.mean(np.abs(mean - truth_level))),
            "inconsistency_per_voxel": inconsistency(mean, variance, truth_level) / len(centres),
        }
        if "standard" in maps:
            p = maps["standard"].probability(centres).astype(np.float64)
            confidence["standard_mean_error"] = float(np.mean(np.abs(p - truth_level)))
            confidence["standard_inconsistency_per_voxel"] = inconsistency(p, p * (1 - p), truth_level) / len(centres)
    # registered to the truth as the thesis registers its reconstructions: each SLAM map read
    # where the best x-y-yaw fit of the optimised base poses to the true ones puts it, so the
    # anchor's drift (unobservable to the graph) is taken out and what is left is the shape
    aligned, aligned_online = {}, None
    T = result.gauge_alignment()
    if T is not None:
        # T^-1 applied: where each truth voxel sits in the maps; scored over the truth voxels
        # the registered online map or the standard map observed
        sampled = (all_centres - T[:3, 3]) @ T[:3, :3]
        seen = (maps["online"].log_odds(sampled) != 0) | standard_seen
        labels = all_occupied[seen]
        if labels.any() and not labels.all():
            aligned_online = roc(maps["online"].probability(sampled[seen]), labels)
            aligned = {"online": aligned_online.auc}
            aligned.update(
                {name: roc(maps[name].probability(sampled[seen]), labels).auc for name in ("virtual", "full_merge")}
            )
            # the maps already in the true frame, over the same voxels where they are
            aligned.update(
                {
                    name: roc(maps[name].probability(all_centres[seen]), labels).auc
                    for name in ("true_pose", "rigid_truth")
                    if name in maps
                }
            )
    # against the map this sensor gives from true poses (as the thesis registers against a
    # true-odometry reconstruction): the discretisation of the surface cancels out
    vs_reference = {}
    if result.truth_merge is not None:
        state = result.truth_merge.state(centres)
        known = state != UNKNOWN
        labels = state[known] == OCCUPIED
        if labels.any() and not labels.all():
            vs_reference = {
                name: roc(m.probability(centres[known]), labels).auc for name, m in maps.items() if name != "true_pose"
            }
    surface = scene.surface_points(surface_points)

    def occupied_centres(m):
        points, values = m.voxels()
        return points[values >= cfg.log_occupied]

    rmse = {
        "without_loop_closures": reconstruction_rmse(occupied_centres(without), surface),
        "with_loop_closures": reconstruction_rmse(occupied_centres(result.global_map), surface),
    }
    if "standard" in maps:
        rmse["standard"] = reconstruction_rmse(occupied_centres(maps["standard"]), surface)
    metrics = {
        "auc": {name: c.auc for name, c in curves.items()} if scorable else dict.fromkeys(maps, float("nan")),
        "auc_aligned": aligned,
        "auc_vs_reference": vs_reference,
        "rmse_m": rmse,
        "confidence_map": confidence,
        "agreement": _agreement(result.global_map, full_merge, cfg.voxel_size),
        "evaluated_voxels": int(len(centres)),
    }
    if aligned_online is not None:  # for the ROC figure, beside the maps as they stand
        curves["online, registered to the truth"] = aligned_online
    return metrics, curves


def _agreement(online, merged, voxel_size: float) -> dict[str, int]:
    """`misclassified` of the online map against the full merge over every voxel either map
    observed (not only the truth's: a disagreement outside the scene's box counts too)."""
    keys = [np.floor(m.voxels()[0] / voxel_size).astype(np.int64) for m in (online, merged)]
    centres = (np.unique(np.concatenate(keys), axis=0) + 0.5) * voxel_size
    return misclassified(online.state(centres), merged.state(centres))
