"""octomap_msgs/Octomap messages in ROS bags (ROS 1, ROS 2, MCAP), read with the bag reader of
`vogjax.io.rosbag` and decoded as OctoMap files are (`vogjax.io.octomap_read`).

    message = read_octomap_message("run.bag", "/octomap_full")          # the last one
    message = read_octomap_message("run.bag", "/octomap_binary", index=0)
    message = read_octomap_message("run.bag", "/octomap_full", time_s=1.7e9)
    vmap = vj.VoxelMap.from_octree(message.tree)

A message carries `binary` (occupied/free only, `writeBinaryData`; what octomap_server
publishes on /octomap_binary) or a full tree (`writeData`, float log-odds; /octomap_full), its
tree type `id`, `resolution` and the serialised nodes in `data` (no header, so no node count to
check: the data must hold one whole tree and nothing after it). The message type is registered
from its definition, so bags without embedded definitions read too.
"""

from __future__ import annotations

import dataclasses
import decimal
from pathlib import Path

import numpy as np

from vogjax.io.octomap_read import OctreeLeaves, decode

OCTOMAP = "octomap_msgs/msg/Octomap"
OCTOMAP_DEFINITION = """std_msgs/Header header
bool binary
string id
float64 resolution
int8[] data
"""


@dataclasses.dataclass(frozen=True)
class OctomapMessage:
    """One decoded octomap_msgs/Octomap message: the tree, which message of the topic it was
    (`index` of `count`, 0 first), its header stamp (ns) and frame."""

    tree: OctreeLeaves
    index: int
    count: int
    stamp_ns: int
    frame: str


def typestore():
    """The message types bags are read with.

    Returns
    -------
    rosbags.typesys.store.Typestore
        The latest ROS 2 types, with octomap_msgs/msg/Octomap registered from its definition.
    """
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.LATEST)
    store.register(get_types_from_msg(OCTOMAP_DEFINITION, OCTOMAP))
    return store


def read_octomap_message(bag, topic: str, index: int | None = None, time_s: float | None = None) -> OctomapMessage:
    """The octomap_msgs/Octomap message of `topic` in `bag`, decoded and checked.

    Parameters
    ----------
    bag : str or os.PathLike
        A ROS 1 .bag, a ROS 2 bag folder, or an .mcap/.db3 file.
    topic : str
        The topic of octomap_msgs/Octomap messages.
    index : int or None
        Which message: 0 the first, -1 the last (Python's indexing). None: the last, or the
        one `time_s` picks.
    time_s : float, int, decimal.Decimal or None
        Pick the last message whose header stamp is at or before this time (seconds, the
        stamps' clock), compared in whole nanoseconds: a float as the decimal it prints as
        (1700000000.1 is 1700000000100000000 ns), a Decimal exactly. Not with `index`.

    Returns
    -------
    OctomapMessage

    Raises
    ------
    ValueError
        One line naming the bag, the topic or the argument: an unreadable bag, a missing topic
        or one of another type, no message to pick, or a malformed tree.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError

    from vogjax.io.rosbag import _Damaged

    bag = Path(bag)
    if index is not None and time_s is not None:
        raise ValueError("index and time_s pick a message each: give one of them")
    if index is not None and (isinstance(index, bool) or not isinstance(index, (int, np.integer))):
        raise ValueError(f"index must be an integer, got {index!r}")
    time_ns = None if time_s is None else nanoseconds("time_s", time_s)
    if not bag.exists():
        raise ValueError(f"bag {str(bag)!r} does not exist")
    try:
        with AnyReader([bag], default_typestore=typestore()) as reader:
            return _read(reader, bag, topic, index, time_ns)
    except (
        AnyReaderError,
        FileNotFoundError,
        NotADirectoryError,
        IsADirectoryError,
        PermissionError,
        UnicodeError,
    ) as error:
        raise ValueError(f"bag {str(bag)!r} cannot be read as a ROS 1, ROS 2 or MCAP bag: {error}") from None
    except _Damaged as damage:
        raise ValueError(f"bag {str(bag)!r} is damaged: {damage}") from None


def nanoseconds(name: str, time_s) -> int:
    """A time in seconds as whole nanoseconds, rounded down (a stamp is at or before it exactly
    when it is at or before this). A float is taken as the shortest decimal that reads back as
    it (`repr`): the float product `time_s * 1e9` would put 1700000000.1 s at ...100000143 ns,
    after a message stamped at 1700000000.1 s.

    Raises
    ------
    ValueError
        Naming `name`: not a real number (a bool is not one), or not finite.
    """
    if isinstance(time_s, (float, np.floating)):
        exact = decimal.Decimal(repr(float(time_s)))
    elif isinstance(time_s, (int, np.integer)) and not isinstance(time_s, (bool, np.bool_)):
        exact = decimal.Decimal(int(time_s))
    elif isinstance(time_s, decimal.Decimal):
        exact = time_s
    else:
        raise ValueError(f"{name} must be a number of seconds, got {time_s!r}")
    if not exact.is_finite():
        raise ValueError(f"{name} must be a finite number of seconds, got {time_s!r}")
    return int((exact * 10**9).to_integral_value(rounding=decimal.ROUND_FLOOR))


def format_stamp(stamp_ns: int) -> str:
    """A stamp in nanoseconds as seconds with all nine decimals, exactly (no float rounding)."""
    sign, magnitude = ("-" if stamp_ns < 0 else ""), abs(int(stamp_ns))
    return f"{sign}{magnitude // 10**9}.{magnitude % 10**9:09d}"


def _read(reader, bag: Path, topic: str, index, time_ns) -> OctomapMessage:
    from vogjax.io.rosbag import _messages, _stamp_ns, _topic

    connections, _ = _topic(reader, topic, "--octomap", {OCTOMAP})
    stamps = [_stamp_ns(message.header) for _, message in _messages(reader, connections)]
    count = len(stamps)
    if count == 0:
        raise ValueError(f"--octomap topic {topic!r} holds no messages")
    if time_ns is not None:
        before = [k for k, stamp in enumerate(stamps) if stamp <= time_ns]
        if not before:
            raise ValueError(
                f"--time {format_stamp(time_ns)}: the {count} messages on {topic!r} are stamped from "
                f"{format_stamp(min(stamps))} s on; none at or before it"
            )
        chosen = max(before, key=lambda k: (stamps[k], k))
    elif index is not None:
        if not -count <= index < count:
            raise ValueError(
                f"--index {index}: topic {topic!r} holds {count} messages (0 to {count - 1}, or -1 the last)"
            )
        chosen = int(index) % count
    else:
        chosen = count - 1
    message = next(m for k, (_, m) in enumerate(_messages(reader, connections)) if k == chosen)
    where = f"bag {str(bag)!r} topic {topic!r} message {chosen}"
    data = np.asarray(message.data).view(np.uint8)
    tree = decode(data, bool(message.binary), str(message.id), float(message.resolution), where)
    return OctomapMessage(tree, chosen, count, stamps[chosen], str(message.header.frame_id).lstrip("/"))
