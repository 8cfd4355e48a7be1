"""Confidence-rich map (Agha-mohammadi) benchmarks, two parts:

1. The paper's 2D experiment (Sec. VII): a 2 x 2 m world of 10 cm cells, half of them occupied
   at random (the cells around the robot free), a range sensor turning in place (28 degree field
   of view, 15 beams, 1 m range, 10 Hz, 15 deg/s for 50 s, range-noise variance 0.04 m^2).
   50 random worlds; the confidence-rich map against log-odds maps with each of 36 inverse
   sensor models (the paper's sweep of q, r_ramp, r_top); map error and inconsistency I_c per
   world, error over time at six noise levels, and the bin-count trade-off. The CRM runs through
   vogjax's 3D ConfidenceMap on one layer of voxels; the log-odds maps with the paper's ISM are
   NumPy over the same beams. Writes crm_2d.json and crm_2d_fig{3,4,5,6,7}.png.
2. Noisy sonar scans of a built-in scene: a ConfidenceMap and a VoxelMap from the same rays,
   compared against the scene's true occupancy on the voxels both observed (mean error, ROC
   AUC), their integration times side by side, and memory per voxel. Writes crm_3d_cpu.json.

    python benchmarks/bench_crm.py [--quick] [--part all|2d|3d] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import warp as wp  # noqa: E402
from tqdm import tqdm  # noqa: E402

import vogjax as vj  # noqa: E402
from vogjax.config.crm import CrmConfig  # noqa: E402
from vogjax.maps.confidence import ConfidenceMap  # noqa: E402
from vogjax.maps.confidence_cost import inconsistency  # noqa: E402

# ---------------------------------------------------------------- Part 1: the paper's 2D experiment
CELL = 0.1  # m
HALF = 10  # cells on each side of the robot: a 2 x 2 m world
RANGE = 1.0  # m
FOV_DEG, BEAMS, RATE_HZ, TURN_DEG_S, DURATION_S = 28.0, 15, 10.0, 15.0, 50.0
NOISE_VARIANCE = 0.04  # m^2
NOISE_LEVELS = (0.1, 0.04, 0.01, 0.0025, 0.0004, 0.0001)  # m^2, Fig. 5
# The paper's ISM sweep: q_h - 0.5 = 0.5 - q_l, r_ramp, r_top (m).
ISM_Q = (0.05, 0.2, 0.4)
ISM_RAMP = (0.05, 0.1, 0.3, 1.0)
ISM_TOP = (0.05, 0.1, 0.3)
ISM_PAPER = {"q": 0.05, "r_ramp": 0.1, "r_top": 0.1}  # q_l = 0.45, q_h = 0.55
LAYER_Z = 0.5 * CELL  # the 2D world is the voxel layer z in [0, CELL)


def ism_settings() -> list[dict]:
    return [{"q": q, "r_ramp": ramp, "r_top": top} for q in ISM_Q for ramp in ISM_RAMP for top in ISM_TOP]


@dataclasses.dataclass(frozen=True)
class Beams2D:
    """The sensor's beams over the whole run (the robot turns in place, so they are the same in
    every world): angle (B,), scan (B,) index, and the cells each beam crosses within RANGE:
    cell (B,C) flat index into the 20 x 20 world (-1 outside it or past the beam's cells),
    t_in (B,C) entry distance, centre_distance (B,C) from the sensor to the cell's centre."""

    angle: np.ndarray
    scan: np.ndarray
    cell: np.ndarray
    t_in: np.ndarray
    centre_distance: np.ndarray

    @property
    def num_scans(self) -> int:
        return int(self.scan.max()) + 1


def cells_along(angle: float, length: float) -> list[tuple[int, int, float]]:
    """(ix, iy, t_in) of the cells a ray from the origin crosses with positive length, in order."""
    d = np.array([math.cos(angle), math.sin(angle)])
    ts = [0.0, length]
    for axis in range(2):
        if d[axis] != 0:
            for k in range(-HALF - 1, HALF + 2):
                t = k * CELL / d[axis]
                if 0 < t < length:
                    ts.append(t)
    ts = sorted(set(ts))
    out = []
    for t0, t1 in zip(ts[:-1], ts[1:]):
        mid = d * 0.5 * (t0 + t1)
        out.append((math.floor(mid[0] / CELL), math.floor(mid[1] / CELL), t0))
    return out


def make_beams(duration_s: float) -> Beams2D:
    scans = int(round(duration_s * RATE_HZ))
    heading = np.pi / 2 + np.deg2rad(TURN_DEG_S) * np.arange(scans) / RATE_HZ
    offsets = np.deg2rad(np.linspace(-FOV_DEG / 2, FOV_DEG / 2, BEAMS))
    angle = (heading[:, None] + offsets[None, :]).reshape(-1)
    rows = [cells_along(a, RANGE) for a in angle]
    width = max(len(r) for r in rows)
    cell = np.full((len(angle), width), -1, np.int64)
    t_in = np.full((len(angle), width), np.inf)
    centre = np.full((len(angle), width), np.inf)
    for b, row in enumerate(rows):
        for c, (ix, iy, t0) in enumerate(row):
            t_in[b, c] = t0
            if -HALF <= ix < HALF and -HALF <= iy < HALF:
                cell[b, c] = (ix + HALF) * 2 * HALF + (iy + HALF)
            centre[b, c] = math.hypot((ix + 0.5) * CELL, (iy + 0.5) * CELL)
    return Beams2D(angle, np.repeat(np.arange(scans), BEAMS), cell, t_in, centre)


def random_world(rng: np.random.Generator) -> np.ndarray:
    """(400,) float truth: half the cells occupied at random, the 4 x 4 cells around the robot free."""
    world = (rng.random((2 * HALF, 2 * HALF)) < 0.5).astype(np.float64)
    world[HALF - 2 : HALF + 2, HALF - 2 : HALF + 2] = 0.0
    return world.reshape(-1)


def readings(world: np.ndarray, beams: Beams2D, variance: float, rng: np.random.Generator) -> np.ndarray:
    """(B,) noisy ranges by the paper's forward model (Eq. 17): the distance to the centre of the
    first occupied cell plus Gaussian noise; inf where no cell within RANGE is occupied or the
    noisy reading lands past RANGE."""
    occupied = np.where(beams.cell >= 0, world[np.maximum(beams.cell, 0)] > 0.5, False)
    first = np.argmax(occupied, axis=1)
    true_range = np.where(occupied.any(axis=1), beams.centre_distance[np.arange(len(first)), first], np.inf)
    z = true_range + math.sqrt(variance) * rng.standard_normal(len(first))
    z = np.maximum(z, 1e-3)  # a reading cannot fall behind the sensor
    return np.where(z <= RANGE, z, np.inf)


def visible_cells(world: np.ndarray, beams: Beams2D) -> np.ndarray:
    """(400,) bool: cells some beam reaches, up to and including the first occupied one."""
    occupied = np.where(beams.cell >= 0, world[np.maximum(beams.cell, 0)] > 0.5, False)
    first = np.where(occupied.any(axis=1), np.argmax(occupied, axis=1), beams.cell.shape[1])
    reached = (np.arange(beams.cell.shape[1])[None, :] <= first[:, None]) & (beams.cell >= 0)
    visible = np.zeros(world.shape, bool)
    visible[beams.cell[reached]] = True
    return visible


def cell_centres() -> np.ndarray:
    i = np.arange(2 * HALF) - HALF
    x, y = np.meshgrid((i + 0.5) * CELL, (i + 0.5) * CELL, indexing="ij")
    return np.stack([x.reshape(-1), y.reshape(-1), np.full(x.size, LAYER_Z)], axis=1)


def crm_run(world_readings: np.ndarray, beams: Beams2D, config: CrmConfig, checkpoints: np.ndarray):
    """The confidence-rich map of one world: mean and variance (T,400) after each checkpoint scan."""
    crm = ConfidenceMap(config, device="cpu")
    direction = np.stack([np.cos(beams.angle), np.sin(beams.angle), np.zeros_like(beams.angle)], axis=1)
    length = np.where(np.isfinite(world_readings), world_readings, RANGE * 1.05 + CELL)
    points = np.array([0.0, 0.0, LAYER_Z]) + direction * length[:, None]
    origins = np.tile([0.0, 0.0, LAYER_Z], (beams.num_scans, 1))
    centres = cell_centres()
    means, variances = [], []
    first = 0
    for end in checkpoints:
        lo, hi = np.searchsorted(beams.scan, [first, end])
        crm.integrate_scans(origins[first:end], points[lo:hi], beams.scan[lo:hi] - first)
        means.append(crm.mean(centres))
        variances.append(crm.variance(centres))
        first = end
    return np.array(means, np.float64), np.array(variances, np.float64)


def ism_run(world_readings: np.ndarray, beams: Beams2D, setting: dict, checkpoints: np.ndarray) -> np.ndarray:
    """Log-odds map with the paper's ISM (Fig. 1) from the same beams: probability (T,400) after
    each checkpoint. Along a beam with reading z, a cell at centre distance r gets q_l before
    z - r_ramp, a ramp up to q_h at z, q_h up to z + r_top, nothing beyond; without a return
    every cell it crosses gets q_l. No clamping (Eq. 10)."""
    q_l, q_h = 0.5 - setting["q"], 0.5 + setting["q"]
    z = world_readings[:, None]
    r = beams.centre_distance
    returned = np.isfinite(z)
    ramp = q_l + (q_h - q_l) * np.clip((r - (z - setting["r_ramp"])) / setting["r_ramp"], 0.0, 1.0)
    p = np.where(r <= z, ramp, np.where(r <= z + setting["r_top"], q_h, 0.5))
    p = np.where(returned, p, q_l)
    valid = beams.cell >= 0
    increment = np.where(valid, np.log(p / (1.0 - p)), 0.0)
    out = []
    cells = np.where(valid, beams.cell, 0)
    for end in checkpoints:
        mask = valid & (beams.scan < end)[:, None]
        log_odds = np.bincount(cells[mask], weights=increment[mask], minlength=4 * HALF * HALF)
        out.append(1.0 / (1.0 + np.exp(-log_odds)))
    return np.array(out)


def map_error(estimate: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Sum over cells of |estimate - truth| (the paper's map error), per leading index."""
    return np.abs(estimate - world).sum(axis=-1)


def crm_config_2d(variance: float, num_bins: int | None = None) -> CrmConfig:
    """The CRM of the 2D experiment: the paper's model as is (readings from cell centres, no
    spurious readings), the sensor's true noise; nothing tuned."""
    changes = {} if num_bins is None else {"num_bins": num_bins}
    return CrmConfig(
        voxel_size=CELL,
        max_range=RANGE,
        range_sigma_m=math.sqrt(variance),
        cause_range="centre",
        spurious_probability=0.0,
        **changes,
    )


def ism_final(z: np.ndarray, beams: Beams2D, settings: list[dict]) -> np.ndarray:
    """(36,400) probability of each ISM setting's map after the whole run."""
    end = np.array([beams.num_scans])
    return np.array([ism_run(z, beams, s, end)[-1] for s in settings])


def part_2d(args) -> dict:
    maps = 5 if args.quick else 50
    duration = 10.0 if args.quick else DURATION_S
    beams = make_beams(duration)
    checkpoints = np.arange(int(RATE_HZ), beams.num_scans + 1, int(RATE_HZ))  # every second
    settings = ism_settings()
    paper = settings.index(ISM_PAPER)
    config = crm_config_2d(NOISE_VARIANCE)
    rng = np.random.default_rng(2018)
    worlds = [random_world(rng) for _ in range(maps)]
    z_all = [readings(w, beams, NOISE_VARIANCE, rng) for w in worlds]

    start = time.perf_counter()
    crm_error, crm_inc, ism_error, ism_inc, crm_curves, ism_curves, crm_s = [], [], [], [], [], [], 0.0
    crm_visible, ism_visible, crm_brier, ism_brier = [], [], [], []
    with np.errstate(over="ignore", invalid="ignore"):
        for world, z in tqdm(list(zip(worlds, z_all)), desc="2D worlds", leave=False):
            t0 = time.perf_counter()
            mean, variance = crm_run(z, beams, config, checkpoints)
            crm_s += time.perf_counter() - t0
            p = ism_final(z, beams, settings)
            crm_error.append(map_error(mean[-1], world))
            crm_inc.append(inconsistency(mean[-1], variance[-1], world))
            visible = visible_cells(world, beams)
            crm_visible.append(map_error(mean[-1][visible], world[visible]))
            ism_visible.append(map_error(p[:, visible], world[visible]))
            crm_brier.append(float(((mean[-1] - world) ** 2).sum()))
            ism_brier.append(((p - world) ** 2).sum(axis=1))
            ism_error.append(map_error(p, world))
            ism_inc.append([inconsistency(q, q * (1 - q), world) for q in p])
            crm_curves.append(map_error(mean, world))
            ism_curves.append(map_error(ism_run(z, beams, ISM_PAPER, checkpoints), world))
        mean0, variance0 = crm_run(z_all[0], beams, config, checkpoints[-1:])
        fig3 = {
            "world": worlds[0],
            "crm_mean": mean0[-1],
            "crm_variance": variance0[-1],
            "visible": visible_cells(worlds[0], beams),
            "ism": ism_run(z_all[0], beams, ISM_PAPER, checkpoints[-1:])[-1],
            "crm_curve": crm_curves[0],
            "ism_curve": ism_curves[0],
            "time_s": checkpoints / RATE_HZ,
        }
        noise = noise_levels(args, beams, checkpoints)
        bins = bin_tradeoff(args, beams, worlds, z_all) if not args.quick or args.bins else None
    seconds = time.perf_counter() - start
    crm_error, crm_inc = np.array(crm_error), np.array(crm_inc)
    ism_error, ism_inc = np.array(ism_error), np.array(ism_inc)
    crm_visible, ism_visible = np.array(crm_visible), np.array(ism_visible)
    crm_brier, ism_brier = np.array(crm_brier), np.array(ism_brier)
    result = {
        "setup": {
            "world_m": 2 * HALF * CELL,
            "cell_m": CELL,
            "range_m": RANGE,
            "fov_deg": FOV_DEG,
            "beams": BEAMS,
            "rate_hz": RATE_HZ,
            "turn_deg_s": TURN_DEG_S,
            "duration_s": duration,
            "noise_variance_m2": NOISE_VARIANCE,
            "maps": maps,
            "occupied_fraction": 0.5,
            "readings": "Eq. 17: distance to the centre of the first occupied cell plus noise; past 1 m: no return",
            "crm": config.to_dict(),
            "ism_settings": settings,
            "ism_paper_setting": paper,
        },
        "crm_error": crm_error.tolist(),
        "ism_error": ism_error.tolist(),
        "crm_inconsistency": crm_inc.tolist(),
        "ism_inconsistency": ism_inc.tolist(),
        # the same error over the cells some beam can reach (up to the first obstacle): without the
        # cells no sensor sees, where a map can only bet on the world's share of occupied cells
        "crm_error_visible": crm_visible.tolist(),
        "ism_error_visible": ism_visible.tolist(),
        # sum of squared errors (the Brier score), which the mean of a distribution minimises; the
        # summed |error| above rewards saturated 0/1 estimates whenever they are right more often than not
        "crm_squared_error": crm_brier.tolist(),
        "ism_squared_error": ism_brier.tolist(),
        "summary": {
            "maps_crm_error_below_all_36": int(np.sum(crm_error < ism_error.min(axis=1))),
            "maps_crm_error_below_paper_ism": int(np.sum(crm_error < ism_error[:, paper])),
            "maps_crm_inconsistency_below_all_36": int(np.sum(crm_inc < ism_inc.min(axis=1))),
            "maps_crm_error_below_each_setting": np.sum(crm_error[:, None] < ism_error, axis=0).tolist(),
            "best_fixed_ism_setting": settings[int(np.argmin(ism_error.mean(axis=0)))],
            "maps_crm_visible_error_below_all_36": int(np.sum(crm_visible < ism_visible.min(axis=1))),
            "crm_visible_error_mean": float(crm_visible.mean()),
            "maps_crm_squared_error_below_all_36": int(np.sum(crm_brier < ism_brier.min(axis=1))),
            "crm_squared_error_mean": float(crm_brier.mean()),
            "best_fixed_ism_squared_error_mean": float(ism_brier.mean(axis=0).min()),
            "best_fixed_ism_visible_error_mean": float(ism_visible.mean(axis=0).min()),
            "crm_error_mean": float(crm_error.mean()),
            "best_ism_error_mean": float(ism_error.min(axis=1).mean()),
            "best_fixed_ism_error_mean": float(ism_error.mean(axis=0).min()),
            "crm_inconsistency_mean": float(crm_inc.mean()),
            "best_ism_inconsistency_mean": float(ism_inc.min(axis=1).mean()),
        },
        "error_over_time": {
            "time_s": (checkpoints / RATE_HZ).tolist(),
            "crm": np.mean(crm_curves, axis=0).tolist(),
            "ism_paper": np.mean(ism_curves, axis=0).tolist(),
        },
        "noise_levels": noise,
        "bins_tradeoff": bins,
        "seconds": {"total": seconds, "crm_integration": crm_s},
    }
    figures_2d(args.out, result, fig3)
    return result


def noise_levels(args, beams: Beams2D, checkpoints: np.ndarray) -> dict:
    """Fig. 5: mean error over time at each noise variance, CRM and the paper's ISM, over a few worlds."""
    worlds = 2 if args.quick else 10
    out = {
        "variances_m2": list(NOISE_LEVELS),
        "worlds": worlds,
        "time_s": (checkpoints / RATE_HZ).tolist(),
        "crm": [],
        "ism_paper": [],
    }
    rng = np.random.default_rng(5)
    for variance in tqdm(NOISE_LEVELS, desc="noise levels", leave=False):
        crm, ism = [], []
        for _ in range(worlds):
            world = random_world(rng)
            z = readings(world, beams, variance, rng)
            crm.append(map_error(crm_run(z, beams, crm_config_2d(variance), checkpoints)[0], world))
            ism.append(map_error(ism_run(z, beams, ISM_PAPER, checkpoints), world))
        out["crm"].append(np.mean(crm, axis=0).tolist())
        out["ism_paper"].append(np.mean(ism, axis=0).tolist())
    return out


def bin_tradeoff(args, beams: Beams2D, worlds: list, z_all: list) -> dict:
    """Map error, inconsistency, bytes per voxel of the CRM against its number of bins, and how far
    its mean strays from a 64-bin filter's on the observed cells (the discretisation error)."""
    counts = (4, 8, 16, 32, 64)
    use = min(len(worlds), 3 if args.quick else 10)
    end = np.array([beams.num_scans])
    out = {
        "num_bins": list(counts),
        "worlds": use,
        "error": [],
        "inconsistency": [],
        "mean_vs_64_bins": [],
        "bytes_per_voxel": [],
    }
    means = {}
    for k in tqdm(counts, desc="bin counts", leave=False):
        config = crm_config_2d(NOISE_VARIANCE, k)
        errors, incs, means[k] = [], [], []
        for world, z in zip(worlds[:use], z_all[:use]):
            mean, variance = crm_run(z, beams, config, end)
            errors.append(map_error(mean[-1], world))
            incs.append(inconsistency(mean[-1], variance[-1], world))
            means[k].append(mean[-1])
        out["error"].append(float(np.mean(errors)))
        out["inconsistency"].append(float(np.mean(incs)))
        out["bytes_per_voxel"].append(ConfidenceMap(config, device="cpu").bytes_per_voxel)
    fine = np.array(means[counts[-1]])
    observed = fine != 0.5
    out["mean_vs_64_bins"] = [float(np.abs(np.array(means[k]) - fine)[observed].mean()) for k in counts]
    return out


def figures_2d(out: Path, result: dict, fig3: dict) -> None:
    crm_error, ism_error = np.array(result["crm_error"]), np.array(result["ism_error"])
    crm_inc, ism_inc = np.array(result["crm_inconsistency"]), np.array(result["ism_inconsistency"])
    paper = result["setup"]["ism_paper_setting"]
    grid = lambda v: np.asarray(v).reshape(2 * HALF, 2 * HALF).T  # noqa: E731  (x right, y up)
    extent = (-HALF * CELL, HALF * CELL, -HALF * CELL, HALF * CELL)

    fig, axes = plt.subplots(1, 4, figsize=(16, 4))
    for ax, (title, values) in zip(
        axes[:3],
        (
            ("ground truth", fig3["world"]),
            ("log-odds, the paper's ISM", fig3["ism"]),
            ("confidence-rich map (mean)", fig3["crm_mean"]),
        ),
    ):
        ax.imshow(grid(values), origin="lower", cmap="gray_r", vmin=0, vmax=1, extent=extent)
        ax.plot(0, 0, "r^")
        ax.set_title(title)
    axes[3].plot(fig3["time_s"], fig3["ism_curve"], "r", label="log-odds (paper's ISM)")
    axes[3].plot(fig3["time_s"], fig3["crm_curve"], "b", label="confidence-rich")
    axes[3].set_xlabel("time (s)")
    axes[3].set_ylabel("map error (sum |mean - truth|)")
    axes[3].legend()
    fig.suptitle("Fig. 3: one random world")
    fig.tight_layout()
    fig.savefig(out / "crm_2d_fig3.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(13, 4.5))
    x = np.arange(ism_error.shape[1] + 1)
    errors = np.r_[ism_error.mean(axis=0), crm_error.mean()]
    incs = np.r_[ism_inc.mean(axis=0), crm_inc.mean()]
    ax.bar(x, errors, color=["tab:blue"] * (len(x) - 1) + ["tab:red"])
    ax.vlines(x, errors - incs, errors, color="k", lw=3, label="inconsistency I_c (part of the error)")
    labels = [f"{s['q']:.2f}/{s['r_ramp']:g}/{s['r_top']:g}" for s in result["setup"]["ism_settings"]] + ["CRM"]
    ax.set_xticks(x, labels, rotation=90, fontsize=7)
    ax.set_ylim(min(errors - incs) * 0.95, max(errors) * 1.02)
    ax.set_ylabel("map error, mean over worlds")
    ax.set_title("Fig. 4: 36 inverse sensor models (q_h - 0.5 / r_ramp / r_top) and the confidence-rich map")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "crm_2d_fig4.png", dpi=110)
    plt.close(fig)

    noise = result["noise_levels"]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for i, variance in enumerate(noise["variances_m2"]):
        color = plt.cm.viridis(i / max(1, len(noise["variances_m2"]) - 1))
        ax.plot(noise["time_s"], noise["crm"][i], color=color, label=f"R = {variance:g} m²")
        ax.plot(noise["time_s"], noise["ism_paper"][i], color=color, ls="--")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"map error, mean over {noise['worlds']} worlds")
    ax.set_title("Fig. 5: noise levels (solid: CRM, dashed: log-odds)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "crm_2d_fig5.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(10, 4))
    worlds = np.arange(len(crm_error))
    ax.bar(worlds, ism_error.min(axis=1) - crm_error, color="tab:green", label="best of 36 ISMs - CRM")
    ax.plot(worlds, ism_error[:, paper] - crm_error, "k.", label="paper's ISM - CRM")
    ax.axhline(0, color="gray", lw=0.8)
    ax.set_xlabel("world")
    ax.set_ylabel("error improvement (positive: CRM better)")
    ax.set_title("Fig. 6: improvement of the map error in each world")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "crm_2d_fig6.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(14, 4.5))
    world = fig3["world"]
    e_crm, s_crm = fig3["crm_mean"] - world, 2 * np.sqrt(fig3["crm_variance"])
    e_ism, s_ism = fig3["ism"] - world, 2 * np.sqrt(fig3["ism"] * (1 - fig3["ism"]))
    shown = np.flatnonzero(fig3["visible"] & ((np.abs(e_crm) > 0.1) | (np.abs(e_ism) > 0.1)))
    i = np.arange(len(shown))
    axes[0].plot(i, e_crm[shown], "b.", label="CRM error")
    axes[0].fill_between(i, -s_crm[shown], s_crm[shown], color="b", alpha=0.15, label="CRM ±2σ")
    axes[0].plot(i, e_ism[shown] - 2.5, "r.", label="log-odds error (shifted -2.5)")
    axes[0].fill_between(i, -s_ism[shown] - 2.5, s_ism[shown] - 2.5, color="r", alpha=0.15, label="log-odds ±2σ")
    axes[0].set_xlabel("visible voxels with an error above 0.1 (world 0)")
    axes[0].set_title("Fig. 7(a): errors and their 2σ bounds")
    axes[0].legend(fontsize=8)
    axes[1].plot(worlds, ism_inc[:, paper], "rs", label="log-odds, paper's ISM")
    axes[1].plot(worlds, ism_inc.min(axis=1), "r_", ms=10, label="log-odds, least of 36 ISMs")
    axes[1].plot(worlds, crm_inc, "bo", label="confidence-rich")
    axes[1].set_xlabel("world")
    axes[1].set_ylabel("inconsistency I_c")
    axes[1].set_title("Fig. 7(b): inconsistency per world")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "crm_2d_fig7.png", dpi=110)
    plt.close(fig)
    if result["bins_tradeoff"]:
        bins = result["bins_tradeoff"]
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.plot(bins["bytes_per_voxel"], bins["error"], "o-")
        for k, b, e in zip(bins["num_bins"], bins["bytes_per_voxel"], bins["error"]):
            ax.annotate(f"{k} bins", (b, e), textcoords="offset points", xytext=(4, 4))
        ax.set_xlabel("bytes per voxel")
        ax.set_ylabel(f"map error, mean over {bins['worlds']} worlds")
        ax.set_title("Bins: accuracy against memory")
        fig.tight_layout()
        fig.savefig(out / "crm_2d_bins.png", dpi=110)
        plt.close(fig)


# ---------------------------------------------------------------- Part 2: sonar scans of a scene
SONAR_SPEED_M_S = 0.5
NOISES_3D = (0.02, 0.05, 0.1)  # m, sonar range noise
TIMED_NOISE = 0.05


def survey_poses(scene, rate_hz: float, laps: int) -> np.ndarray:
    """(S,4,4) T_world_vehicle along the scene's survey at SONAR_SPEED_M_S, one per scan."""
    from vogjax.geometry import pose_from_xyz_yaw

    waypoints = scene.survey(laps)
    xyz, yaw = waypoints[:, :3], np.unwrap(waypoints[:, 3])
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))]
    s = np.arange(0.0, along[-1], SONAR_SPEED_M_S / rate_hz)
    path = np.stack([np.interp(s, along, xyz[:, i]) for i in range(3)] + [np.interp(s, along, yaw)], axis=1)
    return np.array([pose_from_xyz_yaw(*row) for row in path])


