"""`vogjax explore`: next-best-view exploration of a built-in scene, mapped online with loop
closures; writes the run (HDF5) and RUN.explore.csv (one row per planning iteration)."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands.common import add_output_flags, refuse_existing, ruled
from vogjax.commands.simulation import scene_help, scene_names

DESCRIPTION = """\
Explore a built-in scene with the next-best-view planner (Ho et al.): the simulated vehicle
plans a path on the map it builds as it goes (the online global map with loop closures by
default), flies the best branch's first edge, scans, and plans again, until --submaps
submaps are finished or nothing is left to see. The run is written like `vogjax simulate`'s
(HDF5, with ground truth, for `vogjax map`), and RUN.explore.csv beside it holds one row per
planning iteration (gain, path, volume explored, timings)."""

EPILOG = """\
examples:
  vogjax explore --scene boxes --submaps 4 --out explored.h5
  vogjax explore --scene tank --submaps 30 --map standard --seed 3 --config settings.toml --out tank.h5"""


def add_parser(commands) -> None:
    """Declare `vogjax explore` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    explore = commands.add_parser(
        "explore",
        help="explore a built-in scene with the next-best-view planner",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    explore.add_argument("--scene", required=True, choices=scene_names(ground=False), help=scene_help(ground=False))
    explore.add_argument(
        "--submaps",
        type=ruled("integer", 1),
        metavar="N",
        required=True,
        help="stop once this many submaps are finished, checked before each plan: the initial "
        "turn in place and each flown edge run in full first, and the submap being filled "
        "at the stop is finished too, so a run can end with more",
    )
    explore.add_argument(
        "--out", type=Path, required=True, metavar="RUN.h5", help="run file to write (HDF5); RUN.explore.csv beside it"
    )
    explore.add_argument(
        "--map",
        default="global",
        choices=("global", "virtual", "standard"),
        help="the map the planner plans on: the online global map, the virtual "
        "map, or the navigation-only standard map (the papers' baseline)",
    )
    explore.add_argument(
        "--seed",
        type=ruled("integer", 0, 2**63 - 1),
        default=None,
        metavar="N",
        help="seed of the planner, navigation and range noise (default: [planner] seed of --config, else 0)",
    )
    explore.add_argument(
        "--rule",
        default="time",
        choices=("time", "papers"),
        help="how the planner chooses: time-aware (gain per second of flight, yaw along the path; "
        "default) or the papers' rule (discounted gain, with their settings for the scene)",
    )
    explore.add_argument(
        "--config",
        type=Path,
        default=None,
        help="TOML settings: [planner] (PlannerConfig, over the --rule's settings for the "
        "scene) and the pipeline's tables of `vogjax map`: [map], [nav_noise], "
        "[loop_closure] (with [loop_closure.icp], [loop_closure.correlative]), [pose_graph], [timing], "
        "[pipeline]; not [report] (`vogjax config --defaults --for explore` prints them all)",
    )
    explore.add_argument("--overwrite", action="store_true", help="replace --out (and its CSV) if it exists")
    add_output_flags(explore)


def run(args) -> None:
    """Explore and print what was written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax explore`.
    """
    from vogjax.sim.explore import csv_path_of, explore, load_settings

    if not args.out.name:  # '' or '/': no file to write, and no CSV name beside it
        raise ValueError(f"--out must name a run file (RUN.h5), got {str(args.out)!r}")
    for path in (args.out, csv_path_of(args.out)):
        refuse_existing(path, args.overwrite, "--out" if path == args.out else "--out's CSV")
    planner_config, pipeline_config = load_settings(args.config, args.scene, args.seed, args.rule)
    if args.map == "standard" and not pipeline_config.standard_map:
        raise ValueError(
            "--map standard plans on the standard map: --config must not set [pipeline] standard_map = false"
        )
    summary = explore(
        args.scene,
        args.out,
        args.submaps,
        map_kind=args.map,
        seed=planner_config.seed,
        planner_config=planner_config,
        pipeline_config=pipeline_config,
        progress=not args.quiet,
        overwrite=args.overwrite,
    )
    print(
        f"wrote {summary.path} and {summary.csv_path}: {summary.scans} scans, {summary.submaps} submaps, "
        f"{summary.iterations} plans, {summary.path_m:.1f} m flown in {summary.duration_s:.0f} s, "
        f"{summary.explored_m3:.1f} m^3 explored (stopped: {summary.stopped})"
    )
