"""The text table `vogjax map` prints: each run's headline figures, a row per figure and a
column per run, at most WIDTH columns wide (runs beyond that go on to a further block)."""

from __future__ import annotations

from pathlib import Path

WIDTH = 100
# The settings behind each closure gate (`vogjax.slam.loop_closure.REASONS`).
GATE_SETTINGS = {
    "overlap": '[loop_closure] min_overlap_score and overlap_reference ("self": against a complete '
    "overlap's score, for dense clouds), or the search: [loop_closure.correlative] resolution_m and "
    "yaw_step_rad, [nav_noise] (the search's radius)",
    "ambiguous": "[loop_closure] max_ambiguity",
    "not converged": "[loop_closure.icp] max_iterations and max_correspondence_m",
    "fitness": "[loop_closure] max_fitness_m2 (and registration_voxel_m)",
    "inliers": "[loop_closure] min_inlier_fraction",
    "refinement": "[loop_closure] max_refinement_m, or a finer [loop_closure.correlative] resolution_m",
    "drift": "[nav_noise] sigma2_x and sigma2_y (the gate is drift_sigmas of their drift)",
    "yaw drift": "[nav_noise] sigma2_yaw (the gate is drift_sigmas of its drift)",
    "information": "[loop_closure] min_information (and registration_sigma_m)",
    "inconsistent": "[pose_graph] screen and its threshold",
}


def closure_hint(report: dict) -> str | None:
    """A one-line hint when most of a run's closure candidates failed one gate.

    Parameters
    ----------
    report : dict
        The run's report (report.json).

    Returns
    -------
    str or None
        The gate, how many it refused, and the settings behind it; None when no gate refused
        more than half the candidates.
    """
    closures = report.get("loop_closures") or {}
    reasons = closures.get("rejected_by_reason") or {}
    candidates = closures.get("accepted", 0) + closures.get("rejected", 0)
    if not reasons or candidates == 0:
        return None
    reason, count = max(reasons.items(), key=lambda item: item[1])
    if 2 * count <= candidates:
        return None
    return (
        f'{count} of {candidates} closure candidates failed the "{reason}" gate; '
        f"see loop_closures.csv, and {GATE_SETTINGS.get(reason, 'the [loop_closure] settings')}"
    )


def _ms(value: float | None) -> float | None:
    return None if value is None else value * 1e3


# (row label, how to read it from a report, format); None: not measured in that run
ROWS = (
    ("submaps", lambda r: r["submaps"], "d"),
    (
        "loop closures accepted / rejected",
        lambda r: (r["loop_closures"]["accepted"], r["loop_closures"]["rejected"]),
        "/",
    ),
    ("AUC online global map", lambda r: r["auc"].get("online"), ".3f"),
    ("AUC virtual map", lambda r: r["auc"].get("virtual"), ".3f"),
    ("AUC full merge", lambda r: r["auc"].get("full_merge"), ".3f"),
    ("AUC standard map (navigation)", lambda r: r["auc"].get("standard"), ".3f"),
    ("surface RMSE standard map [m]", lambda r: r["rmse_m"].get("standard"), ".3f"),
    ("surface RMSE without closures [m]", lambda r: r["rmse_m"].get("without_loop_closures"), ".3f"),
    ("surface RMSE with closures [m]", lambda r: r["rmse_m"].get("with_loop_closures"), ".3f"),
    ("base pose RMSE navigation [m]", lambda r: r["trajectory_rmse_m"].get("navigation"), ".2f"),
    ("base pose RMSE optimized [m]", lambda r: r["trajectory_rmse_m"].get("optimized"), ".2f"),
    ("update per submap, online [ms]", lambda r: _ms(r["timing_s"].get("update_per_submap", {}).get("online")), ".1f"),
    (
        "update per submap, full merge [ms]",
        lambda r: _ms(r["timing_s"].get("update_per_submap", {}).get("full_merge")),
        ".1f",
    ),
    ("planner query, global map [ms]", lambda r: _ms(r["timing_s"].get("query", {}).get("global")), ".1f"),
    ("faster than real time [x]", lambda r: r["timing_s"].get("real_time_factor"), ".0f"),
    ("device", lambda r: r.get("device"), "s"),
)


def _cell(value, spec: str) -> str:
    if value is None:
        return "-"
    if spec == "/":
        return f"{value[0]} / {value[1]}"
    return format(value, spec)


def _shortened(name: str, room: int) -> str:
    return name if len(name) <= room else name[: room - 3] + "..."


def summary_table(reports: list[dict], width: int = WIDTH) -> str:
    """A text table of the reports' headline figures: a row per figure, a column per run.

    Parameters
    ----------
    reports : list of dict
        Reports of `vogjax map` (report.json's contents).
    width : int
        The most columns a line may take; runs that do not fit go on to a further block.

    Returns
    -------
    str
        The table, then a line per run that has no ground truth (its AUC and RMSE skipped).
    """
    label_width = max(len(label) for label, _, _ in ROWS)
    room = max(8, width - label_width - 2)  # a run's name longer than a column may be is shortened
    columns = [
        [_shortened(Path(r["run"]).stem, room)] + [_cell(read(r), spec) for _, read, spec in ROWS] for r in reports
    ]
    blocks, block, used = [], [], label_width
    for column in columns:
        column_width = max(len(cell) for cell in column)
        if block and used + 2 + column_width > width:
            blocks.append(block)
            block, used = [], label_width
        block.append(column)
        used += 2 + column_width
    blocks.append(block)
    lines = []
    for block in blocks:
        widths = [max(len(cell) for cell in column) for column in block]
        labels = ["", *(label for label, _, _ in ROWS)]
        for i, label in enumerate(labels):
            cells = "  ".join(column[i].rjust(w) for column, w in zip(block, widths))
            lines.append(f"{label.ljust(label_width)}  {cells}".rstrip())
        lines.append("")
    lines.pop()
    lines += [
        f"{Path(r['run']).stem}: no ground truth (no built-in scene): AUC and RMSE skipped"
        for r in reports
        if r.get("ground_truth", "scene") != "scene"
    ]
    return "\n".join(lines)
