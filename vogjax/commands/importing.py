"""`vogjax import`: a ROS bag's scans (point clouds, laser scans or depth images) and odometry
as a vogjax run file (no ground truth); an OctoMap .bt/.ot file, or an octomap_msgs/Octomap
message of a bag, as a map file (`vogjax.commands.octomap_import`)."""

from __future__ import annotations

import sys
from pathlib import Path

from vogjax.commands import octomap_import
from vogjax.commands.common import add_output_flags, refuse_existing, refuse_replacing_input, ruled

DESCRIPTION = """\
Convert a ROS bag into a run file for `vogjax map`: the scans of a PointCloud2 or LaserScan
topic (--points) or of a depth camera's Image topic (--depth, with its CameraInfo), each paired
with the vehicle's pose from a nav_msgs/Odometry topic (interpolated to the scan's time), and
the sensor's mount from /tf_static or /tf when --frame names the sensor's frame. Clouds with
per-point times (fields time, t or timestamp) are deskewed: every point is placed where the
sensor was when it fired. Intensity and ring are kept in the run; every field of the scans is
reported as used or ignored. ROS 1 .bag files, ROS 2 bag folders and .mcap/.db3 files are read
without a ROS installation (rosbags). The run has no ground truth: `vogjax map` then skips AUC
and RMSE.

An OctoMap map imports too: a .bt or .ot file given as BAG, or an octomap_msgs/Octomap topic
of a bag with --octomap, becomes a vogjax map file (.vog)."""

