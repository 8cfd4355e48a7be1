"""`vogjax simulate`: a sonar survey of a built-in scene, written as a run file."""

from __future__ import annotations

import argparse
from pathlib import Path

from vogjax.commands.common import add_output_flags, refuse_existing, ruled

DESCRIPTION = """\
Simulate a survey of a built-in scene: an MJX-simulated underwater vehicle flies the scene's
survey pattern with a forward-looking profiling sonar (96 beams over 29 degrees, 5 Hz), its
navigation drifting as in Sodhi et al. (Eq. 10), and the scans, the drifting navigation and
the true poses are written to a run file (HDF5) that `vogjax map` reprocesses. Same scene,
scans and seed: the same run, bit for bit."""

EPILOG = """\
examples:
  vogjax simulate --scene boxes --scans 600 --out boxes.h5
  vogjax simulate --scene propeller --laps 3 --seed 7 --out propeller.h5 --overwrite"""


def scene_names() -> tuple[str, ...]:
    """The built-in scenes' names.

    Returns
    -------
    tuple of str
        `vogjax.scenes.NAMES`.
    """
    from vogjax import scenes

    return scenes.NAMES


def scene_help() -> str:
    """The help of a `--scene` flag.

    Returns
    -------
    str
        "a built-in scene: propeller, pilings, tank, boxes".
    """
    return f"a built-in scene: {', '.join(scene_names())}"


def add_parser(commands) -> None:
    """Declare `vogjax simulate` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    from vogjax.scenes.scene import MAX_LAPS

    sim = commands.add_parser(
        "simulate", help="simulate a sonar survey of a built-in scene", description=DESCRIPTION, epilog=EPILOG
    )
    sim.add_argument("--scene", required=True, choices=scene_names(), help=scene_help())
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
        "--range-noise", type=ruled("number", 0), default=0.02, metavar="M", help="sonar range noise (Gaussian), metres"
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
    from vogjax.config import SonarConfig
    from vogjax.sim import simulate_run
    from vogjax.sim.mission import MAX_SCANS

    refuse_existing(args.out, args.overwrite)
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