def sonar_rays(scene, noise_m: float, laps: int, seed: int):
    """World rays of a simulated survey: origins (S,3), endpoints (S*B,3), scan index (S*B,)."""
    from vogjax import sensors, sim

    config = vj.SonarConfig(range_noise_m=noise_m)
    sonar = sensors.ProfilingSonar(config)
    T_world_sensor = survey_poses(scene, config.rate_hz, laps) @ sonar.T_vehicle_sensor
    scans = sim.scan(scene.warp_mesh, T_world_sensor, sonar, np.random.default_rng(seed))
    length = np.where(scans.no_return, config.max_range_m * 1.05 + 0.1, scans.ranges)
    points = scans.origins[:, None] + scans.directions * length[..., None]
    count, beams = scans.ranges.shape
    valid = ~scans.invalid.reshape(-1)  # a surface within the blind distance: the beam clears nothing
    return (
        scans.origins,
        points.reshape(-1, 3)[valid],
        np.repeat(np.arange(count), beams)[valid],
        float(scans.no_return.mean()),
    )


def labelled(truth, centres: np.ndarray):
    """Truth labels (V,) of voxel centres (FREE, OCCUPIED, INSIDE; 0 outside the labelled box)."""
    keys = np.floor(centres / truth.voxel_size).astype(np.int64) - truth.first_key
    inside = np.all((keys >= 0) & (keys < truth.labels.shape), axis=1)
    labels = np.zeros(len(centres), np.int8)
    labels[inside] = truth.labels[tuple(keys[inside].T)]
    return labels


