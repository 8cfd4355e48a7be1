"""`vogjax map`: reprocess runs into loop-closure-consistent maps, with a report per run."""

from __future__ import annotations

import sys
from pathlib import Path


def add_parser(commands) -> None:
    mapping = commands.add_parser("map", help="reprocess runs into loop-closure-consistent maps, with reports")
    mapping.add_argument("runs", nargs="+", type=Path, help="run files (HDF5, from `vogjax simulate` or a logger)")
    mapping.add_argument("--out", type=Path, required=True, help="output folder: one sub-folder per run")
    mapping.add_argument("--config", type=Path, default=None, help="TOML settings (see README)")
    mapping.add_argument(
        "--preset", default=None, help="settings to start from: default or paper (--config overrides them)"
    )
    mapping.add_argument(
        "--workers",
        type=int,
        default=None,
        help="map this many runs at once with Ray, each in its own process; a run that fails "
        "fails alone (pip install 'vogjax[workers]')",
    )
    mapping.add_argument(
        "--address",
        default=None,
        help="with --workers: an existing Ray cluster (e.g. ray://head:10001, or auto); default: a local one",
    )
    mapping.add_argument(
        "--crm",
        action="store_true",
        help="also build a confidence-rich map of each run ([pipeline] confidence_map = true)",
    )
    mapping.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args) -> None:
    from vogjax import report
    from vogjax.config import JobConfig

    base = JobConfig.preset(args.preset)
    config = JobConfig.from_toml(args.config, base) if args.config else base
    if args.crm:
        config = config.replace(pipeline=config.pipeline.replace(confidence_map=True))
    if args.workers is None and args.address is None:
        reports = report.map_runs(args.runs, args.out, config, progress=not args.quiet)
        print(report.summary_table(reports))
        print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
        return
    from vogjax.report.workers import map_runs_parallel

    workers = len(args.runs) if args.workers is None else args.workers
    outcomes = map_runs_parallel(args.runs, args.out, config, workers, args.address, progress=not args.quiet)
    reports = [o.report for o in outcomes if o.report is not None]
    if reports:
        print(report.summary_table(reports))
        print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
    failed = [o for o in outcomes if o.error is not None]
    for outcome in failed:
        print(f"vogjax map: error: {outcome.path}: {outcome.error}", file=sys.stderr)
    if failed:
        raise SystemExit(2)
