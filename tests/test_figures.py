"""The figures of `vogjax map` read at a glance (issue 34), checked through matplotlib's objects,
not pixels: titles that name the map and the run, a legend entry for every mark, human labels,
coincident ROC curves drawn once, the chance diagonal and a note on curves below it, a top view
cropped to the structure with its outline, timing panels named after the papers' figures, and
legends that hide nothing (outside the axes)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.contour import ContourSet

from vogjax import pipeline, scenes
from vogjax.config import JobConfig
from vogjax.report import plots, timing
from vogjax.report.evaluate import evaluate_run
from vogjax.report.metrics import roc
from vogjax.report.summary import summary_table
from vogjax.sim import simulate_run

SETTINGS = {
    "pipeline": {"scans_per_submap": 20},
    "timing": {"rays": 300, "every_submaps": 2},
    "report": {"surface_points": 2000},
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A short boxes survey mapped, with its scene, scores and timing curves."""
    path = tmp_path_factory.mktemp("figures") / "boxes.h5"
    simulate_run("boxes", path, num_scans=240, progress=False)
    config = JobConfig.from_document(SETTINGS)
    result = pipeline.run(path, config.pipeline, progress=False)
    scene = scenes.load("boxes")
    metrics, curves = evaluate_run(result, scene, config.report.surface_points)
    return result, scene, metrics, curves


def legend_texts(figure) -> list[str]:
    return [text.get_text() for ax in figure.axes if ax.get_legend() for text in ax.get_legend().get_texts()]


def outside_every_axes(figure, legend) -> bool:
    """Whether the legend's box overlaps none of the figure's axes (drawn to know the boxes)."""
    figure.canvas.draw()
    box = legend.get_window_extent()
    return not any(box.overlaps(ax.get_window_extent()) for ax in figure.axes)


def test_top_view_is_cropped_to_the_structure_with_its_outline_and_a_legend(run):
    result, scene, _, _ = run
    centres, log_odds = result.global_map.voxels()
    figure = plots.top_view_figure(
        centres, log_odds, result.config.map, title="boxes: the online global map from above", scene=scene
    )
    ax = figure.axes[0]
    assert ax.get_title() == "boxes: the online global map from above"
    assert ax.get_xlabel() == "x [m]" and ax.get_ylabel() == "y [m]"
    texts = legend_texts(figure)
    for mark in ("occupied", "free", "unknown", "ground truth"):
        assert sum(t.startswith(mark) for t in texts) == 1, texts
    assert outside_every_axes(figure, ax.get_legend())
    # cropped to the mesh (the floor, 8 m square) and a margin, not to the free space seen (22 m)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    lo, hi = scene.mesh.bounds[0, :2], scene.mesh.bounds[1, :2]
    assert x0 <= lo[0] and x1 >= hi[0] and y0 <= lo[1] and y1 >= hi[1]
    size = float(np.max(hi - lo))
    assert x1 - x0 <= (hi[0] - lo[0]) + 2 * max(1.0, 0.1 * size) + 2 * result.config.map.voxel_size
    assert observed_span(centres) > 1.5 * (x1 - x0)
    # one outline per part of the mesh (the floor and three boxes)
    contours = [c for c in ax.collections if isinstance(c, ContourSet)]
    assert len(contours) == len(scene.mesh.split(only_watertight=False)) == 4
    colourbar = figure.axes[1]
    assert "z [m]" in colourbar.get_ylabel()
    default = plots.top_view_figure(centres, log_odds, result.config.map, map_name="virtual map")
    assert default.axes[0].get_title() == "virtual map, top view"
    plt.close("all")


def observed_span(centres: np.ndarray) -> float:
    return float(np.ptp(centres[:, 0]))


def test_trajectory_shows_the_errors_and_explains_every_mark_outside_the_axes(run):
    result, _, _, _ = run
    figure = plots.trajectories_figure(result, title="boxes: vehicle path from above")
    ax = figure.axes[0]
    assert ax.get_title() == "boxes: vehicle path from above"
    texts = legend_texts(figure)
    errors = result.metrics["trajectory_rmse_m"]
    assert any(t.startswith("true path") for t in texts)
    assert any(t.startswith("navigation") and f"{errors['navigation']:.2f} m RMS" in t for t in texts)
    assert any(t.startswith("optimized") and f"{errors['optimized']:.2f} m RMS" in t for t in texts)
    assert any("submap base poses" in t for t in texts) and any(t == "start" for t in texts)
    assert any(t.startswith(f"accepted loop closures ({len(result.loop_closures)})") for t in texts)
    # every line drawn with a style of its own has a legend entry
    legend = ax.get_legend()
    assert len(legend.get_texts()) == 6
    assert outside_every_axes(figure, legend)
    plt.close("all")


def test_roc_draws_coincident_curves_once_with_human_labels_and_the_chance_diagonal(run):
    _, _, metrics, curves = run
    figure = plots.roc_figure(curves, title="boxes: occupancy vs ground truth (ROC)", note="scored over N voxels")
    ax = figure.axes[0]
    assert ax.get_title() == "boxes: occupancy vs ground truth (ROC)"
    texts = legend_texts(figure)
    groups = plots.coincident_groups(curves)
    assert len(texts) == len(groups) + 1  # a curve per group, and the diagonal
    assert any(t.startswith("chance") for t in texts)
    for name in ("true_pose", "rigid_truth", "full_merge"):
        assert not any(name in t for t in texts)
    assert any(t.startswith("true poses") for t in texts) and any(t.startswith("rigid truth") for t in texts)
    for curve in curves.values():  # every AUC is in the legend
        assert any(f"{curve.auc:.3f}" in t for t in texts)
    assert "false positive rate" in ax.get_xlabel() and "true positive rate" in ax.get_ylabel()
    assert outside_every_axes(figure, ax.get_legend())
    assert any("scored over N voxels" in t.get_text() for t in ax.texts)
    plt.close("all")


