"""`vogjax demo`: simulate a survey of a built-in scene and map it with loop closures."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands.simulation import scene_help


def add_parser(commands) -> None:
    demo = commands.add_parser("demo", help="simulate a survey of a built-in scene and map it with loop closures")
    demo.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    demo.add_argument("--scene", default="propeller", help=scene_help())
    demo.add_argument("--laps", type=int, default=2, help="times the survey is flown")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args) -> None:
    from vogjax import demo

    demo.run(args.out, args.scene, args.laps, progress=not args.quiet)
