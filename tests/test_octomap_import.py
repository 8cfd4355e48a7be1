"""Reading OctoMap: files written by OctoMap itself (octomap-python) and by vogjax read back
voxel for voxel; every malformed file is a one-line ValueError naming it (fuzzed with
hypothesis against a pure-Python reader written from OctoMap's format); maps from bags."""

import decimal
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax import cli
from vogjax.io import octomap as om
from vogjax.io.voxels import VoxelSet

from . import reference as ref

octomap = pytest.importorskip("octomap")


def voxel_dict(vmap):
    centres, values = vmap.voxels()
    keys = np.floor(centres / vmap.config.voxel_size).astype(np.int64)
    return dict(zip(map(tuple, keys.tolist()), values.tolist()))


def octomap_leaves(tree, voxel_size, value=lambda leaf: leaf.getValue()):
    """{voxel key: value(leaf)} of OctoMap's leaves, pruned ones expanded (octomap-python alone)."""
    cells = {}
    for leaf in tree.begin_leafs():
        n = int(round(leaf.getSize() / voxel_size))
        corner = np.floor((np.array(leaf.getCoordinate()) - leaf.getSize() / 2) / voxel_size + 0.5).astype(int)
        for offset in np.ndindex(n, n, n):
            cells[tuple((corner + offset).tolist())] = value(leaf)
    return cells


def octomap_scans(seed=0, scans=8, beams=120, voxel_size=0.1):
    cfg = vj.MapConfig(voxel_size=voxel_size)
    tree = octomap.OcTree(voxel_size)
    tree.setProbHit(cfg.prob_hit)
    tree.setProbMiss(cfg.prob_miss)
    tree.setClampingThresMin(cfg.clamp_min)
    tree.setClampingThresMax(cfg.clamp_max)
    tree.setOccupancyThres(cfg.occupied_threshold)
    origins, points, scan = ref.random_scans(np.random.default_rng(seed), scans, beams, spread=5.0, far=0.1)
    for s in range(scans):
        tree.insertPointCloud(points[scan == s].astype(np.float64), origins[s].astype(np.float64), maxrange=11.0)
    return cfg, tree, (origins, points, scan)


def test_files_octomap_writes_read_back_voxel_for_voxel(tmp_path):
    cfg, tree, _ = octomap_scans(scans=4, beams=80)
    tree.updateInnerOccupancy()
    (tmp_path / "map.ot").write_bytes(tree.write())
    expected = {k: np.float32(v) for k, v in octomap_leaves(tree, cfg.voxel_size).items()}
    ours = vj.VoxelMap.from_octomap(tmp_path / "map.ot")
    assert ours.config.voxel_size == cfg.voxel_size
    assert voxel_dict(ours) == expected and len(expected) > 10_000
    # writeBinary: max-likelihood at the occupancy threshold, pruned; leaves read as the clamping bounds
    (tmp_path / "map.bt").write_bytes(tree.writeBinary())
    binary = octomap.OcTree(str(tmp_path / "map.bt").encode())
    assert any(leaf.getSize() > 1.5 * cfg.voxel_size for leaf in binary.begin_leafs())  # pruned leaves
    occupied = octomap_leaves(binary, cfg.voxel_size, lambda leaf: binary.isNodeOccupied(leaf))
    ours = vj.VoxelMap.from_octomap(tmp_path / "map.bt")
    got = voxel_dict(ours)
    assert got.keys() == occupied.keys()
    assert got == {k: (cfg.log_clamp_max if o else cfg.log_clamp_min) for k, o in occupied.items()}
    # and OctoMap's inner nodes of the read map, at every level, as in the file's tree
    binary.updateInnerOccupancy()
    centres = np.array(list(occupied))[::7] * cfg.voxel_size + cfg.voxel_size / 2
    for level in range(7):
        theirs = []
        for c in centres:
            node = binary.search(c, depth=16 - level)
            theirs.append(cfg.log_clamp_max if binary.isNodeOccupied(node) else cfg.log_clamp_min)
        np.testing.assert_array_equal(ours.log_odds(centres, level), np.float32(theirs))


