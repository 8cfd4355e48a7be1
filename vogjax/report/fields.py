"""What each field of report.json means: the one description the reference page is generated from.

`FIELDS` maps a dotted path to its description; `*` stands for any key at that level (a map's
name, a step's name). A test walks a real report and checks that every field it holds is
described here and that every path described here can occur.
"""

from __future__ import annotations

MAPS = (
    "`online` (the global map kept current by Algorithm 1), `virtual` (the submaps summed at the optimised "
    "poses), `full_merge` (the same submaps merged from scratch), `standard` (one map from navigation poses, "
    "no SLAM), `true_pose` (the same submaps built and placed by the ground truth: the ceiling), "
    "`rigid_truth` (the pipeline's own submaps, bent by the drift inside them, each at its rigid truth), "
    "`confidence` (the confidence-rich map's mean, with `--crm`)"
)

FIELDS: dict[str, str] = {
    "run": "Path of the run file, as given.",
    "scene": "Built-in scene the run was simulated in, or null for runs without one (imported bags).",
    "ground_truth": "`scene` when the run is scored against its scene's ground truth, else why it is not.",
    "scans": "Scans in the run.",
    "duration_s": "Duration of the run from its time stamps, seconds.",
    "submaps": "Submaps the run was cut into.",
    "auc": "Area under the ROC curve of each map's occupancy probability against the ground truth, over the "
    "true water and surface voxels the online or the standard map observed (0.5 is chance; null where a map "
    "has nothing to score).",
    "auc.*": f"One map's AUC: {MAPS}.",
    "auc_aligned": "The same AUCs with the SLAM maps registered to the truth first: each read where the best "
    "x-y-yaw fit of the optimised base poses to the true ones puts it (the anchor's drift, which no loop "
    "closure can observe, taken out).",
    "auc_aligned.*": "One map's registered AUC (`online`, `virtual`, `full_merge`; `true_pose` and "
    "`rigid_truth` scored over the same voxels).",
    "auc_vs_reference": "The maps scored against the true-pose map's states instead of the mesh.",
    "auc_vs_reference.*": "One map's AUC against the true-pose map.",
    "confidence_map": "With `--crm`: the confidence-rich map against the truth ({} without it).",
    "confidence_map.mean_error": "Mean absolute error of the confidence-rich map's mean.",
    "confidence_map.inconsistency_per_voxel": "Agha-mohammadi's inconsistency I_c (Eq. 28) per voxel.",
    "confidence_map.standard_mean_error": "The same error for the standard map's probability.",
    "confidence_map.standard_inconsistency_per_voxel": "I_c per voxel of the standard map, with variance p(1-p).",
    "rmse_m": "Reconstruction error: occupied voxel centres registered to the true surface (correlative "
    "x-y-yaw search, then point-to-plane ICP), then the RMS distance to it, metres; null for a map with "
    "fewer than 3 occupied voxels.",
    "rmse_m.standard": "The standard map (navigation poses, no submaps).",
    "rmse_m.without_loop_closures": "The virtual map at the navigation poses.",
    "rmse_m.with_loop_closures": "The online map.",
    "agreement": "How far the online map is from a full merge of the same submaps.",
    "agreement.voxels": "Voxels compared (observed in either map).",
    "agreement.misclassified": "Voxels whose state differs (0 when every eps of Algorithm 1 is 0).",
    "agreement.occupied_disagreements": "Of those, voxels occupied in one map and not in the other.",
    "trajectory_rmse_m": "RMS position error of the submap base poses against the truth, metres.",
    "trajectory_rmse_m.navigation": "Navigation (dead reckoning) poses; with scan matching on, as it corrected them.",
    "trajectory_rmse_m.odometry": "The odometry as the run recorded it, before scan matching (with scan matching on).",
    "trajectory_rmse_m.optimized": "Poses optimised by the pose graph.",
    "trajectory_rmse_m.rigid_truth": "Each submap's rigid truth (true rotation, the translation that puts "
    "its returns closest to where they truly are) against its base's true pose: how bent the submaps are.",
    "trajectory_rmse_m.optimized_vs_rigid_truth": "Optimised poses against the rigid truths.",
    "trajectory_rmse_m.navigation_aligned": "Navigation after the best rotation about z and x-y shift onto "
    "the truth (the directions the graph cannot observe).",
    "trajectory_rmse_m.optimized_aligned": "Optimised poses after the same alignment.",
    "loop_closures": "Loop closures found and how good they are.",
    "loop_closures.accepted": "Closures accepted into the pose graph.",
    "loop_closures.rejected": "Candidates rejected.",
    "loop_closures.rejected_by_reason": "Rejections counted by the gate that refused them.",
    "loop_closures.rejected_by_reason.*": "Rejections for one reason (`overlap`, `not converged`, `fitness`, "
    "`refinement`, `drift`, `yaw drift` (the yaw, when closures solve it), `inconsistent` (refused by the "
    "pose graph's screen), ...).",
    "loop_closures.precision": "Share of accepted closures within 0.2 m and 1 degree of the truth, in the "
    "directions they constrain.",
    "loop_closures.precision_rigid": "The same against the rigid truths (the bends taken out).",
    "loop_closures.precision_ceiling": "Share of accepted pairs whose rigid truths relate within 0.2 m and 1 "
    "degree of the truth: what a registration recovering every rigid truth exactly would score.",
    "loop_closures.errors": "One entry per accepted closure: submaps `i` and `k`, constrained `directions`, "
    "what the registration measured (`fitness_m2`, the correlative peak's `overlap` and `ambiguity`, the "
    "screen's `distance` in sigmas), and its error against the truth (`translation_m`, `rotation_deg`), the "
    "rigid truths (`*_rigid`) and the rigid truths' own (`*_bend`).",
    "loop_closures.rejections": "One entry per rejected candidate, in the order they were judged: submaps `i` "
    "and `k`, the `reason`, the figure that failed (`value`) and its bound (`limit`), and on runs with ground "
    "truth the error of what the alignment found against the true and the rigid-truth relative pose "
    "(`translation_m`, `translation_m_rigid`; null where the alignment did not run): whether the gate was right.",
    "timing_s": "Where the time went, seconds (kernel compilation excluded).",
    "timing_s.pipeline": "Wall time of the pipeline, without the timing probes.",
    "timing_s.scans_per_s": "Scans mapped per second.",
    "timing_s.real_time_factor": "Duration of the run over the pipeline's wall time.",
    "timing_s.steps": "Seconds per pipeline step; `loop_closure` includes `correlative_search` and `icp`, "
    "`probes` is the timing probes' own time. With SLAM on a second thread (`slam_on_second_thread`) its "
    "steps (`isam2`, `loop_closure`) ran beside the map work, sharing the cores: the steps then sum to "
    "more than the wall time.",
    "timing_s.slam_on_second_thread": "Whether each submap's SLAM step ran on a second thread beside the "
    "map work (`[pipeline] slam_thread`; `auto`: with a CUDA map or two or more usable CPU cores).",
    "timing_s.steps.*": "One step's total seconds.",
    "timing_s.update_per_submap": "Cumulative average map-update time per submap at the end of the run.",
    "timing_s.update_per_submap.online": "Online map: undo/redo plus add.",
    "timing_s.update_per_submap.virtual": "Virtual map: the pose update.",
    "timing_s.update_per_submap.full_merge": "The papers' baseline: add, and a full re-merge at every loop closure.",
    "timing_s.update_per_submap.submaps": "Submaps averaged over.",
    "timing_s.query": "One query of planner rays from observed free space, at the last probe.",
    "timing_s.query.rays": "Rays per query.",
    "timing_s.query.global": "Seconds on the global map.",
    "timing_s.query.virtual": "Seconds on the virtual map.",
    "timing_s.query.submaps": "Submaps at that probe.",
    "timing_s.curves": "The data of both timing figures (Sodhi et al. Figs. 8 and 9), per submap or probe.",
    "timing_s.curves.*": "One curve's values.",
    "timing_s.reapplied_per_submap": "Mean number of submaps Algorithm 1 re-applied per new submap.",
    "timing_s.warm_up": "One-off kernel compilation before the pipeline, reported apart.",
    "fig9": "Sodhi et al.'s Fig. 9: per new submap, the cumulative averages `online_s`, `virtual_s`, "
    "`full_merge_s`, and `reapplied`.",
    "fig9.*": "One series of Fig. 9.",
    "returns": "The returns (beams that hit something) the run's scans held, and those past the map's reach.",
    "returns.total": "Returns read.",
    "returns.beyond_reach": "Returns farther than `reach_m`: each cleared free space up to it and marked nothing "
    "occupied (`vogjax map` warns when there are any).",
    "returns.beyond_reach_share": "`beyond_reach` over `total` (0 without returns).",
    "returns.reach_m": "The map's reach: `[map] max_range`, or the sensor's range if shorter.",
    "scan_matching": "Scan matching over the recorded odometry (`[scan_matching]`, on in the lidar preset).",
    "scan_matching.enabled": "Whether the odometry was corrected by scan matching before mapping.",
    "scan_matching.registered": "Scans registered to the local map (one every `every_s`).",
    "scan_matching.failed": "Scans due for registration that were not (no local map yet, too few returns, no "
    "convergence, or a move past ICP's pair distance): they kept the odometry's motion (`vogjax map` warns when "
    "they are more than a tenth of those due).",
    "preset": "The sensor and platform preset the run was mapped with (`vogjax map --sensor-preset`), chosen "
    "from its metadata; `name` null when presets were off.",
    "preset.name": "The preset's name: `sonar` (the papers' settings), or e.g. `lidar + wheel odometry`.",
    "preset.sensor": "The sensor preset: `sonar`, `lidar`, `depth_camera` or `laser_scan`.",
    "preset.odometry": "The odometry's kind: `hauv`, `wheel` or `unknown`.",
    "preset.reason": "What in the run's metadata picked them, in words.",
    "preset.settings": "Every setting the preset or the navigation noise derived, or you kept over them: "
    "`table.key` -> `value` (as TOML) and `from` (`preset`, `navigation noise: why`, or `your settings: "
    "preset VALUE`).",
    "preset.notes": "What you should know before the run is mapped (a sensor reaching past the map's range).",
    "config": "Every setting the run used (see the settings reference).",
    "versions": "Installed versions of vogjax and its core dependencies, and the platform.",
    "versions.*": "One version string.",
    "device": "Warp device the maps lived on.",
}

