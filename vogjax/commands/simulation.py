"""`vogjax simulate`: a sonar survey, or a spinning lidar's drive, of a built-in scene, written as a run file."""

from __future__ import annotations

import argparse
from pathlib import Path

from vogjax.commands.common import add_output_flags, refuse_existing, ruled

DESCRIPTION = """\
Simulate a survey of a built-in scene: an MJX-simulated underwater vehicle flies the scene's
survey pattern with a forward-looking profiling sonar (96 beams over 29 degrees, 5 Hz), its
navigation drifting as in Sodhi et al. (Eq. 10), and the scans, the drifting navigation and
the true poses are written to a run file (HDF5) that `vogjax map` reprocesses. The warehouse is
a ground scene: a ground vehicle drives its perimeter aisle with a spinning lidar (16 rings over
+-15 degrees, 0.4 degree columns, 10 Hz, 0.5-50 m), its wheel odometry drifting in x, y and
yaw; every column is cast from where the sensor was when it fired, and the points are stored
deskewed with the odometry (--sweep). Same scene, scans and seed: the same run, bit for bit."""

EPILOG = """\
examples:
  vogjax simulate --scene boxes --scans 600 --out boxes.h5
  vogjax simulate --scene propeller --laps 3 --seed 7 --out propeller.h5 --overwrite
  vogjax simulate --scene warehouse --sensor lidar --out warehouse.h5"""


SENSORS = ("sonar", "lidar")


def scene_names(ground: bool = True) -> tuple[str, ...]:
    """The built-in scenes' names.

    Parameters
    ----------
    ground : bool, optional
        Include the ground scenes (driven with a lidar: `vogjax.scenes.GROUND_SCENES`); the
        commands that fly the HAUV leave them out.

    Returns
    -------
    tuple of str
        `vogjax.scenes.NAMES`, without the ground scenes unless `ground`.
    """
    from vogjax import scenes

    return tuple(n for n in scenes.NAMES if ground or n not in scenes.GROUND_SCENES)


def scene_help(ground: bool = True) -> str:
    """The help of a `--scene` flag.

    Parameters
    ----------
    ground : bool, optional
        Name the ground scenes too.

    Returns
    -------
    str
        "a built-in scene: propeller, pilings, tank, boxes, warehouse".
    """
    return f"a built-in scene: {', '.join(scene_names(ground))}"


def add_parser(commands) -> None:
    """Declare `vogjax simulate` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    from vogjax.scenes.scene import MAX_LAPS

    sim = commands.add_parser(
        "simulate",
        help="simulate a sonar survey (or a lidar's drive) of a built-in scene",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    sim.add_argument("--scene", required=True, choices=scene_names(), help=scene_help())
    sim.add_argument(
        "--sensor",
        choices=SENSORS,
        default=None,
        help="the range sensor: sonar (the HAUV's profiling sonar, on the underwater scenes) or lidar "
        "(a ground vehicle's spinning lidar, on the warehouse); default: the scene's",
    )
    sim.add_argument(
        "--sweep",
        choices=("deskewed", "raw", "instant"),
        default="deskewed",
        help="lidar only: store the points deskewed with the odometry, raw (motion-distorted, as if "
        "fired at the stamp) or fired all at the stamp (no distortion)",
    )
    sim.add_argument("--out", type=Path, required=True, metavar="RUN.h5", help="run file to write (HDF5)")
    sim.add_argument(
        "--laps",
        type=ruled("integer", 1, MAX_LAPS),
        metavar="N",
        default=None,
        help="times the survey is flown (default 2, or as many as --scans fill)",
    )
    sim.add_argument(
        "--scans",
        type=ruled("integer", 1),
        default=None,
        metavar="N",
        help="number of scans (default: enough for the laps)",
    )
    sim.add_argument(
        "--seed",
        type=ruled("integer", 0, 2**63 - 1),
        default=0,
        metavar="N",
        help="seed of the navigation and range noise",
    )
    sim.add_argument(
        "--range-noise", type=ruled("number", 0), default=0.02, metavar="M", help="range noise (Gaussian), metres"
    )
    sim.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    add_output_flags(sim)


def run(args: argparse.Namespace) -> None:
    """Simulate the survey and print what was written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax simulate`.
    """
    from vogjax import scenes

    refuse_existing(args.out, args.overwrite)
    ground = args.scene in scenes.GROUND_SCENES
    sensor = args.sensor or ("lidar" if ground else "sonar")
    if (sensor == "lidar") != ground:
        wanted = "lidar" if ground else "sonar"
        kind = "a ground scene, driven" if ground else "an underwater scene, flown"
        raise ValueError(f"--sensor {sensor}: the {args.scene} is {kind} with --sensor {wanted}")
    if sensor == "lidar":
        _simulate_lidar(args)
        return
    if args.sweep != "deskewed":
        raise ValueError("--sweep applies to --sensor lidar only")
    from vogjax.config import SonarConfig
    from vogjax.sim import simulate_run
    from vogjax.sim.mission import MAX_SCANS

    if args.scans is not None and args.scans > MAX_SCANS:
        raise ValueError(f"--scans must be at most {MAX_SCANS}, got {args.scans}")
    summary = simulate_run(
        args.scene,
        args.out,
        laps=args.laps,
        seed=args.seed,
        num_scans=args.scans,
        sensor=SonarConfig(range_noise_m=args.range_noise),
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(
        f"wrote {summary.path}: {summary.scans} scans, {summary.duration_s:.0f} s of survey, "
        f"{summary.returns:.0%} of beams returned"
    )


def _simulate_lidar(args: argparse.Namespace) -> None:
    """The lidar's drive of a ground scene, and a line of what was written."""
    from vogjax.config import LidarConfig
    from vogjax.sensors import SpinningLidar
    from vogjax.sim.lidar_mission import MAX_SCANS, simulate_lidar_run

    if args.scans is not None and args.scans > MAX_SCANS:
        raise ValueError(f"--scans must be at most {MAX_SCANS}, got {args.scans}")
    summary = simulate_lidar_run(
        args.scene,
        args.out,
        laps=args.laps,
        seed=args.seed,
        num_scans=args.scans,
        sensor=SpinningLidar(LidarConfig(range_noise_m=args.range_noise)),
        sweep=args.sweep,
        overwrite=args.overwrite,
        progress=not args.quiet,
    )
    print(
        f"wrote {summary.path}: {summary.scans} lidar scans ({summary.sweep}), {summary.duration_s:.0f} s of driving, "
        f"{summary.returns:.0%} of beams returned, {summary.invalid:.2%} invalid (nearer than the minimum range)"
    )