def test_vogjax_exports_re_import_equal(tmp_path):
    cfg = vj.MapConfig()
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(*ref.random_scans(np.random.default_rng(3), 10, 150, spread=4.0, far=0.1))
    om.save(vmap, tmp_path / "map.ot")
    om.save(vmap, tmp_path / "map.bt")
    full = vj.VoxelMap.from_octomap(tmp_path / "map.ot", config=cfg)
    centres, values = vmap.voxels()
    np.testing.assert_array_equal(full.voxels()[0], centres)
    np.testing.assert_array_equal(full.voxels()[1], values)
    binary = vj.VoxelMap.from_octomap(tmp_path / "map.bt", config=cfg)
    state = vmap.state(centres)
    known = state != vj.UNKNOWN
    got_centres, got_values = binary.voxels()
    np.testing.assert_array_equal(got_centres, centres[known])  # unknown ones are not in a .bt
    np.testing.assert_array_equal(binary.state(got_centres), state[known])
    assert set(got_values.tolist()) == {cfg.log_clamp_min, cfg.log_clamp_max}
    # a global map's export too, and an empty map
    gmap_voxels = VoxelSet.from_log_odds(centres[::3], values[::3], cfg.voxel_size)
    om.save(gmap_voxels, tmp_path / "set.ot")
    np.testing.assert_array_equal(vj.VoxelMap.from_octomap(tmp_path / "set.ot").voxels()[1], values[::3])
    om.save(vj.VoxelMap(cfg), tmp_path / "empty.bt")
    assert len(vj.VoxelMap.from_octomap(tmp_path / "empty.bt").voxels()[0]) == 0


def test_pruned_nodes_of_every_size_expand_to_their_voxels(tmp_path):
    """An aligned 32^3 cube of one value (a depth-11 node: 64 whole blocks), a 4^3 and a 2^3 cube
    (depths 14 and 15) and single voxels: a handful of nodes, every voxel read back."""
    s = 0.05
    cube = np.stack(np.meshgrid(*[np.arange(32)] * 3, indexing="ij"), -1).reshape(-1, 3) + [32, -64, 0]
    small = np.stack(np.meshgrid(*[np.arange(4)] * 3, indexing="ij"), -1).reshape(-1, 3) + [100, 100, 100]
    tiny = np.stack(np.meshgrid(*[np.arange(2)] * 3, indexing="ij"), -1).reshape(-1, 3) + [-6, 2, 8]
    single = np.array([[-1, -1, -1], [7, 7, 7]])
    keys = np.concatenate([cube, small, tiny, single])
    values = np.concatenate([np.full(len(cube), 1.5), np.full(len(small), -0.7), np.full(len(tiny), 0.3), [2.0, -1.0]])
    voxels = VoxelSet.from_log_odds((keys + 0.5) * s, values.astype(np.float32), s)
    nodes = om.save(voxels, tmp_path / "cubes.ot")
    assert nodes < 100
    vmap = vj.VoxelMap.from_octomap(tmp_path / "cubes.ot")
    assert voxel_dict(vmap) == dict(zip(map(tuple, keys.tolist()), np.float32(values).tolist()))
    with pytest.raises(ValueError, match=r"expands to 32842 voxels in 68 blocks .* more than max_voxels=10000"):
        vj.VoxelMap.from_octomap(tmp_path / "cubes.ot", max_voxels=10_000)


# ------------------------------------------------------------------ malformed files
def single_voxel(format: str) -> bytes:
    voxels = VoxelSet.from_log_odds(np.array([[0.05, 0.05, 0.05]]), np.float32([2.0]), 0.1)
    return om.encode_bt(voxels) if format == "bt" else om.encode_ot(voxels)


def header_and_data(blob: bytes) -> tuple[bytes, bytes]:
    cut = blob.index(b"\ndata\n") + 6
    return blob[:cut], blob[cut:]