def best_time(repeats: int, build):
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = build()
        wp.synchronize()
        times.append(time.perf_counter() - start)
    return min(times), result


def part_3d(args) -> dict:
    from vogjax import scenes
    from vogjax.report.metrics import roc

    scene = scenes.load(args.scene)
    truth = scene.occupancy(0.1)
    laps = 1 if args.quick else 2
    map_config = vj.MapConfig(voxel_size=0.1, max_range=11.0)
    out = {
        "scene": args.scene,
        "laps": laps,
        "voxel_size_m": 0.1,
        "map_config": map_config.to_dict(),
        "noise": [],
        "machine": machine(args.device),
    }
    for noise in tqdm(NOISES_3D, desc="sonar noise", leave=False):
        origins, points, scan_index, no_return = sonar_rays(scene, noise, laps, seed=11)
        crm_config = CrmConfig(voxel_size=0.1, max_range=11.0, range_sigma_m=noise)
        timed = noise == TIMED_NOISE
        repeats = 1 if args.quick or not timed else 5
        # compile and warm both first; then alternate them, so both see the same machine load
        ConfidenceMap(crm_config, args.device).integrate_scans(
            origins[:4], points[scan_index < 4], scan_index[scan_index < 4]
        )
        vj.VoxelMap(map_config, args.device).integrate_scans(
            origins[:4], points[scan_index < 4], scan_index[scan_index < 4]
        )
        pairs = []
        for _ in range(repeats):
            t_vox, voxmap = best_time(
                1, lambda: _built(vj.VoxelMap(map_config, args.device), origins, points, scan_index)
            )
            t_crm, crm = best_time(
                1, lambda: _built(ConfidenceMap(crm_config, args.device), origins, points, scan_index)
            )
            pairs.append((t_crm, t_vox))
        pairs = np.array(pairs)
        t_crm, t_vox = pairs.min(axis=0)
        centres, crm_mean, crm_variance = crm.voxels()
        vox_centres, _ = voxmap.voxels()
        labels = labelled(truth, centres)
        both = np.isin(_packed(centres), _packed(vox_centres))
        keep = both & np.isin(labels, (scenes.FREE, scenes.OCCUPIED))
        occupied = labels[keep] == scenes.OCCUPIED
        target = occupied.astype(np.float64)
        crm_scores = crm_mean[keep].astype(np.float64)
        vox_scores = voxmap.probability(centres[keep]).astype(np.float64)
        crm_error = np.abs(crm_scores - target)
        vox_error = np.abs(vox_scores - target)
        row = {
            "range_noise_m": noise,
            "scans": int(origins.shape[0]),
            "rays": int(points.shape[0]),
            "no_return_fraction": no_return,
            "crm_config": crm_config.to_dict(),
            "voxels_compared": int(keep.sum()),
            "occupied_voxels": int(occupied.sum()),
            "crm_observed_voxels": int(len(centres)),
            "voxelmap_observed_voxels": int(len(vox_centres)),
            "mean_abs_error": {
                "crm": float(crm_error.mean()),
                "voxelmap": float(vox_error.mean()),
                "crm_occupied": float(crm_error[occupied].mean()),
                "voxelmap_occupied": float(vox_error[occupied].mean()),
                "crm_free": float(crm_error[~occupied].mean()),
                "voxelmap_free": float(vox_error[~occupied].mean()),
            },
            "voxels_crm_closer": float(np.mean(crm_error < vox_error)),
            "auc": {"crm": roc(crm_scores, occupied).auc, "voxelmap": roc(vox_scores, occupied).auc},
            "inconsistency_per_voxel": {
                "crm": inconsistency(crm_scores, crm_variance[keep], target) / keep.sum(),
                "voxelmap": inconsistency(vox_scores, vox_scores * (1 - vox_scores), target) / keep.sum(),
            },
            "integration_s": {
                "crm": float(t_crm),
                "voxelmap": float(t_vox),
                "ratio": float(t_crm / t_vox),
                "median_paired_ratio": float(np.median(pairs[:, 0] / pairs[:, 1])),
                "repeats": repeats,
                "timed": timed,
            },
            "memory": {
                "crm_bytes_per_voxel": crm.bytes_per_voxel,
                "voxelmap_bytes_per_voxel": 4,
                "crm_bytes": crm.memory_bytes(),
                "voxelmap_bytes": voxmap.memory_bytes(),
                "crm_blocks": crm.num_blocks,
                "voxelmap_blocks": voxmap.num_blocks,
            },
        }
        out["noise"].append(row)
        if timed:
            out["bins_tradeoff"] = bins_3d(args, crm_config, origins, points, scan_index, truth, vox_centres)
    return out


