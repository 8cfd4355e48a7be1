"""`vogjax explore`: next-best-view exploration of a built-in scene, mapped online with loop
closures; writes the run (HDF5) and RUN.explore.csv (one row per planning iteration)."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands.simulation import scene_help


def add_parser(commands) -> None:
    explore = commands.add_parser("explore", help="explore a built-in scene with the next-best-view planner")
    explore.add_argument("--scene", required=True, help=scene_help())
    explore.add_argument(
        "--submaps",
        type=int,
        required=True,
        help="stop once this many submaps are finished, checked before each plan: the initial "
        "turn in place and each flown edge run in full first, and the submap being filled "
        "at the stop is finished too, so a run can end with more",
    )
    explore.add_argument("--out", type=Path, required=True, help="run file to write (HDF5); RUN.explore.csv beside it")
    explore.add_argument(
        "--map",
        default="global",
        choices=("global", "virtual", "standard"),
        help="the map the planner plans on: the online global map (default), the virtual "
        "map, or the navigation-only standard map (the papers' baseline)",
    )
    explore.add_argument("--seed", type=int, default=0, help="seed of the planner, navigation and range noise")
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
        "[loop_closure] (with [loop_closure.icp], [loop_closure.correlative]), [timing], "
        "[pipeline]; not [report]",
    )
    explore.add_argument("--overwrite", action="store_true", help="replace --out (and its CSV) if it exists")
    explore.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> None:
    from vogjax.sim.explore import explore, load_settings

    if args.seed < 0:
        raise ValueError(f"--seed must be non-negative, got {args.seed}")
    planner_config, pipeline_config = load_settings(args.config, args.scene, args.seed, args.rule)
    summary = explore(
        args.scene,
        args.out,
        args.submaps,
        map_kind=args.map,
        seed=args.seed,
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
