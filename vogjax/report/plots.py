"""The figures of a `vogjax map` report: what the map shows from above, where the vehicle went,
how well each map scores against the ground truth, and what the updates and queries cost.

Each figure comes from a `*_figure` function that returns the matplotlib Figure (titles,
labels and legend entries can be read from it), and a function of the figure's name that
draws it and saves it as a PNG.
"""

from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

# the maps' names in report.json -> what a figure calls them
MAP_LABELS = {
    "online": "online global map",
    "virtual": "virtual map",
    "full_merge": "full merge",
    "standard": "standard map (navigation only)",
    "true_pose": "true poses (the scans mapped where they were taken)",
    "rigid_truth": "rigid truth (these submaps at their best true placement)",
    "confidence": "confidence-rich map (mean)",
    "online, registered to the truth": "online global map, registered to the truth",
}
# curves no further apart than this anywhere (true positive rate, on a grid of false positive
# rates) look like one line at a figure's resolution: they are drawn once, with one label
COINCIDENT = 0.005
FREE_GREY = 0.85
TRUTH_COLOUR = "tab:red"


def _save(figure: Figure, path) -> None:
    figure.savefig(path, bbox_inches="tight")  # legends outside the axes stay in the picture
    plt.close(figure)


# ------------------------------------------------------------------------------ top view


def top_view_figure(
    centres: np.ndarray,
    log_odds: np.ndarray,
    config,
    title: str = "",
    scene=None,
    map_name: str = "online global map",
) -> Figure:
    """The map seen from above: per column of voxels, occupied (coloured by the height of its
    highest occupied voxel), free (observed, none occupied) or unknown; cropped to the
    structure, with the outline of each of the scene's parts when there is ground truth.

    Parameters
    ----------
    centres : numpy.ndarray
        (K, 3) float: centres of the map's observed voxels, world frame, m.
    log_odds : numpy.ndarray
        (K,) float: their log-odds.
    config : MapConfig
        The map's settings (voxel size, thresholds).
    title : str
        The figure's title (default: names the map).
    scene : vogjax.scenes.Scene or None
        The run's scene: the crop is its structure and its parts are outlined; None: cropped
        to the occupied voxels.
    map_name : str
        Which map this is, for the default title.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    s = config.voxel_size
    occupied = log_odds >= config.log_occupied
    free = log_odds <= config.log_free
    lo_m, hi_m = _crop(centres, occupied, scene, s)
    lo, hi = np.floor(lo_m / s).astype(int), np.floor(hi_m / s).astype(int)
    shape = hi - lo + 1
    keys = np.floor(centres[:, :2] / s).astype(int)
    inside = np.all((keys >= lo) & (keys <= hi), axis=1)
    seen = np.zeros(shape, bool)
    seen[tuple((keys[free & inside] - lo).T)] = True
    height = np.full(shape, np.nan)
    chosen = occupied & inside
    ij = keys[chosen] - lo
    z = centres[chosen, 2]
    order = np.argsort(z)  # later writes (higher z) win
    height[ij[order, 0], ij[order, 1]] = z[order]
    extent = [lo[0] * s, (hi[0] + 1) * s, lo[1] * s, (hi[1] + 1) * s]
    aspect = shape[1] / max(shape[0], 1)
    figure, ax = plt.subplots(figsize=(7.5, min(12.0, 6.5 * aspect + 1.5)), dpi=120)
    ax.imshow(np.where(seen, FREE_GREY, 1.0).T, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1)
    image = ax.imshow(height.T, origin="lower", extent=extent, cmap="viridis")
    figure.colorbar(image, ax=ax, fraction=0.04, pad=0.02, shrink=0.85, label="highest occupied voxel, z [m]")
    handles = [
        Patch(facecolor=plt.get_cmap("viridis")(0.6), label="occupied (coloured by height)"),
        Patch(facecolor=str(FREE_GREY), label="free (observed, nothing occupied)"),
        Patch(facecolor="white", edgecolor="0.6", label="unknown (never observed)"),
    ]
    if scene is not None and _outline(ax, scene, s, lo, shape):
        handles.append(
            Line2D(
                [],
                [],
                color=TRUTH_COLOUR,
                lw=1.2,
                label="ground truth: each part's outline (the map is not registered to it)",
            )
        )
    ax.set_xlim(extent[:2])
    ax.set_ylim(extent[2:])
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{map_name}, top view")
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=2, fontsize=8, frameon=False)
    return figure


def _crop(centres: np.ndarray, occupied: np.ndarray, scene, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) x-y corners, m: the scene's structure (its mesh) or else the occupied voxels
    (the observed ones when none is), with a margin of a tenth of the size, 1 m at least."""
    if scene is not None:
        lo, hi = np.asarray(scene.mesh.bounds, float)[:, :2]
    else:
        points = centres[occupied] if occupied.any() else centres
        if not len(points):
            return np.zeros(2), np.full(2, voxel_size)
        lo, hi = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    margin = max(1.0, 0.1 * float(np.max(hi - lo)))
    return lo - margin, hi + margin