def malformed(name: str) -> tuple[bytes, str]:
    bt_head, bt_data = header_and_data(single_voxel("bt"))
    ot_head, ot_data = header_and_data(single_voxel("ot"))
    nan = np.frombuffer(ot_data, dtype=[("v", "<f4"), ("c", "u1")]).copy()
    nan["v"][3] = np.nan
    deep = bytearray(ot_data)
    deep[-1] = 1  # the depth-16 leaf claims a child
    cases = {
        "empty": (b"", "is no OctoMap file"),
        "first line": (b"# Octomap Tree file\n" + bt_head.split(b"\n", 1)[1] + bt_data, "is no OctoMap file"),
        "no data line": (bt_head[:-5], "no 'data' line"),
        "no res": (bt_head.replace(b"res 0.1\n", b"") + bt_data, "header without res"),
        "res text": (bt_head.replace(b"res 0.1", b"res abc") + bt_data, "res 'abc' is no number"),
        "res nan": (bt_head.replace(b"res 0.1", b"res nan") + bt_data, "res 'nan' is no number"),
        # Python's float() reads "0.1_5" as 0.15; OctoMap reads 0.1 and skips "_5" as a keyword
        "res underscore": (bt_head.replace(b"res 0.1", b"res 0.1_5") + bt_data, "res '0.1_5' is no number"),
        "res negative": (bt_head.replace(b"res 0.1", b"res -0.1") + bt_data, "resolution -0.1 m"),
        "res tiny": (bt_head.replace(b"res 0.1", b"res 1e-9") + bt_data, "resolution 1e-09 m"),
        "res huge": (bt_head.replace(b"res 0.1", b"res 1e9") + bt_data, "resolution 1000000000.0 m"),
        "size": (bt_head.replace(b"size 17", b"size -3") + bt_data, "size '-3' is no node count"),
        "size twice": (bt_head.replace(b"size 17", b"size 17\nsize 17") + bt_data, "malformed OctoMap header line"),
        "size mismatch": (
            bt_head.replace(b"size 17", b"size 18") + bt_data,
            "tree of 17 nodes; its header's size says 18",
        ),
        "type": (ot_head.replace(b"id OcTree", b"id ColorOcTree") + ot_data, "holds a full .* 'ColorOcTree' tree"),
        "truncated bt": (bt_head + bt_data[:-1], "truncated"),
        "truncated ot": (ot_head + ot_data[:-5], "truncated"),
        "trailing bt": (bt_head + bt_data + b"\x00\x00", "2 bytes of data after its tree"),
        "trailing ot": (ot_head.replace(b"size 17", b"size 18") + ot_data + ot_data[-5:], "1 nodes of data after"),
        "childless": (bt_head + bt_data[:-2] + b"\x00\x00", "inner node without children"),
        "too deep bt": (bt_head + bt_data[:-2] + b"\x03\x00", "node with children at depth 16"),
        "too deep ot": (ot_head + bytes(deep), "node with children at depth 16"),
        "nan": (ot_head + nan.tobytes(), "NaN or infinite log-odds"),
        "root leaf": (ot_head.replace(b"size 17", b"size 1") + ot_data[:4] + b"\x00", "expands to 281474976710656"),
    }
    return cases[name]


MALFORMED = [
    "empty",
    "first line",
    "no data line",
    "no res",
    "res text",
    "res nan",
    "res underscore",
    "res negative",
    "res tiny",
    "res huge",
    "size",
    "size twice",
    "size mismatch",
    "type",
    "truncated bt",
    "truncated ot",
    "trailing bt",
    "trailing ot",
    "childless",
    "too deep bt",
    "too deep ot",
    "nan",
    "root leaf",
]


@pytest.mark.parametrize("name", MALFORMED)
def test_a_malformed_file_is_a_one_line_error_naming_it(tmp_path, name):
    blob, match = malformed(name)
    path = tmp_path / "bad.bt"
    path.write_bytes(blob)
    with pytest.raises(ValueError, match=match) as error:
        vj.VoxelMap.from_octomap(path)
    message = str(error.value)
    assert "\n" not in message and message.startswith(f"path {str(path)!r}")


