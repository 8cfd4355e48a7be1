"""Figures people would rather look at than read."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def top_view(centres: np.ndarray, log_odds: np.ndarray, config, path, title: str = "") -> None:
    """Top view: free space in grey, occupied voxels coloured by their highest z."""
    s = config.voxel_size
    keys = np.floor(centres[:, :2] / s).astype(int)
    lo = keys.min(axis=0)
    shape = keys.max(axis=0) - lo + 1
    occupied = log_odds >= config.log_occupied
    free = log_odds <= config.log_free
    seen = np.zeros(shape, bool)
    seen[tuple((keys[free] - lo).T)] = True
    height = np.full(shape, np.nan)
    ij = keys[occupied] - lo
    order = np.argsort(centres[occupied, 2])  # later writes (higher z) win
    height[ij[order, 0], ij[order, 1]] = centres[occupied, 2][order]
    extent = [lo[0] * s, (lo[0] + shape[0]) * s, lo[1] * s, (lo[1] + shape[1]) * s]
    fig, ax = plt.subplots(figsize=(8, 8 * shape[1] / max(shape[0], 1) + 0.8), dpi=120)
    ax.imshow(np.where(seen, 0.85, 1.0).T, origin="lower", extent=extent, cmap="gray", vmin=0, vmax=1)
    image = ax.imshow(height.T, origin="lower", extent=extent, cmap="viridis")
    fig.colorbar(image, ax=ax, fraction=0.03, label="highest occupied voxel, z [m]")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or "occupancy, top view (grey: observed free)")
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


def trajectories(result, path, title: str = "") -> None:
    """Top view of the vehicle's path: truth, navigation and optimised (scans carried with their
    submaps), submap bases as dots, accepted loop closures between optimised bases."""
    fig, ax = plt.subplots(figsize=(7, 6), dpi=120)
    for name, style in (
        ("truth", dict(color="k", lw=2.5, alpha=0.3)),
        ("navigation", dict(color="tab:red", lw=1.0)),
        ("optimized", dict(color="tab:blue", lw=1.0)),
    ):
        poses = result.scan_poses(name)
        if poses is None:
            continue
        ax.plot(poses[:, 0, 3], poses[:, 1, 3], label=name, **style)
        bases = poses[result.submap_base_scan]
        ax.plot(bases[:, 0, 3], bases[:, 1, 3], ".", color=style["color"], ms=4)
    xy = result.optimized[:, :2, 3]
    for closure in result.loop_closures:
        ax.plot(*xy[[closure.i, closure.k]].T, color="tab:green", lw=0.6, alpha=0.6)
    ax.plot([], [], color="tab:green", lw=0.6, label=f"loop closures ({len(result.loop_closures)})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title or "vehicle path, top view (dots: submap bases)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def roc_curves(curves: dict, path, title: str = "") -> None:
    """ROC of each map's occupancy against ground truth, AUC in the legend."""
    fig, ax = plt.subplots(figsize=(5.5, 5), dpi=120)
    for name, curve in curves.items():
        ax.plot(
            curve.false_positive_rate,
            curve.true_positive_rate,
            label=f"{name} (AUC {curve.auc:.3f})",
            ls="--" if "registered" in name else "-",
        )
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8, ls=":")
    ax.set_xlabel("false positive rate")
    ax.set_ylabel("true positive rate")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title or "occupancy vs ground truth")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def timing(curves, path, title: str = "") -> None:
    """Left: cumulative average update time per submap (Sodhi et al., Fig. 9). Right: one
    planner query against the global and the virtual map by submap count (Fig. 8)."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2), dpi=120)
    n = np.arange(1, len(curves.online_s) + 1)
    for name, values in (
        ("full merge at loop closures", curves.full_merge_s),
        ("virtual map (pose update)", curves.virtual_s),
        ("online global map", curves.online_s),
    ):
        left.plot(n, np.maximum(values, 1e-6) * 1e3, label=name)
    left.set_yscale("log")
    left.set_xlabel("submaps")
    left.set_ylabel("update time per submap, cumulative average [ms]")
    left.legend(fontsize=8)
    for name, values in (("global map", curves.query_global_s), ("virtual map", curves.query_virtual_s)):
        right.plot(curves.sampled_submaps, values * 1e3, marker="o", label=name)
    right.set_xlabel("submaps")
    right.set_ylabel(f"{curves.rays // 1000}k-ray query [ms]")
    right.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
