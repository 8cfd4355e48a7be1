"""`vogjax simulate`: a sonar survey of a built-in scene, written as a run file."""

from __future__ import annotations

from pathlib import Path


def scene_help() -> str:
    from vogjax import scenes

    return f"a built-in scene: {', '.join(scenes.NAMES)}"


def add_parser(commands) -> None:
    sim = commands.add_parser("simulate", help="simulate a sonar survey of a built-in scene")
    sim.add_argument("--scene", required=True, help=scene_help())
    sim.add_argument("--out", type=Path, required=True, help="run file to write (HDF5)")
    sim.add_argument(
        "--laps", type=int, default=None, help="times the survey is flown (default 2, or as many as --scans fill)"
    )
    sim.add_argument("--scans", type=int, default=None, help="number of scans (default: enough for the laps)")
    sim.add_argument("--seed", type=int, default=0, help="seed of the navigation and range noise")
    sim.add_argument("--range-noise", type=float, default=0.02, help="sonar range noise, metres")
    sim.add_argument("--overwrite", action="store_true", help="replace --out if it exists")


def run(args) -> None:
    from vogjax.config import SonarConfig
    from vogjax.sim import simulate_run

    summary = simulate_run(
        args.scene,
        args.out,
        laps=args.laps,
        seed=args.seed,
        num_scans=args.scans,
        sensor=SonarConfig(range_noise_m=args.range_noise),
        overwrite=args.overwrite,
    )
    print(
        f"wrote {summary.path}: {summary.scans} scans, {summary.duration_s:.0f} s of survey, "
        f"{summary.returns:.0%} of beams returned"
    )