# Fields below these are described as a whole (settings, lists of series).
OPAQUE = (
    "config",
    "preset.settings",
    "loop_closures.errors",
    "loop_closures.rejections",
    "timing_s.curves.*",
    "fig9.*",
)


def describe(path: str) -> str | None:
    """The description of a report field.

    Parameters
    ----------
    path : str
        Dotted path of the field, e.g. ``"auc.online"``.

    Returns
    -------
    str or None
        Its description (the exact path first, then the path with its last key as ``*``), or None
        when the field is not described.
    """
    if path in FIELDS:
        return FIELDS[path]
    parent, _, _ = path.rpartition(".")
    return FIELDS.get(f"{parent}.*" if parent else "*")


def undescribed(report: dict) -> list[str]:
    """Fields of a report that `FIELDS` does not describe.

    Parameters
    ----------
    report : dict
        A report as `vogjax map` writes it (parsed JSON).

    Returns
    -------
    list of str
        Dotted paths of the fields without a description, in the report's order.
    """
    missing = []

    def walk(node: dict, prefix: str) -> None:
        for key, value in node.items():
            path = f"{prefix}.{key}" if prefix else key
            if describe(path) is None:
                missing.append(path)
                continue
            pattern = path if path in FIELDS else f"{prefix}.*"
            if isinstance(value, dict) and pattern not in OPAQUE and path not in OPAQUE:
                walk(value, path)

    walk(report, "")
    return missing