def test_a_path_that_cannot_be_opened_is_a_one_line_error_naming_it(tmp_path):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    for path, match in (
        (tmp_path / "missing.bt", "No such file"),
        (tmp_path, "Is a directory"),
        (tmp_path / "a", "symbolic links"),
        (tmp_path / ("x" * 300 + ".bt"), "too long"),
        (str(tmp_path / "nul\0.bt"), "null byte"),
    ):
        with pytest.raises(ValueError, match=match) as error:
            vj.VoxelMap.from_octomap(path)
        assert "\n" not in str(error.value) and str(error.value).startswith("path ")


def test_the_single_voxel_files_are_well_formed():
    """The fixtures the malformed cases are cut from read as they should."""
    for format in ("bt", "ot"):
        assert header_and_data(single_voxel(format))[0].count(b"size 17") == 1


def test_config_must_fit_the_tree(tmp_path):
    (tmp_path / "map.ot").write_bytes(single_voxel("ot"))
    (tmp_path / "map.bt").write_bytes(single_voxel("bt"))
    with pytest.raises(ValueError, match="resolution 0.1 m; config.voxel_size is 0.2 m"):
        vj.VoxelMap.from_octomap(tmp_path / "map.ot", config=vj.MapConfig(voxel_size=0.2))
    with pytest.raises(ValueError, match=r"log-odds in \[2, 2\], outside config's clamping range"):
        vj.VoxelMap.from_octomap(tmp_path / "map.ot", config=vj.MapConfig(clamp_max=0.8))
    with pytest.raises(ValueError, match="config clamps nothing"):
        vj.VoxelMap.from_octomap(tmp_path / "map.bt", config=vj.MapConfig.paper())
    assert voxel_dict(vj.VoxelMap.from_octomap(tmp_path / "map.ot", config=vj.MapConfig.paper())) == {(0, 0, 0): 2.0}
    with pytest.raises(ValueError, match="cannot be read"):
        vj.VoxelMap.from_octomap(tmp_path / "missing.bt")


# ------------------------------------------------------------------ fuzz against a reference reader
class Bad(Exception):
    pass