def _outline(ax, scene, voxel_size: float, lo: np.ndarray, shape: np.ndarray) -> bool:
    """Draw the footprint outline of each part of the scene's mesh on the map's grid; whether
    anything was drawn."""
    from vogjax.scenes.scene import triangle_points

    drawn = False
    x = (lo[0] + np.arange(shape[0]) + 0.5) * voxel_size
    y = (lo[1] + np.arange(shape[1]) + 0.5) * voxel_size
    for part in scene.mesh.split(only_watertight=False):
        mask = np.zeros(shape, bool)
        for points in triangle_points(part, voxel_size / 2):
            keys = np.floor(points[:, :2] / voxel_size).astype(int) - lo
            keys = keys[np.all((keys >= 0) & (keys < shape), axis=1)]
            mask[tuple(keys.T)] = True
        if mask.sum() < 2:
            continue
        padded = np.pad(mask, 1)  # a part at the crop's edge still gets a closed outline
        xs = np.r_[x[0] - voxel_size, x, x[-1] + voxel_size]
        ys = np.r_[y[0] - voxel_size, y, y[-1] + voxel_size]
        ax.contour(xs, ys, padded.T.astype(float), levels=[0.5], colors=TRUTH_COLOUR, linewidths=1.0)
        drawn = True
    return drawn


def top_view(centres: np.ndarray, log_odds: np.ndarray, config, path, title: str = "", **options) -> None:
    """Save `top_view_figure(centres, log_odds, config, title, **options)` as a PNG at `path`.

    Parameters
    ----------
    centres, log_odds, config, title
        As `top_view_figure`.
    path : str or Path
        The PNG to write.
    **options
        `scene`, `map_name`: as `top_view_figure`.
    """
    _save(top_view_figure(centres, log_odds, config, title, **options), path)


# ------------------------------------------------------------------------------ trajectories