def bins_3d(args, config: CrmConfig, origins, points, scan_index, truth, vox_centres) -> dict:
    """Per bin count on the same rays: error and AUC against the truth, how far the mean and the
    standard deviation stray from a 64-bin filter's (the discretisation error), memory, time."""
    from vogjax import scenes
    from vogjax.report.metrics import roc

    counts = (4, 8, 16, 32, 64)
    maps = {}
    out = {
        "num_bins": list(counts),
        "mean_abs_error": [],
        "auc": [],
        "mean_vs_64_bins": [],
        "std_vs_64_bins": [],
        "bytes_per_voxel": [],
        "integration_s": [],
    }
    for k in tqdm(counts, desc="bin counts", leave=False):
        cfg = config.replace(num_bins=k)
        ConfidenceMap(cfg, "cpu").integrate_scans(origins[:2], points[scan_index < 2], scan_index[scan_index < 2])
        seconds, crm = best_time(1, lambda: _built(ConfidenceMap(cfg, "cpu"), origins, points, scan_index))
        maps[k] = crm.voxels()
        out["bytes_per_voxel"].append(crm.bytes_per_voxel)
        out["integration_s"].append(seconds)
    centres, mean64, variance64 = maps[64]
    labels = labelled(truth, centres)
    keep = np.isin(_packed(centres), _packed(vox_centres)) & np.isin(labels, (scenes.FREE, scenes.OCCUPIED))
    occupied = labels[keep] == scenes.OCCUPIED
    for k in counts:
        _, mean, variance = maps[k]
        out["mean_abs_error"].append(float(np.abs(mean[keep] - occupied).mean()))
        out["auc"].append(roc(mean[keep].astype(np.float64), occupied).auc)
        out["mean_vs_64_bins"].append(float(np.abs(mean - mean64).mean()))
        out["std_vs_64_bins"].append(float(np.abs(np.sqrt(variance) - np.sqrt(variance64)).mean()))
    return out


