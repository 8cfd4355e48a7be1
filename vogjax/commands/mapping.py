"""`vogjax map`: reprocess runs into loop-closure-consistent maps, with a report per run."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vogjax.commands.common import add_output_flags, config_help, refuse_existing, ruled

DESCRIPTION = """\
Reprocess recorded runs into loop-closure-consistent occupancy maps. Each run's scans are cut
into submaps anchored to the nodes of an iSAM2 pose graph, loop closures are found by
registering submaps against earlier ones, and the online global map is kept consistent by
undoing and redoing only the submaps whose poses moved and are uncertain (Sodhi et al.,
Algorithm 1). Per run, DIR/<run name>/ receives the map (global_map.vog), the trajectories
(CSV and TUM), the loop closures, report.json and four figures (top_view.png,
trajectory.png, roc.png, timing.png); a run of a built-in scene is scored against its ground
truth. A table of each run's headline figures is printed. An existing run folder is kept
unless --overwrite is given; a folder appears only once everything in it is written."""

EPILOG = """\
examples:
  vogjax map boxes.h5 --out maps
  vogjax map a.h5 b.h5 --out maps --preset paper --config settings.toml --overwrite
  vogjax map runs/*.h5 --out maps --workers 4        # several runs at once (Ray)"""


def add_parser(commands) -> None:
    """Declare `vogjax map` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    from vogjax.config.pipeline import PRESETS
    from vogjax.config.presets import CHOICES

    mapping = commands.add_parser(
        "map",
        help="reprocess runs into loop-closure-consistent maps, with reports",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    mapping.add_argument(
        "runs",
        nargs="+",
        type=Path,
        metavar="RUN",
        help="run files (HDF5, from `vogjax simulate`, `import` or a logger)",
    )
    mapping.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder: one sub-folder per run")
    mapping.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="FILE",
        help=config_help(
            "[map], [nav_noise], [loop_closure] (with [loop_closure.icp], "
            "[loop_closure.correlative]), [pose_graph], [timing], [pipeline] and [report]"
        ),
    )
    mapping.add_argument(
        "--preset",
        choices=PRESETS,
        default="default",
        help="settings to start from: default, or paper (Sodhi et al. IV-C: 200 scans per submap, no "
        "clamping); --config overrides them",
    )
    mapping.add_argument(
        "--sensor-preset",
        choices=CHOICES,
        default="auto",
        help="each run's sensor and platform preset: auto (from the run's metadata: its sensor and "
        "odometry pick the map's reach and voxels, the submaps' length, the closure search and "
        "navigation noise; a sonar run's is the papers' defaults), none (the settings as given), or "
        "one of sonar, lidar, depth_camera, laser_scan; settings in --config or --preset win over it. "
        "What it derives is printed (on stderr) and recorded in report.json",
    )
    mapping.add_argument(
        "--workers",
        type=ruled("integer", 1),
        default=None,
        metavar="N",
        help="map this many runs at once with Ray, each in its own process; a run that fails "
        "fails alone (pip install 'vogjax[workers]'; default: one after another in this process, "
        "or with --address one worker per run)",
    )
    mapping.add_argument(
        "--address",
        default=None,
        metavar="ADDR",
        help="with --workers: an existing Ray cluster (e.g. ray://head:10001, or auto); default: a local one",
    )
    mapping.add_argument(
        "--crm",
        action="store_true",
        help="also build a confidence-rich map of each run ([pipeline] confidence_map = true)",
    )
    mapping.add_argument("--overwrite", action="store_true", help="replace a run's folder in --out if it exists")
    add_output_flags(mapping)


def run(args: argparse.Namespace) -> None:
    """Map the runs, print the summary table and the folders written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax map`.
    """
    from vogjax import report
    from vogjax.config import JobConfig, presets
    from vogjax.config.schema import read_toml
    from vogjax.io.atomic import check_writable
    from vogjax.report.job import refuse_inputs_inside

    for path in args.runs:
        refuse_existing(args.out / path.stem, args.overwrite, flag="--out", folder=True)
    folders = [args.out / path.stem for path in args.runs]
    refuse_inputs_inside(folders, args.runs)
    if args.config:
        refuse_inputs_inside(folders, [args.config], "--config")
    base = JobConfig.preset(args.preset)
    document = read_toml(args.config) if args.config else {}
    config = JobConfig.from_file_document(document, args.config, base) if args.config else base
    given = presets.changed_settings(base) | presets.given_settings(document)
    if args.crm:
        config = config.replace(pipeline=config.pipeline.replace(confidence_map=True))
    progress = not args.quiet
    for path in args.runs:  # outputs checked before anything is printed or mapped
        check_writable(args.out / path.stem, folder=True)
    for path in args.runs:  # what each run's preset derives, before any work
        try:
            derived = report.derive_settings(path, config, args.sensor_preset, given)
        except ValueError:  # an unreadable run: its error comes from mapping it (alone, with --workers)
            continue
        if not args.quiet:
            print(f"{path}: " + "\n".join(derived.lines()), file=sys.stderr)
    if args.workers is None and args.address is None:
        reports = report.map_runs(
            args.runs,
            args.out,
            config,
            progress=progress,
            overwrite=args.overwrite,
            sensor_preset=args.sensor_preset,
            given=given,
        )
        _warn(reports, args.quiet)
        print(report.summary_table(reports))
        print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
        return
    from vogjax.report.workers import map_runs_parallel

    workers = len(args.runs) if args.workers is None else args.workers
    outcomes = map_runs_parallel(
        args.runs,
        args.out,
        config,
        workers,
        args.address,
        progress=progress,
        overwrite=args.overwrite,
        sensor_preset=args.sensor_preset,
        given=given,
    )
    reports = [o.report for o in outcomes if o.report is not None]
    _warn(reports, args.quiet)
    if reports:
        print(report.summary_table(reports))
        print(f"wrote {', '.join(str(args.out / Path(r['run']).stem) for r in reports)}")
    failed = [o for o in outcomes if o.error is not None]
    for outcome in failed:
        print(f"vogjax map: error: {outcome.path}: {outcome.error}", file=sys.stderr)
    if failed:
        raise SystemExit(2)


def _warn(reports: list[dict], quiet: bool) -> None:
    """On stderr, per run: the share of returns past the map's reach, scan registrations that
    failed (more than a tenth), and (unless quiet) a hint when most closure candidates failed
    one gate."""
    from vogjax.report.summary import closure_hint

    for r in reports:
        name = Path(r["run"]).stem
        returns = r.get("returns", {})
        if returns.get("beyond_reach"):
            print(
                f"vogjax map: warning: {name}: {returns['beyond_reach_share']:.1%} of the returns reach past the map's "
                f"range ({returns['reach_m']:g} m): they cleared free space up to it and marked nothing "
                "([map] max_range)",
                file=sys.stderr,
            )
        matching = r.get("scan_matching", {})
        due = matching.get("registered", 0) + matching.get("failed", 0)
        if matching.get("failed", 0) > 0.1 * due:
            print(
                f"vogjax map: warning: {name}: {matching['failed']} of {due} scans due for scan matching were not "
                "registered (no local map, too few returns, no convergence or too large a move): they kept the "
                "odometry's motion ([scan_matching])",
                file=sys.stderr,
            )
        hint = None if quiet else closure_hint(r)
        if hint:
            print(f"vogjax map: hint: {name}: {hint}", file=sys.stderr)