def trajectories_figure(result, title: str = "") -> Figure:
    """The vehicle's path from above: the truth, navigation and the optimised poses (scans
    carried with their submaps), each submap's base pose on each, and the accepted loop
    closures between the optimised base poses; the base poses' RMS errors in the legend.

    Parameters
    ----------
    result : vogjax.pipeline.Result
        A pipeline run.
    title : str
        The figure's title.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    errors = result.metrics["trajectory_rmse_m"] if result.scan_truth is not None else {}
    figure, ax = plt.subplots(figsize=(9.5, 6), dpi=120)
    names = {"truth": "true path", "navigation": "navigation", "optimized": "optimized (SLAM)"}
    for name, style in (
        ("truth", dict(color="k", lw=2.5, alpha=0.3)),
        ("navigation", dict(color="tab:red", lw=1.0)),
        ("optimized", dict(color="tab:blue", lw=1.0)),
    ):
        poses = result.scan_poses(name)
        if poses is None:
            continue
        label = names[name]
        if name in errors and errors[name] is not None:
            label += f": base poses {errors[name]:.2f} m RMS from the truth"
        ax.plot(poses[:, 0, 3], poses[:, 1, 3], label=label, **style)
        bases = poses[result.submap_base_scan]
        ax.plot(bases[:, 0, 3], bases[:, 1, 3], "o", color=style["color"], ms=2.5)
    xy = result.optimized[:, :2, 3]
    for closure in result.loop_closures:
        ax.plot(*xy[[closure.i, closure.k]].T, color="tab:green", lw=0.6, alpha=0.6)
    start = result.scan_poses("truth")
    start = (start if start is not None else result.scan_poses("navigation"))[0]
    ax.plot(start[0, 3], start[1, 3], "*", color="k", ms=10, label="start")
    ax.plot([], [], "o", color="0.35", ms=2.5, label="submap base poses (dots, on each path)")
    ax.plot(
        [],
        [],
        color="tab:green",
        lw=0.6,
        label=f"accepted loop closures ({len(result.loop_closures)}), joining optimized base poses",
    )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
    ax.set_title(title or "vehicle path, top view")
    return figure


def trajectories(result, path, title: str = "") -> None:
    """Save `trajectories_figure(result, title)` as a PNG at `path`.

    Parameters
    ----------
    result : vogjax.pipeline.Result
        A pipeline run.
    path : str or Path
        The PNG to write.
    title : str
        The figure's title.
    """
    _save(trajectories_figure(result, title), path)


# ------------------------------------------------------------------------------ ROC


def coincident_groups(curves: dict) -> list[list[str]]:
    """The curves' names grouped into those that coincide (within COINCIDENT everywhere).

    Parameters
    ----------
    curves : dict
        Name -> `Roc`.

    Returns
    -------
    list of list of str
        Groups in the order of their first curve; each curve in one group.
    """
    grid = np.linspace(0.0, 1.0, 501)
    sampled = {name: np.interp(grid, c.false_positive_rate, c.true_positive_rate) for name, c in curves.items()}
    groups: list[list[str]] = []
    for name in curves:
        for group in groups:
            if np.max(np.abs(sampled[group[0]] - sampled[name])) <= COINCIDENT:
                group.append(name)
                break
        else:
            groups.append([name])
    return groups


def _group_label(names: list[str], curves: dict) -> str:
    labels = [MAP_LABELS.get(n, n.replace("_", " ")) for n in names]
    aucs = [f"{curves[n].auc:.3f}" for n in names]
    if len(names) == 1:
        return f"{labels[0]} (AUC {aucs[0]})"
    if len(set(aucs)) == 1:
        return f"{', '.join(labels)}: one curve (AUC {aucs[0]} each)"
    return f"{', '.join(labels)}: one curve (AUC {' / '.join(aucs)})"


def below_chance(curve, margin: float = 0.01) -> bool:
    """Whether a ROC curve dips below the diagonal by more than `margin` somewhere.

    Parameters
    ----------
    curve : Roc
        The curve.
    margin : float
        How far below it counts.

    Returns
    -------
    bool
        True when some point has a true positive rate under its false positive rate - margin.
    """
    return bool(np.any(curve.true_positive_rate < curve.false_positive_rate - margin))


def roc_figure(curves: dict, title: str = "", note: str = "") -> Figure:
    """ROC of each map's occupancy against the ground truth, AUC in the legend; curves that
    coincide drawn once with one label, the chance diagonal, and a note under the axes on any
    curve below it.

    Parameters
    ----------
    curves : dict
        Map name (report.json's: "online", "virtual", ...) -> `Roc`.
    title : str
        The figure's title.
    note : str
        A line under the axes (what was scored).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    figure, ax = plt.subplots(figsize=(6, 5.2), dpi=120)
    below = []
    for group in coincident_groups(curves):
        curve = curves[group[0]]
        dashed = any("registered" in name for name in group)
        ax.plot(
            curve.false_positive_rate,
            curve.true_positive_rate,
            label=_group_label(group, curves),
            ls="--" if dashed else "-",
            lw=1.8 if len(group) > 1 else 1.2,
        )
        below += [MAP_LABELS.get(name, name).split(" (")[0] for name in group if below_chance(curves[name])]
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":", label="chance (a coin flip per voxel)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.01)
    ax.set_xlabel("false positive rate (true free voxels called occupied)")
    ax.set_ylabel("true positive rate (true occupied voxels called occupied)")
    ax.set_title(title or "occupancy vs ground truth (ROC)")
    lines = [note] if note else []
    if below:
        lines.append(
            f"Below the diagonal ({', '.join(below)}): at those thresholds the map calls more free voxels "
            "occupied than occupied ones, as a map does whose surfaces lie off the true ones (drift)."
        )
    legend = ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), fontsize=8, frameon=False)
    if lines:
        text = "\n".join(textwrap.fill(line, 95) for line in lines)
        ax.annotate(
            text,
            xy=(0.5, 0),
            xycoords=legend,
            xytext=(0, -6),
            textcoords="offset points",
            ha="center",
            va="top",
            fontsize=7.5,
            color="0.25",
        )
    return figure


