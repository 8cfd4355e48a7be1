"""`vogjax import`: a ROS bag's scans and odometry as a vogjax run file (no ground truth); an
OctoMap .bt/.ot file, or an octomap_msgs/Octomap message of a bag, as a map file
(`vogjax.commands.octomap_import`)."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands import octomap_import


def add_parser(commands) -> None:
    bag = commands.add_parser("import", help="convert a ROS 1/ROS 2/MCAP bag into a run file for `vogjax map`")
    bag.add_argument(
        "bag", type=Path, help="a ROS 1 .bag, a ROS 2 bag folder, or an .mcap/.db3 file; or an OctoMap .bt/.ot file"
    )
    bag.add_argument("--points", help="topic of sensor_msgs/PointCloud2 or sensor_msgs/LaserScan")
    bag.add_argument("--odometry", help="topic of nav_msgs/Odometry (the vehicle's poses)")
    bag.add_argument("--out", type=Path, required=True, help="run file to write (HDF5)")
    bag.add_argument(
        "--frame",
        default=None,
        help="the sensor frame the points are in; its mount on the odometry's child frame comes from "
        "/tf_static or /tf (default: the points are in the child frame)",
    )
    bag.add_argument(
        "--max-range",
        type=float,
        default=None,
        help="the sensor's reach in metres (default: LaserScan's range_max, or a cloud's farthest point)",
    )
    bag.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    octomap_import.add_arguments(bag)
    bag.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> None:
    if octomap_import.wanted(args):
        return octomap_import.run(args)
    if args.points is None or args.odometry is None:
        raise ValueError("--points and --odometry are required to import a bag's scans (or --octomap TOPIC: a map)")
    from vogjax.io.rosbag import import_bag

    # as `vogjax simulate` does: an existing run is refused before the bag is read (import_bag
    # then checks, with io.atomic.check_writable, that --out can be published)
    if args.out.exists() and not args.overwrite:
        raise ValueError(f"out {str(args.out)!r} exists (pass --overwrite to replace it)")
    summary = import_bag(
        args.bag,
        args.out,
        args.points,
        args.odometry,
        frame=args.frame,
        max_range_m=args.max_range,
        progress=not args.quiet,
    )
    dropped = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in summary.dropped.items()) or "none"
    frames = summary.metadata["source"]["frames"]
    print(
        f"wrote {summary.path}: {summary.scans} of {summary.scans_read} scans ({summary.beams} beams each, "
        f"{summary.padded_beams} padding copies), scans dropped: {dropped}; {summary.invalid_beams} invalid beams "
        f"dropped; frames {frames['world']} <- {frames['vehicle']} <- {frames['sensor']}; "
        f"max range {summary.metadata['sensor_config']['max_range_m']:g} m"
    )
