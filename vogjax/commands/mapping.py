"""`vogjax map`: reprocess runs into loop-closure-consistent maps, with a report per run."""

from __future__ import annotations

from pathlib import Path


def add_parser(commands) -> None:
    mapping = commands.add_parser("map", help="reprocess runs into loop-closure-consistent maps, with reports")
    mapping.add_argument("runs", nargs="+", type=Path, help="run files (HDF5, from `vogjax simulate` or a logger)")
    mapping.add_argument("--out", type=Path, required=True, help="output folder: one sub-folder per run")
    mapping.add_argument("--config", type=Path, default=None, help="TOML settings (see README)")
    mapping.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args) -> None:
    from vogjax import report
    from vogjax.config import JobConfig

    config = JobConfig.from_toml(args.config) if args.config else JobConfig()
    reports = report.map_runs(args.runs, args.out, config, progress=not args.quiet)
    print(report.summary_table(reports))
    print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
