"""`vogjax import MAP.bt|MAP.ot --out MAP.vog` and `vogjax import BAG --octomap TOPIC --out
MAP.vog`: an OctoMap tree as a vogjax map file (a VoxelMap), the route `vogjax.commands.importing`
takes for them."""

from __future__ import annotations

import decimal

SUFFIXES = (".bt", ".ot")


def seconds(text: str) -> decimal.Decimal:
    """--time's value: the digits as typed, as a Decimal (a stamp's nine decimals do not fit a
    float's 16 digits next to 1.7e9 s)."""
    try:
        value = decimal.Decimal(text.strip())
    except decimal.InvalidOperation:
        raise ValueError(text) from None
    if not value.is_finite():
        raise ValueError(text)
    return value


def add_arguments(parser) -> None:
    """Declare the flags of a map import on `vogjax import`'s parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The parser of `vogjax import`.
    """
    parser.add_argument(
        "--octomap",
        default=None,
        metavar="TOPIC",
        help="topic of octomap_msgs/Octomap (binary or full): write one map (the last message, or --index, "
        "--time) to --out as a .vog map file instead of importing scans (default: import scans)",
    )
    parser.add_argument(
        "--index",
        type=int,
        default=None,
        metavar="N",
        help="with --octomap: the message to take, 0 first, -1 last (default: the last)",
    )
    parser.add_argument(
        "--time",
        type=seconds,
        default=None,
        metavar="SECONDS",
        help="with --octomap: the last message stamped at or before this time, header stamps in seconds "
        "(default: the last message)",
    )


def wanted(args) -> bool:
    """Whether the command imports a map: an OctoMap file, or --octomap (or its --index, --time)."""
    return args.bag.suffix.lower() in SUFFIXES or args.octomap is not None or (args.index, args.time) != (None, None)


def run(args) -> None:
    import numpy as np

    import vogjax as vj
    from vogjax.commands.common import refuse_replacing_input
    from vogjax.io.atomic import check_writable

    from_file = args.bag.suffix.lower() in SUFFIXES
    if from_file and args.octomap is not None:
        raise ValueError(f"--octomap reads a bag; {str(args.bag)!r} is an OctoMap file")
    if not from_file and args.octomap is None:
        raise ValueError("--index and --time pick an --octomap message: pass --octomap TOPIC")
    scans = [
        flag
        for flag, given in (
            ("--points", args.points is not None),
            ("--depth", args.depth is not None),
            ("--odometry", args.odometry is not None),
            ("--frame", args.frame is not None),
            ("--max-range", args.max_range is not None),
            ("--camera-info", args.camera_info is not None),
            ("--stride", args.stride != 1),
            ("--no-deskew", args.no_deskew),
            ("--min-intensity", args.min_intensity is not None),
        )
        if given
    ]
    if scans:
        raise ValueError(f"{scans[0]} belongs to importing scans; a map is imported from an OctoMap tree alone")
    if from_file and (args.index, args.time) != (None, None):
        raise ValueError("--index and --time pick a message of a bag; an OctoMap file holds one tree")
    if args.out.suffix != ".vog":  # a map file under a run's .h5 name is one `vogjax map` cannot read
        raise ValueError(f"--out must name a .vog map file (an OctoMap imports as a map), got {str(args.out)!r}")
    refuse_replacing_input(args.out, args.bag, "file being imported")
    if args.out.exists() and not args.overwrite:
        raise ValueError(f"out {str(args.out)!r} exists (pass --overwrite to replace it)")
    check_writable(args.out)
    if from_file:
        source = f"OctoMap file {args.bag}"
        vmap = vj.VoxelMap.from_octomap(args.bag, device="cpu")
    else:
        from vogjax.io.octomap_bag import format_stamp, read_octomap_message

        message = read_octomap_message(args.bag, args.octomap, index=args.index, time_s=args.time)
        stamp = format_stamp(message.stamp_ns)
        source = f"message {message.index} of {message.count} on {args.octomap} (stamp {stamp} s)"
        where = f"bag {str(args.bag)!r} topic {args.octomap!r} message {message.index}"
        vmap = vj.VoxelMap.from_octree(message.tree, device="cpu", where=where)
    vmap.save(args.out)
    _, values = vmap.voxels()
    cfg = vmap.config
    occupied = int(np.count_nonzero(values >= cfg.log_occupied))
    free = int(np.count_nonzero(values <= cfg.log_free))
    print(
        f"wrote {args.out}: VoxelMap of {len(values)} voxels ({occupied} occupied, {free} free) from {source}; "
        f"voxel size {cfg.voxel_size:g} m (the tree's resolution), other settings MapConfig's defaults "
        f"(thresholds {cfg.occupied_threshold:g}/{cfg.free_threshold:g}, clamping {cfg.clamp_min:g}/{cfg.clamp_max:g}, "
        f"max range {cfg.max_range:g} m)"
    )
