"""`vogjax demo`: simulate a survey of a built-in scene and map it with loop closures."""

from __future__ import annotations

import argparse
from pathlib import Path

from vogjax.commands.common import add_output_flags, ruled
from vogjax.commands.simulation import scene_help, scene_names

DESCRIPTION = """\
The whole pipeline in one command: simulate a survey of a built-in scene (as `vogjax
simulate`, with 2 cm sonar range noise and drifting navigation) into DIR/<scene>.h5, map it
with loop closures (as `vogjax map`) into DIR/<scene>/, and print the summary table: the
maps' agreement with the ground truth, the trajectory errors and the timings. The demo's
own run file and report folder in DIR are replaced when it runs again. The propeller survey
of two laps (4,000 scans) takes under a minute on two CPU cores once Warp has compiled its
kernels."""

EPILOG = """\
examples:
  vogjax demo
  vogjax demo --scene boxes --laps 1 --out demo_boxes --quiet"""


def add_parser(commands) -> None:
    """Declare `vogjax demo` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    from vogjax.scenes.scene import MAX_LAPS

    demo = commands.add_parser(
        "demo",
        help="simulate a survey of a built-in scene and map it with loop closures",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    demo.add_argument("--out", type=Path, default=Path("demo_out"), metavar="DIR", help="output folder")
    demo.add_argument("--scene", default="propeller", choices=scene_names(ground=False), help=scene_help(ground=False))
    demo.add_argument(
        "--laps", type=ruled("integer", 1, MAX_LAPS), default=2, metavar="N", help="times the survey is flown"
    )
    add_output_flags(demo)


def run(args: argparse.Namespace) -> None:
    """Run the demo.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax demo`.
    """
    from vogjax import demo

    demo.run(args.out, args.scene, args.laps, progress=not args.quiet)