def _built(vmap, origins, points, scan_index):
    vmap.integrate_scans(origins, points, scan_index)
    return vmap


def _packed(centres: np.ndarray) -> np.ndarray:
    """One int64 per voxel centre (10 cm voxels), to match the voxels of two maps."""
    keys = np.floor(centres / 0.1).astype(np.int64) + (1 << 20)
    return (keys[:, 0] << 42) | (keys[:, 1] << 21) | keys[:, 2]


def print_3d(result: dict) -> None:
    print(f"3D, scene {result['scene']}, {result['laps']} laps of its survey:")
    if "bins_tradeoff" in result:
        b = result["bins_tradeoff"]
        print(
            "   bins: "
            + ", ".join(
                f"{k}: |mean - 64 bins| {d:.3f}, {n} B/voxel"
                for k, d, n in zip(b["num_bins"], b["mean_vs_64_bins"], b["bytes_per_voxel"])
            )
        )
    for row in result["noise"]:
        e, a, t = row["mean_abs_error"], row["auc"], row["integration_s"]
        print(
            f"   noise {row['range_noise_m']:.2f} m, {row['rays']} rays: mean |error| CRM {e['crm']:.3f} vs log-odds "
            f"{e['voxelmap']:.3f} on {row['voxels_compared']} voxels; AUC CRM {a['crm']:.3f} vs {a['voxelmap']:.3f}; "
            f"integration CRM {t['crm']:.2f} s vs {t['voxelmap']:.2f} s ({t['ratio']:.1f}x)"
        )


