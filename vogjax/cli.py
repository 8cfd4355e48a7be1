"""The `vogjax` command."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


SCENES = "a built-in scene: propeller, pilings, tank or boxes"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="vogjax", description="GPU/JAX occupancy mapping")
    commands = parser.add_subparsers(dest="command", required=True)
    demo = commands.add_parser("demo", help="simulate a survey of a built-in scene and map it with loop closures")
    demo.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder")
    demo.add_argument("--scene", default="propeller", help=SCENES)
    demo.add_argument("--laps", type=int, default=2, help="times the survey is flown")
    demo.add_argument("--quiet", action="store_true", help="no progress bars")
    sim = commands.add_parser("simulate", help="simulate a sonar survey of a built-in scene")
    sim.add_argument("--scene", required=True, help=SCENES)
    sim.add_argument("--out", type=Path, required=True, help="run file to write (HDF5)")
    sim.add_argument("--laps", type=int, default=2, help="times the survey is flown")
    sim.add_argument("--scans", type=int, default=None, help="number of scans (default: enough)")
    sim.add_argument("--seed", type=int, default=0, help="seed of the navigation and range noise")
    sim.add_argument("--range-noise", type=float, default=0.02, help="sonar range noise, metres")
    mapping = commands.add_parser("map", help="reprocess runs into loop-closure-consistent maps, with reports")
    mapping.add_argument("runs", nargs="+", type=Path, help="run files (HDF5, from `vogjax simulate` or a logger)")
    mapping.add_argument("--out", type=Path, required=True, help="output folder: one sub-folder per run")
    mapping.add_argument("--config", type=Path, default=None, help="TOML settings (see README)")
    mapping.add_argument("--quiet", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    if args.command == "map":
        from vogjax import report
        from vogjax.config import JobConfig

        try:
            config = JobConfig.from_toml(args.config) if args.config else JobConfig()
            reports = report.map_runs(args.runs, args.out, config, progress=not args.quiet)
        except ValueError as error:
            parser.error(str(error))
        print(report.summary_table(reports))
        print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
    if args.command == "simulate":
        from vogjax.config import SonarConfig
        from vogjax.sim import simulate_run

        try:
            summary = simulate_run(args.scene, args.out, laps=args.laps, seed=args.seed,
                                   num_scans=args.scans, sensor=SonarConfig(range_noise_m=args.range_noise))
        except ValueError as error:
            parser.error(str(error))
        print(f"wrote {summary.path}: {summary.scans} scans, {summary.duration_s:.0f} s of survey, "
              f"{summary.returns:.0%} of beams returned")
    if args.command == "demo":
        from vogjax import demo as demo_module

        try:
            demo_module.run(args.out, args.scene, args.laps, progress=not args.quiet)
        except ValueError as error:
            parser.error(str(error))
    return 0


if __name__ == "__main__":
    sys.exit(main())