def roc_curves(curves: dict, path, title: str = "", note: str = "") -> None:
    """Save `roc_figure(curves, title, note)` as a PNG at `path`.

    Parameters
    ----------
    curves : dict
        Map name -> `Roc`.
    path : str or Path
        The PNG to write.
    title, note : str
        As `roc_figure`.
    """
    _save(roc_figure(curves, title, note), path)


# ------------------------------------------------------------------------------ timing


def timing_figure(curves, title: str = "") -> Figure:
    """Left (Sodhi et al., Fig. 9): the cumulative mean time per submap to keep a map current,
    for the online global map, the virtual map and the paper's baseline (a full merge at each
    loop closure). Right (Fig. 8): one planner query against the global and the virtual map as
    the submaps grow.

    Parameters
    ----------
    curves : vogjax.report.timing.TimingCurves
        The run's timing curves.
    title : str
        The figure's title (the run and the device).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4.4), dpi=120)
    n = np.arange(1, len(curves.online_s) + 1)
    for name, values in (
        ("baseline: full merge at each loop closure", curves.full_merge_s),
        ("virtual map (setting the poses)", curves.virtual_s),
        ("online global map (Algorithm 1)", curves.online_s),
    ):
        left.plot(n, np.maximum(values, 1e-6) * 1e3, label=name)
    left.set_yscale("log")
    left.set_xlabel("submaps")
    left.set_ylabel("cumulative mean [ms]")
    left.set_title("map update per submap (Sodhi et al., Fig. 9)", fontsize=10)
    left.legend(fontsize=8)
    for name, values in (
        ("global map", curves.query_global_s),
        ("virtual map (a sum over submaps)", curves.query_virtual_s),
    ):
        right.plot(curves.sampled_submaps, values * 1e3, marker="o", label=name)
    right.set_xlabel("submaps")
    right.set_ylabel("query time [ms]")
    rays = f"{curves.rays // 1000}k" if curves.rays >= 1000 else str(curves.rays)
    right.set_title(f"planner query, {rays} rays (Sodhi et al., Fig. 8)", fontsize=10)
    right.legend(fontsize=8)
    figure.suptitle(title or "update and query times")
    figure.tight_layout()
    return figure


def timing(curves, path, title: str = "") -> None:
    """Save `timing_figure(curves, title)` as a PNG at `path`.

    Parameters
    ----------
    curves : vogjax.report.timing.TimingCurves
        The run's timing curves.
    path : str or Path
        The PNG to write.
    title : str
        The figure's title.
    """
    _save(timing_figure(curves, title), path)


__all__ = [
    "MAP_LABELS",
    "below_chance",
    "coincident_groups",
    "roc_curves",
    "roc_figure",
    "timing",
    "timing_figure",
    "top_view",
    "top_view_figure",
    "trajectories",
    "trajectories_figure",
]