EPILOG = """\
examples:
  vogjax import survey.bag --points /velodyne_points --odometry /odom --frame velodyne --out survey.h5
  vogjax import rosbag2_folder --points /scan --odometry /odometry/filtered --out run.h5 --max-range 30
  vogjax import rgbd.bag --depth /camera/depth/image_raw --stride 4 --odometry /odom --frame camera --out rgbd.h5
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
    scans = bag.add_argument_group("scans (one of --points and --depth)")
    topics = scans.add_mutually_exclusive_group()
    topics.add_argument(
        "--points",
        metavar="TOPIC",
        help="topic of sensor_msgs/PointCloud2 or sensor_msgs/LaserScan (no default: this or --depth)",
    )
    topics.add_argument(
        "--depth",
        metavar="TOPIC",
        help="topic of a depth camera's sensor_msgs/Image, 16UC1 in mm or 32FC1 in m (no default: this or --points)",
    )
    scans.add_argument(
        "--camera-info",
        metavar="TOPIC",
        help="the depth images' sensor_msgs/CameraInfo topic (default: camera_info beside the --depth topic)",
    )
    scans.add_argument(
        "--stride",
        type=ruled("integer", 1, 65536),
        default=1,
        metavar="N",
        help="of a depth image, every Nth pixel of every Nth row",
    )
    scans.add_argument(
        "--no-deskew",
        action="store_true",
        help="take clouds at their stamps, ignoring per-point times (default: deskew clouds that have them)",
    )
    scans.add_argument(
        "--min-intensity",
        type=ruled("number"),
        default=None,
        metavar="VALUE",
        help="drop (and count) points and laser returns of lower intensity (default: keep all)",
    )
    bag.add_argument(
        "--odometry",
        metavar="TOPIC",
        help="topic of nav_msgs/Odometry, the vehicle's poses (no default: required to import scans)",
    )
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
    if args.odometry is None:
        raise ValueError("--odometry TOPIC is required to import a bag's scans (or --octomap TOPIC: a map)")
    from vogjax.io.rosbag import MAX_RANGE_M, import_bag

    # as `vogjax simulate` does: an existing run is refused before the bag is read (import_bag
    # then checks, with io.atomic.check_writable, that --out can be published)
    if args.out.suffix == ".vog":  # a run under a map's name is one `vogjax view` and `export` cannot read
        raise ValueError(f"--out must name a run file (RUN.h5): scans import as a run, got {str(args.out)!r}")
    refuse_replacing_input(args.out, args.bag, "bag being imported")
    refuse_existing(args.out, args.overwrite)
    if args.max_range is not None and args.max_range > MAX_RANGE_M:
        raise ValueError(f"--max-range must be at most {MAX_RANGE_M:g} m, got {args.max_range:g}")
    check_scan_flags(args)
    summary = import_bag(
        args.bag,
        args.out,
        args.points,
        args.odometry,
        frame=args.frame,
        max_range_m=args.max_range,
        progress=not args.quiet,
        depth_topic=args.depth,
        camera_info_topic=args.camera_info,
        stride=args.stride,
        deskew=not args.no_deskew,
        min_intensity=args.min_intensity,
    )
    if not args.quiet:
        print(fields_note(summary.metadata), file=sys.stderr)
    dropped = ", ".join(f"{n} {reason.replace('_', ' ')}" for reason, n in summary.dropped.items()) or "none"
    frames = summary.metadata["source"]["frames"]
    print(
        f"wrote {summary.path}: {summary.scans} of {summary.scans_read} scans ({summary.beams} beams each, "
        f"{summary.padded_beams} padding copies), scans dropped: {dropped}; {summary.invalid_beams} invalid beams "
        f"dropped; frames {frames['world']} <- {frames['vehicle']} <- {frames['sensor']}; "
        f"max range {summary.metadata['sensor_config']['max_range_m']:g} m; {deskew_note(summary.metadata)}"
    )


def check_scan_flags(args) -> None:
    """Refuse flag combinations the scans cannot take, naming the flag (before the bag is read).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of `vogjax import`.

    Raises
    ------
    ValueError
        When neither or both of --points and --depth are given, or a depth-camera flag comes
        without --depth, or --min-intensity with it.
    """
    if (args.points is None) == (args.depth is None):
        raise ValueError("give one of --points TOPIC (clouds, laser scans) and --depth TOPIC (a depth camera)")
    if args.depth is None:
        for flag, given in (("--camera-info", args.camera_info is not None), ("--stride", args.stride != 1)):
            if given:
                raise ValueError(f"{flag} applies to depth images: give --depth TOPIC")
    elif args.min_intensity is not None:
        raise ValueError("--min-intensity applies to --points: a depth image has no intensity")
    elif args.no_deskew:
        raise ValueError("--no-deskew applies to --points: depth images have no per-point times")


def fields_note(metadata: dict) -> str:
    """One line naming every field of the scans and what the import did with it.

    Parameters
    ----------
    metadata : dict
        An imported run's metadata (its `import.fields`).

    Returns
    -------
    str
        E.g. "fields of /points: x, y, z (float32: position), time (float32: point time), ...; ignored: ...".
    """
    fields = metadata["import"].get("fields", {})
    used, ignored = {}, []
    for name, field in fields.items():
        if field["use"].startswith("ignored"):
            ignored.append(name + field["use"][len("ignored") :])
        else:
            used.setdefault((field["type"], field["use"]), []).append(name)
    parts = [f"{', '.join(names)} ({kind}: {use})" for (kind, use), names in used.items()]
    kept = metadata["import"].get("optional_fields", [])
    return (
        f"fields of {metadata['source']['points_topic']}: {'; '.join(parts) or 'none'}"
        f"; kept in the run: {', '.join(kept) or 'none'}; ignored: {', '.join(ignored) or 'none'}"
    )


def deskew_note(metadata: dict) -> str:
    """What the summary says of the point times: the field, its layout, whether points were deskewed.

    Parameters
    ----------
    metadata : dict
        An imported run's metadata (its `import.point_time`).

    Returns
    -------
    str
    """
    time = metadata["import"]["point_time"]
    if not time["deskewed"]:
        return f"not deskewed: {time.get('reason', 'no per-point times')}"
    low, high = time["offsets_s"]
    layout = f"{time['type']}, {time['meaning']}"
    return f"deskewed by field {time['field']} ({layout}; points fired {low:+.3f} to {high:+.3f} s from the stamp)"