def reference_read(blob: bytes, budget: int) -> dict:
    """{voxel key: float32 log-odds} of an OctoMap file, or Bad: OctoMap's format, read node by
    node in plain Python (recursion), with the acceptance rules vogjax states."""
    first, _, rest = blob[:65536].partition(b"\n")
    first = first.decode("latin-1").rstrip("\r")
    if first.startswith("# Octomap OcTree binary file"):
        binary = True
    elif first.startswith("# Octomap OcTree file"):
        binary = False
    else:
        raise Bad("first line")
    fields, offset = {}, len(first.encode("latin-1")) + 1
    while True:
        if b"\n" not in rest:
            raise Bad("no data line")
        line, _, rest = rest.partition(b"\n")
        offset += len(line) + 1
        tokens = line.decode("latin-1").split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0] == "data":
            break
        if tokens[0] in ("id", "size", "res"):
            if len(tokens) != 2 or tokens[0] in fields:
                raise Bad("header line")
            fields[tokens[0]] = tokens[1]
    if (
        set(fields) != {"id", "size", "res"}
        or not (fields["size"].isascii() and fields["size"].isdigit())
        or len(fields["size"]) > 18
    ):
        raise Bad("header")
    try:
        res = float(fields["res"])
    except ValueError:
        raise Bad("res") from None
    if not (math.isfinite(res) and 1e-4 <= res <= 1e3):
        raise Bad("res")
    if fields["id"] not in (("OcTree", "ColorOcTree", "OcTreeStamped") if binary else ("OcTree",)):
        raise Bad("type")
    size, data = int(fields["size"]), blob[offset:]
    cfg = vj.MapConfig(voxel_size=res, max_range=min(11.0, 4096 * res))
    leaves, state = [], {"pos": 0, "nodes": 0}
    if size == 0:
        if data:
            raise Bad("data after an empty tree")
    elif binary:

        def node(depth, x, y, z):
            pos = state["pos"]
            if pos + 2 > len(data):
                raise Bad("truncated")
            word = data[pos] | data[pos + 1] << 8
            state["pos"] = pos + 2
            state["nodes"] += 1
            if word == 0:
                raise Bad("childless")
            for i in range(8):
                bits = (word >> 2 * i) & 3
                child = (2 * x + (i & 1), 2 * y + (i >> 1 & 1), 2 * z + (i >> 2 & 1))
                if bits == 3:
                    if depth + 1 == 16:
                        raise Bad("deep")
                    node(depth + 1, *child)
                elif bits:
                    state["nodes"] += 1
                    leaves.append((depth + 1, child, cfg.log_clamp_max if bits == 2 else cfg.log_clamp_min))

        node(0, 0, 0, 0)
        if state["pos"] != len(data) or state["nodes"] != size:
            raise Bad("length")
    else:
        if len(data) < 5 * size or len(data) % 5:
            raise Bad("length")
        records = np.frombuffer(data, dtype=[("v", "<f4"), ("c", "u1")])
        if not np.all(np.isfinite(records["v"])):
            raise Bad("nan")

        def node(depth, x, y, z):
            k = state["nodes"]
            if k >= len(records):
                raise Bad("truncated")
            state["nodes"] = k + 1
            value, children = records["v"][k], int(records["c"][k])
            if children == 0:
                leaves.append((depth, (x, y, z), value))
                return
            if depth == 16:
                raise Bad("deep")
            for i in range(8):
                if children >> i & 1:
                    node(depth + 1, 2 * x + (i & 1), 2 * y + (i >> 1 & 1), 2 * z + (i >> 2 & 1))

        node(0, 0, 0, 0)
        if state["nodes"] != len(records) or state["nodes"] != size:
            raise Bad("length")
    whole, parts = 0, set()
    for depth, (x, y, z), _ in leaves:
        if depth <= 13:
            whole += 8 ** (13 - depth)
        else:
            parts.add(tuple(c << (16 - depth) >> 3 for c in (x, y, z)))
    if 512 * (whole + len(parts)) > budget:
        raise Bad("budget")
    values = [v for _, _, v in leaves]
    if not binary and values and (min(values) < cfg.log_clamp_min or max(values) > cfg.log_clamp_max):
        raise Bad("clamping")
    cells = {}
    for depth, (x, y, z), value in leaves:
        n = 1 << (16 - depth)
        for offset in np.ndindex(n, n, n):
            key = (x * n + offset[0] - 32768, y * n + offset[1] - 32768, z * n + offset[2] - 32768)
            cells[key] = float(np.float32(value))
    return cells


def fuzz_sources():
    cfg, tree, _ = octomap_scans(seed=5, scans=1, beams=4, voxel_size=0.2)
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2))
    vmap.integrate_scans(*ref.random_scans(np.random.default_rng(1), 1, 3, spread=1.0))
    voxels = VoxelSet.from_map(vmap)
    return [tree.writeBinary(), tree.write(), om.encode_bt(voxels), om.encode_ot(voxels)]


SOURCES = fuzz_sources()
BUDGET = 1 << 16


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    source=st.sampled_from(range(len(SOURCES))),
    edits=st.lists(
        st.tuples(st.sampled_from(["set", "cut", "insert", "drop"]), st.floats(0, 1), st.integers(0, 255)),
        min_size=1,
        max_size=3,
    ),
)
def test_fuzzed_files_read_as_the_reference_reads_them_or_fail_on_one_line(tmp_path, source, edits):
    blob = bytearray(SOURCES[source])
    for kind, where, byte in edits:
        i = int(where * len(blob))
        if kind == "set" and i < len(blob):
            blob[i] = byte
        elif kind == "cut":
            del blob[i:]
        elif kind == "insert":
            blob[i:i] = bytes([byte])
        elif kind == "drop" and i < len(blob):
            del blob[i]
    path = tmp_path / "fuzzed.ot"
    path.write_bytes(bytes(blob))
    try:
        expected = reference_read(bytes(blob), BUDGET)
    except Bad:
        expected = None
    try:
        got = voxel_dict(vj.VoxelMap.from_octomap(path, max_voxels=BUDGET))
    except ValueError as error:
        message = str(error)
        assert "\n" not in message and str(path) in message, message
        assert expected is None, f"vogjax refused what the reference reads: {message}"
        return
    assert expected is not None, "vogjax read what the reference refuses"
    assert got == expected


