"""`vogjax import`: a ROS bag's scans and odometry as a vogjax run file (no ground truth); an
OctoMap .bt/.ot file, or an octomap_msgs/Octomap message of a bag, as a map file
(`vogjax.commands.octomap_import`)."""

from __future__ import annotations

from pathlib import Path

from vogjax.commands import octomap_import
from vogjax.commands.common import add_output_flags, refuse_existing, ruled

DESCRIPTION = """\
Convert a ROS bag into a run file for `vogjax map`: the scans of a PointCloud2 or LaserScan
topic, each paired with the vehicle's pose from a nav_msgs/Odometry topic (interpolated to the
scan's time), and the sensor's mount from /tf_static or /tf when --frame names the sensor's
frame. ROS 1 .bag files, ROS 2 bag folders and .mcap/.db3 files are read without a ROS
installation (rosbags). The run has no ground truth: `vogjax map` then skips AUC and RMSE.

An OctoMap map imports too: a .bt or .ot file given as BAG, or an octomap_msgs/Octomap topic
of a bag with --octomap, becomes a vogjax map file (.vog)."""

EPILOG = """\
examples:
  vogjax import survey.bag --points /velodyne_points --odometry /odom --frame velodyne --out survey.h5
  vogjax import rosbag2_folder --points /scan --odometry /odometry/filtered --out run.h5 --max-range 30
  vogjax import map.bt --out map.vog
  vogjax import mapping.bag --octomap /octomap_full --out map.vog"""


def add_parser(commands) -> None:
    """Declare `vogjax import` and its arguments.

    Parameters
    ----------
    commands : argparse._SubParsersAction
        The subcommands of `vogjax`.
    """
    bag = commands.add_parser(
        "import",
        help="convert a ROS 1/ROS 2/MCAP bag into a run file for `vogjax map`",
        description=DESCRIPTION,
        epilog=EPILOG,
    )
    bag.add_argument(
        "bag", type=Path, help="a ROS 1 .bag, a ROS 2 bag folder, or an .mcap/.db3 file; or an OctoMap .bt/.ot file"
    )
    bag.add_argument("--points", help="topic of sensor_msgs/PointCloud2 or sensor_msgs/LaserScan")
    bag.add_argument("--odometry", help="topic of nav_msgs/Odometry (the vehicle's poses)")
    bag.add_argument(
        "--out", type=Path, required=True, metavar="RUN.h5", help="run file to write (HDF5; .vog for an OctoMap map)"
    )
    bag.add_argument(
        "--frame",
        default=None,
        help="the sensor frame the points are in; its mount on the odometry's child frame comes from "
        "/tf_static or /tf (default: the points are in the child frame)",
    )
    bag.add_argument(
        "--max-range",
        type=ruled("number", 0, low_open=True),
        default=None,
        help="the sensor's reach in metres (default: LaserScan's range_max, or a cloud's farthest point)",
    )
    bag.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    octomap_import.add_arguments(bag)
    add_output_flags(bag)


def run(args) -> None:
    """Import the bag and print what was written.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax import`.
    """
    if octomap_import.wanted(args):
        return octomap_import.run(args)
    if args.points is None or args.odometry is None:
        raise ValueError("--points and --odometry are required to import a bag's scans (or --octomap TOPIC: a map)")
    from vogjax.io.rosbag import MAX_RANGE_M, import_bag

    # as `vogjax simulate` does: an existing run is refused before the bag is read (import_bag
    # then checks, with io.atomic.check_writable, that --out can be published)
    refuse_existing(args.out, args.overwrite)
    if args.max_range is not None and args.max_range > MAX_RANGE_M:
        raise ValueError(f"--max-range must be at most {MAX_RANGE_M:g} m, got {args.max_range:g}")
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