def test_roc_merges_curves_that_coincide_and_notes_one_below_chance():
    """Curves built to be equal, near, apart and below the diagonal."""
    rng = np.random.default_rng(0)
    occupied = rng.random(4000) < 0.3
    good = np.where(occupied, rng.uniform(0.4, 1.0, 4000), rng.uniform(0.0, 0.7, 4000))
    curves = {
        "online": roc(good, occupied),
        "virtual": roc(good.copy(), occupied),  # the same scores: the same curve
        "full_merge": roc(np.clip(good + 1e-4, 0, 1), occupied),  # a shift that reorders nothing
        "standard": roc(1.0 - good, occupied),  # inverted: below the diagonal everywhere
        "true_pose": roc(np.where(occupied, 0.9, 0.1), occupied),
    }
    assert plots.coincident_groups(curves) == [["online", "virtual", "full_merge"], ["standard"], ["true_pose"]]
    figure = plots.roc_figure(curves)
    texts = legend_texts(figure)
    merged = [t for t in texts if "online global map" in t]
    assert merged == [f"online global map, virtual map, full merge: one curve (AUC {curves['online'].auc:.3f} each)"]
    lines = [line for line in figure.axes[0].get_lines() if not line.get_label().startswith("_")]
    assert len(lines) == 4  # three groups and the diagonal
    notes = " ".join(t.get_text() for t in figure.axes[0].texts)
    assert "Below the diagonal (standard map)" in notes
    assert plots.below_chance(curves["standard"]) and not plots.below_chance(curves["online"])
    plt.close("all")


def test_timing_panels_name_the_papers_figures_and_the_baseline(run):
    result, _, _, _ = run
    curves = timing.curves(result)
    figure = plots.timing_figure(curves, title="boxes: update and query times on cpu")
    left, right = figure.axes
    assert "Fig. 9" in left.get_title() and "Sodhi" in left.get_title()
    assert "Fig. 8" in right.get_title() and "300 rays" in right.get_title()
    assert figure._suptitle.get_text() == "boxes: update and query times on cpu"
    assert len(left.get_ylabel()) <= 25 and len(right.get_ylabel()) <= 25
    left_texts = [t.get_text() for t in left.get_legend().get_texts()]
    assert any(t.startswith("baseline: full merge") for t in left_texts)
    assert any("online global map" in t for t in left_texts) and any("virtual map" in t for t in left_texts)
    assert len(right.get_legend().get_texts()) == 2
    plt.close("all")


def test_the_saved_figures_are_what_the_figure_functions_draw(run, tmp_path):
    result, scene, metrics, curves = run
    centres, log_odds = result.global_map.voxels()
    plots.top_view(centres, log_odds, result.config.map, tmp_path / "top_view.png", title="t", scene=scene)
    plots.trajectories(result, tmp_path / "trajectory.png", title="t")
    plots.roc_curves(curves, tmp_path / "roc.png", title="t")
    plots.timing(timing.curves(result), tmp_path / "timing.png", title="t")
    for name in ("top_view", "trajectory", "roc", "timing"):
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert plt.get_fignums() == []  # closed once saved


def report_like(name: str, value: float) -> dict:
    """The keys of report.json the summary table reads."""
    return {
        "run": f"runs/{name}.h5",
        "submaps": 41,
        "loop_closures": {"accepted": 171, "rejected": 1048},
        "auc": {"online": value, "virtual": value, "full_merge": value, "standard": None},
        "rmse_m": {"standard": 0.245, "without_loop_closures": 0.527, "with_loop_closures": 0.068},
        "trajectory_rmse_m": {"navigation": 1.25, "optimized": 0.34},
        "timing_s": {
            "update_per_submap": {"online": 0.0282, "full_merge": 0.1063},
            "query": {"global": 0.0376},
            "real_time_factor": 165.0,
        },
        "device": "cuda:0",
        "ground_truth": "scene",
    }


@pytest.mark.parametrize("runs", [1, 2, 5, 12])
def test_summary_table_fits_in_100_columns(runs):
    reports = [report_like(f"propeller_seed_{i}", 0.7 + i / 1000) for i in range(runs)]
    text = summary_table(reports)
    assert max(len(line) for line in text.splitlines()) <= 100
    blocks = text.split("\n\n")  # runs that do not fit go on to a further block
    assert all(block.count("AUC online global map") == 1 for block in blocks)
    headers = [name for block in blocks for name in block.splitlines()[0].split()]
    assert headers == [f"propeller_seed_{i}" for i in range(runs)]
    for r in reports:
        assert f"{r['auc']['online']:.3f}" in text
    assert text.count("171 / 1048") == runs and text.count("cuda:0") == runs
    long = summary_table([report_like("x" * 150, 0.7)])
    assert max(len(line) for line in long.splitlines()) <= 100