def machine(device: str) -> dict:
    return {
        "device": device,
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "warp": wp.__version__,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--part", choices=("all", "2d", "3d"), default="all")
    parser.add_argument("--quick", action="store_true", help="a smoke run: few worlds, short runs")
    parser.add_argument("--bins", action="store_true", help="with --quick: still measure the bin counts")
    parser.add_argument("--scene", default="tank", help="built-in scene of the 3D part")
    parser.add_argument("--device", default="cpu", help="Warp device of the 3D part (cpu, cuda:0)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    vj.devices.init()
    if args.part in ("all", "2d"):
        result = part_2d(args)
        result["machine"] = machine("cpu")
        (args.out / "crm_2d.json").write_text(json.dumps(result, indent=1))
        s = result["summary"]
        print(
            f"2D, {result['setup']['maps']} worlds in {result['seconds']['total']:.0f} s: CRM error below all 36 ISMs "
            f"in {s['maps_crm_error_below_all_36']}, below the paper's ISM in {s['maps_crm_error_below_paper_ism']}; "
            f"inconsistency below all 36 in {s['maps_crm_inconsistency_below_all_36']}"
        )
        print(
            f"   mean error CRM {s['crm_error_mean']:.2f}, best fixed ISM {s['best_fixed_ism_error_mean']:.2f}, best "
            f"ISM "
            f"per world {s['best_ism_error_mean']:.2f}; visible cells: CRM {s['crm_visible_error_mean']:.2f}, best "
            f"fixed "
            f"ISM {s['best_fixed_ism_visible_error_mean']:.2f}; squared error CRM {s['crm_squared_error_mean']:.2f}, "
            f"best "
            f"fixed ISM {s['best_fixed_ism_squared_error_mean']:.2f} (CRM below all 36 in "
            f"{s['maps_crm_squared_error_below_all_36']} worlds); mean I_c CRM {s['crm_inconsistency_mean']:.2f}, "
            f"least ISM per world {s['best_ism_inconsistency_mean']:.2f}"
        )
    if args.part in ("all", "3d"):
        result = part_3d(args)
        (args.out / f"crm_3d_{args.device.split(':')[0]}.json").write_text(json.dumps(result, indent=1))
        print_3d(result)


if __name__ == "__main__":
    main()