# ------------------------------------------------------------------ the command and bags
def test_import_command_writes_a_map_file(tmp_path, capsys):
    cfg, tree, _ = octomap_scans(seed=2, scans=3)
    (tmp_path / "map.bt").write_bytes(tree.writeBinary())
    out = tmp_path / "map.vog"
    assert cli.main(["import", str(tmp_path / "map.bt"), "--out", str(out)]) == 0
    line = capsys.readouterr().out
    assert line.startswith(f"wrote {out}: VoxelMap of ") and "voxel size 0.1 m (the tree's resolution)" in line
    expected = octomap_leaves(tree, cfg.voxel_size, lambda leaf: tree.isNodeOccupied(leaf))
    loaded = vj.VoxelMap.load(out)
    assert {k: v == cfg.log_clamp_max for k, v in voxel_dict(loaded).items()} == expected
    # a fresh process: stdout carries the result line alone (no Warp banner)
    done = subprocess.run(
        [sys.executable, "-m", "vogjax.cli", "import", str(tmp_path / "map.bt"), "--out", str(tmp_path / "fresh.vog")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert done.stdout.count("\n") == 1 and done.stdout.startswith("wrote ")
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["import", str(tmp_path / "map.bt"), "--out", str(out)])
    assert exit_info.value.code == 2
    assert "exists (pass --overwrite" in capsys.readouterr().err
    (tmp_path / "bad.ot").write_bytes(b"# Octomap OcTree file\nid OcTree\nsize 3\nres 0.1\ndata\n\x00")
    with pytest.raises(SystemExit):
        cli.main(["import", str(tmp_path / "bad.ot"), "--out", str(tmp_path / "bad.vog")])
    err = capsys.readouterr().err.strip()
    assert err.startswith("vogjax import: error: path ") and "truncated" in err and "\n" not in err
    assert not (tmp_path / "bad.vog").exists()
    with pytest.raises(SystemExit):
        cli.main(["import", str(tmp_path / "map.bt"), "--out", str(tmp_path / "x.vog"), "--points", "/p"])
    assert "--points belongs to importing scans" in capsys.readouterr().err


rosbags = pytest.importorskip("rosbags")


def octomap_bag(path, kind, trees):
    """A bag of octomap_msgs/Octomap messages: trees [(stamp_ns, binary, OcTree)]."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    definition = "std_msgs/Header header\nbool binary\nstring id\nfloat64 resolution\nint8[] data\n"
    store.register(get_types_from_msg(definition, "octomap_msgs/msg/Octomap"))
    t = store.types
    writer = Writer1(path) if kind == "ros1" else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    with writer:
        connection = writer.add_connection("/octomap", "octomap_msgs/msg/Octomap", typestore=store)
        for stamp, binary, tree in trees:
            blob = tree.writeBinary() if binary else tree.write()
            data = np.frombuffer(blob[blob.index(b"\ndata\n") + 6 :], dtype=np.int8)
            stamp_msg = t["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
            extra = {"seq": 0} if kind == "ros1" else {}
            header = t["std_msgs/msg/Header"](**extra, stamp=stamp_msg, frame_id="map")
            message = t["octomap_msgs/msg/Octomap"](
                header=header, binary=binary, id="OcTree", resolution=tree.getResolution(), data=data
            )
            raw = (
                store.serialize_ros1(message, connection.msgtype)
                if kind == "ros1"
                else store.serialize_cdr(message, connection.msgtype)
            )
            writer.write(connection, stamp, raw)
    return path


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_maps_in_a_bag_import_the_last_or_the_chosen_one(tmp_path, capsys, kind):
    t0 = 1_700_000_000_000_000_000
    trees = []
    for k in range(3):
        cfg, tree, _ = octomap_scans(seed=10 + k, scans=1 + k, beams=60)
        trees.append((t0 + k * 500_000_000, k == 1, tree))  # message 1 binary, the others full
    bag = octomap_bag(tmp_path / ("maps.bag" if kind == "ros1" else "maps"), kind, trees)
    full = [octomap_leaves(tree, 0.1) for _, _, tree in trees]
    for argv, chosen in (([], 2), (["--index", "0"], 0), (["--index", "-2"], 1), (["--time", "1700000000.7"], 1)):
        out = tmp_path / f"map{chosen}.vog"
        assert cli.main(["import", str(bag), "--octomap", "/octomap", "--out", str(out), "--overwrite", *argv]) == 0
        assert f"message {chosen} of 3 on /octomap" in capsys.readouterr().out
        got = voxel_dict(vj.VoxelMap.load(out))
        if chosen == 1:
            tree = trees[1][2]
            occupied = octomap_leaves(tree, 0.1, lambda leaf: tree.isNodeOccupied(leaf))
            assert {k: v == cfg.log_clamp_max for k, v in got.items()} == occupied
        else:
            assert got == {k: float(np.float32(v)) for k, v in full[chosen].items()}
    for argv, match in (
        (["--index", "3"], "--index 3: topic '/octomap' holds 3 messages"),
        (["--time", "1600000000"], "none at or before it"),
    ):
        with pytest.raises(SystemExit):
            cli.main(["import", str(bag), "--octomap", "/octomap", "--out", str(tmp_path / "x.vog"), *argv])
        assert match in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["import", str(bag), "--octomap", "/nothing", "--out", str(tmp_path / "x.vog")])
    assert "--octomap: the bag has no topic '/nothing'" in capsys.readouterr().err


def test_a_time_picks_the_message_stamped_at_it_to_the_nanosecond(tmp_path, capsys):
    """--time compares whole nanoseconds: a message stamped exactly at the time given is picked
    (the float product stamp * 1e-9 puts 1700000000.1 s above 1700000000.1), one stamped a
    nanosecond later is not, and stamps print with their nine decimals exactly."""
    from vogjax.io.octomap_bag import read_octomap_message

    t0 = 1_700_000_000_000_000_000
    _, tree, _ = octomap_scans(seed=3, scans=1, beams=30)
    stamps = [t0, t0 + 100_000_000, t0 + 200_000_000, t0 + 300_000_001]
    bag = octomap_bag(tmp_path / "maps.bag", "ros1", [(stamp, False, tree) for stamp in stamps])
    for time_s, chosen in ((1700000000.1, 1), (1700000000.2, 2), (1700000000.3, 2), (1700000000, 0), (2e9, 3)):
        assert read_octomap_message(bag, "/octomap", time_s=time_s).index == chosen
    for text, chosen in (("1700000000.300000001", 3), ("1700000000.300000000", 2), ("1700000000.0999999999", 0)):
        out = tmp_path / "m.vog"
        assert (
            cli.main(["import", str(bag), "--octomap", "/octomap", "--out", str(out), "--overwrite", "--time", text])
            == 0
        )
        stamp = stamps[chosen]
        assert (
            f"message {chosen} of 4 on /octomap (stamp {stamp // 10**9}.{stamp % 10**9:09d} s)"
            in capsys.readouterr().out
        )
    with pytest.raises(ValueError, match=r"--time 1699999999\.999999999: .* stamped from 1700000000\.000000000 s on"):
        read_octomap_message(bag, "/octomap", time_s=decimal.Decimal("1699999999.999999999"))
    for bad in ("1700000000", True, [1.0], float("nan")):
        with pytest.raises(ValueError, match="time_s must be a"):
            read_octomap_message(bag, "/octomap", time_s=bad)
    for text in ("soon", "nan", "inf"):
        with pytest.raises(SystemExit):
            cli.main(["import", str(bag), "--octomap", "/octomap", "--out", str(tmp_path / "x.vog"), "--time", text])
        assert "--time" in capsys.readouterr().err
