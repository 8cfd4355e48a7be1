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
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
