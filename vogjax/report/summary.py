"""The text table `vogjax map` prints: each run's headline figures."""

from __future__ import annotations

from pathlib import Path


def summary_table(reports: list[dict]) -> str:
    """A short text table of the reports' headline figures."""

    def fmt(value, spec):
        return "-" if value is None else format(value, spec)

    rows = [
        (
            "run",
            "submaps",
            "LC acc/rej",
            "AUC online",
            "AUC virtual",
            "AUC merge",
            "AUC standard",
            "RMSE std",
            "RMSE no-LC",
            "RMSE LC",
            "traj nav",
            "traj opt",
            "update ms",
            "merge ms",
            "query ms",
            "x real time",
        )
    ]
    for r in reports:
        t = r["timing_s"]
        upd, query = t.get("update_per_submap", {}), t.get("query", {})
        rows.append(
            (
                Path(r["run"]).stem,
                str(r["submaps"]),
                f"{r['loop_closures']['accepted']}/{r['loop_closures']['rejected']}",
                *(fmt(r["auc"].get(k), ".3f") for k in ("online", "virtual", "full_merge", "standard")),
                *(fmt(r["rmse_m"].get(k), ".3f") for k in ("standard", "without_loop_closures", "with_loop_closures")),
                *(fmt(r["trajectory_rmse_m"].get(k), ".2f") for k in ("navigation", "optimized")),
                fmt(upd.get("online") and upd["online"] * 1e3, ".1f"),
                fmt(upd.get("full_merge") and upd["full_merge"] * 1e3, ".1f"),
                fmt(query.get("global") and query["global"] * 1e3, ".1f"),
                fmt(t["real_time_factor"], ".0f"),
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.rjust(w) for cell, w in zip(row, widths)) for row in rows]
    lines += [
        f"{Path(r['run']).stem}: no ground truth (no built-in scene): AUC and RMSE skipped"
        for r in reports
        if r.get("ground_truth", "scene") != "scene"
    ]
    return "\n".join(lines)
