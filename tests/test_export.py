"""Exports: OctoMap .bt/.ot read back by OctoMap itself (octomap-python), PLY read by trimesh,
TUM trajectories read back with SciPy's quaternions."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import vogjax as vj
from vogjax import cli
from vogjax.io import octomap as om
from vogjax.io import ply
from vogjax.io.tum import load_tum, save_tum
from vogjax.io.voxels import VoxelSet, load_map

from . import reference as ref
from .submap_helpers import random_vog

octomap = pytest.importorskip("octomap")


@pytest.fixture(scope="module")
def voxel_map():
    cfg = vj.MapConfig()
    m = vj.VoxelMap(cfg)
    m.integrate_scans(*ref.random_scans(np.random.default_rng(2), 10, 200, spread=4.0, far=0.1))
    return m


def octomap_tree(voxels: VoxelSet, cfg: vj.MapConfig, only_known: bool):
    """OctoMap's own tree of the same voxels and values (pruned as OctoMap prunes)."""
    tree = octomap.OcTree(voxels.voxel_size)
    tree.setClampingThresMin(cfg.clamp_min)
    tree.setClampingThresMax(cfg.clamp_max)
    tree.setOccupancyThres(cfg.occupied_threshold)
    keep = voxels.state() != vj.UNKNOWN if only_known else np.ones(len(voxels), bool)
    for centre, value in zip(voxels.centres[keep], voxels.log_odds[keep]):
        tree.updateNode(centre, float(value), False)
    return tree


def covered_voxels(tree, voxel_size):
    """Voxel count OctoMap's leaves cover (a pruned leaf stands for several)."""
    return sum(round(leaf.getSize() / voxel_size) ** 3 for leaf in tree.begin_leafs())


def data(blob: bytes) -> bytes:
    return blob[blob.index(b"\ndata\n") + 6 :]


def test_bt_is_read_by_octomap_with_every_observed_voxels_state(voxel_map, tmp_path):
    voxels = VoxelSet.from_map(voxel_map)
    state = voxel_map.state(voxels.centres)
    assert {vj.UNKNOWN, vj.FREE, vj.OCCUPIED} <= set(state.tolist())  # every case occurs
    nodes = om.save(voxel_map, tmp_path / "map.bt")
    tree = octomap.OcTree(str(tmp_path / "map.bt").encode())
    assert tree.size() == nodes and tree.getResolution() == voxel_map.config.voxel_size
    for centre, expected in zip(voxels.centres, state):
        node = tree.search(centre)
        if expected == vj.UNKNOWN:  # between the thresholds: left out, unknown to OctoMap too
            with pytest.raises(octomap.NullPointerException):
                node.getValue()
        else:
            assert tree.isNodeOccupied(node) == (expected == vj.OCCUPIED)
    # nothing else in the tree, and pruning happened (leaves larger than a voxel)
    assert covered_voxels(tree, voxels.voxel_size) == np.count_nonzero(state != vj.UNKNOWN)
    assert max(leaf.getSize() for leaf in tree.begin_leafs()) > 1.5 * voxels.voxel_size


def test_ot_is_read_by_octomap_with_every_voxels_log_odds(voxel_map, tmp_path):
    voxels = VoxelSet.from_map(voxel_map)
    om.save(voxel_map, tmp_path / "map.ot")
    tree = octomap.OcTree.read(str(tmp_path / "map.ot").encode())
    assert tree.getResolution() == voxel_map.config.voxel_size
    read = np.array([tree.search(c).getLogOdds() for c in voxels.centres], dtype=np.float32)
    np.testing.assert_array_equal(read, voxels.log_odds)
    assert covered_voxels(tree, voxels.voxel_size) == len(voxels)


def test_files_equal_octomaps_own_writers_byte_for_byte(voxel_map):
    """Node order, child bits, pruning and inner values exactly as OctoMap writes them."""
    voxels = VoxelSet.from_map(voxel_map)
    cfg = voxel_map.config
    assert data(om.encode_ot(voxels)) == data(octomap_tree(voxels, cfg, only_known=False).write())
    # writeBinary: max-likelihood at the occupancy threshold, then pruned
    assert data(om.encode_bt(voxels)) == data(octomap_tree(voxels, cfg, only_known=True).writeBinary())


def test_global_map_exports_through_the_cli(tmp_path, capsys):
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    gmap = vj.GlobalMap(cfg)
    gmap.merge(random_vog(np.random.default_rng(5), 3, cfg))
    gmap.save(tmp_path / "global.vog")
    centres, values = gmap.voxels()
    state = gmap.state(centres)
    for format in ("bt", "ot", "ply"):
        out = tmp_path / f"map.{format}"
        assert cli.main(["export", str(tmp_path / "global.vog"), "--format", format, "--out", str(out)]) == 0
        assert str(out) in capsys.readouterr().out
    tree = octomap.OcTree(str(tmp_path / "map.bt").encode())
    known = state != vj.UNKNOWN
    occupied = [tree.isNodeOccupied(tree.search(c)) for c in centres[known]]
    np.testing.assert_array_equal(occupied, state[known] == vj.OCCUPIED)
    full = octomap.OcTree.read(str(tmp_path / "map.ot").encode())
    np.testing.assert_array_equal([full.search(c).getLogOdds() for c in centres], values)
    assert isinstance(load_map(tmp_path / "global.vog"), vj.GlobalMap)


def test_probabilities_export_as_their_log_odds(tmp_path):
    """What a map of occupancy probabilities (a confidence-rich map's mean) goes through."""
    rng = np.random.default_rng(1)
    keys = rng.choice(40**3, 500, replace=False)
    centres = (np.stack(np.unravel_index(keys, (40, 40, 40)), axis=1) - 20 + 0.5) * 0.05
    p = rng.uniform(0.01, 0.99, len(centres))
    voxels = VoxelSet.from_probabilities(centres, p, 0.05, occupied_threshold=0.6, free_threshold=0.4)
    om.save(voxels, tmp_path / "p.ot")
    tree = octomap.OcTree.read(str(tmp_path / "p.ot").encode())
    read = np.array([tree.search(c).getOccupancy() for c in centres])
    np.testing.assert_allclose(read, p, rtol=1e-6)


def test_keys_reach_the_edges_of_octomaps_range_and_no_further(tmp_path):
    s = 0.25
    edge = np.array([[-32768 + 0.5, 0.5, 0.5], [32767.5, -32767.5, 32767.5]]) * s
    voxels = VoxelSet.from_log_odds(edge, np.float32([2.0, -2.0]), s)
    om.save(voxels, tmp_path / "edge.bt")
    tree = octomap.OcTree(str(tmp_path / "edge.bt").encode())
    assert [tree.isNodeOccupied(tree.search(c)) for c in edge] == [True, False]
    assert [[k[i] for i in range(3)] for k in map(tree.coordToKey, edge)] == [[0, 32768, 32768], [65535, 0, 65535]]
    for beyond in ([32768.5, 0.5, 0.5], [0.5, -32768.5, 0.5]):
        outside = VoxelSet.from_log_odds(np.array([beyond]) * s, np.float32([2.0]), s)
        with pytest.raises(ValueError, match=r"OctoMap's 16-bit keys hold coordinates in \[-8192, 8192\)"):
            om.save(outside, tmp_path / "far.bt")
    assert not (tmp_path / "far.bt").exists()


def test_an_empty_map_is_an_empty_tree(tmp_path):
    om.save(vj.VoxelMap(), tmp_path / "empty.bt")
    assert octomap.OcTree(str(tmp_path / "empty.bt").encode()).size() == 0


def test_bad_input_is_a_clear_error(voxel_map, tmp_path, capsys):
    with pytest.raises(ValueError, match="format must be one of bt, ot"):
        om.save(voxel_map, tmp_path / "map.xyz")
    with pytest.raises(ValueError, match="not centres of voxels"):
        VoxelSet.from_log_odds(np.array([[0.0, 0.0, 0.0]]), np.float32([1.0]), 0.1)
    with pytest.raises(ValueError, match="each voxel once"):
        VoxelSet.from_log_odds(np.array([[0.05, 0.05, 0.05]] * 2), np.float32([1.0, 1.0]), 0.1)
    with pytest.raises(ValueError, match="probabilities must lie strictly between 0 and 1"):
        VoxelSet.from_probabilities(np.array([[0.05, 0.05, 0.05]]), [1.0], 0.1)
    (tmp_path / "junk.vog").write_bytes(b"not a map")
    for argv in (
        ["export", str(tmp_path / "junk.vog"), "--out", str(tmp_path / "x.bt")],
        ["export", str(tmp_path / "missing.vog"), "--out", str(tmp_path / "x.bt")],
        ["export", str(tmp_path / "junk.vog"), "--out", str(tmp_path / "x.txt")],
    ):
        with pytest.raises(SystemExit) as exit_info:
            cli.main(argv)
        assert exit_info.value.code == 2
    errors = capsys.readouterr().err.splitlines()
    assert "not a vogjax map file" in errors[0] and "cannot be read" in errors[1] and "--format" in errors[2]
    assert not (tmp_path / "x.bt").exists()


def test_ply_holds_the_occupied_voxels_coloured_by_height(voxel_map, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    voxels = VoxelSet.from_map(voxel_map)
    occupied = voxels.centres[voxels.state() == vj.OCCUPIED]
    assert ply.save(voxel_map, tmp_path / "map.ply") == len(occupied)
    cloud = trimesh.load(tmp_path / "map.ply")
    np.testing.assert_allclose(cloud.vertices, occupied, atol=1e-6)
    colours = np.asarray(cloud.colors)[:, :3].astype(int)
    order = np.argsort(occupied[:, 2], kind="stable")
    import matplotlib

    viridis = np.round(matplotlib.colormaps["viridis"]([0.0, 1.0])[:, :3] * 255).astype(int)
    np.testing.assert_array_equal(colours[order[0]], viridis[0])  # lowest: viridis' purple
    np.testing.assert_array_equal(colours[order[-1]], viridis[1])  # highest: its yellow
    # green rises monotonically along viridis: so with height
    assert np.all(np.diff(colours[order, 1]) >= 0)


def test_tum_trajectory_reads_back_with_scipys_quaternions(tmp_path):
    rng = np.random.default_rng(0)
    poses = np.tile(np.eye(4), (20, 1, 1))
    poses[:, :3, :3] = Rotation.random(20, random_state=1).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(20, 3)) * 50
    times = 1.7e9 + np.cumsum(rng.uniform(0.05, 0.2, 20))
    save_tum(tmp_path / "t.tum", times, poses)
    table = np.loadtxt(tmp_path / "t.tum")
    assert table.shape == (20, 8)
    np.testing.assert_allclose(table[:, 0], times, rtol=0, atol=1e-6)
    np.testing.assert_allclose(table[:, 1:4], poses[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(Rotation.from_quat(table[:, 4:8]).as_matrix(), poses[:, :3, :3], atol=1e-7)
    back_times, back_poses = load_tum(tmp_path / "t.tum")
    np.testing.assert_allclose(back_poses, poses, atol=1e-6)
    with pytest.raises(ValueError, match="strictly increasing"):
        save_tum(tmp_path / "bad.tum", times[::-1], poses)
    with pytest.raises(ValueError, match="poses must have shape"):
        save_tum(tmp_path / "bad.tum", times, poses[:3])


def test_a_confidence_rich_map_exports_its_mean_occupancy(tmp_path):
    from vogjax.config.crm import CrmConfig
    from vogjax.maps.confidence import ConfidenceMap

    crm = ConfidenceMap(CrmConfig(voxel_size=0.2, max_range=6.0))
    crm.integrate_scans(*ref.random_scans(np.random.default_rng(7), 4, 100, spread=3.0, far=0.1))
    crm.save(tmp_path / "crm.vog")
    centres, mean, _ = crm.voxels()
    state = crm.state(centres)
    assert {vj.FREE, vj.OCCUPIED} <= set(state.tolist())
    for format in ("bt", "ot"):
        assert cli.main(["export", str(tmp_path / "crm.vog"), "--out", str(tmp_path / f"crm.{format}")]) == 0
    full = octomap.OcTree.read(str(tmp_path / "crm.ot").encode())
    np.testing.assert_allclose([full.search(c).getOccupancy() for c in centres], mean, rtol=1e-5)
    tree = octomap.OcTree(str(tmp_path / "crm.bt").encode())
    for centre, expected in zip(centres, state):
        if expected != vj.UNKNOWN:
            assert tree.isNodeOccupied(tree.search(centre)) == (expected == vj.OCCUPIED)
    assert covered_voxels(tree, 0.2) == np.count_nonzero(state != vj.UNKNOWN)


def test_ply_keeps_far_voxel_centres_exact(tmp_path):
    # as float32, centres 500 km out moved by up to 0.3 voxel; such files are written in float64
    trimesh = pytest.importorskip("trimesh")
    far = vj.VoxelMap(vj.MapConfig(voxel_size=0.1))
    origin = np.array([5e5, 0.0, 0.0])
    far.integrate_scan(origin, origin + [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    voxels = VoxelSet.from_map(far)
    occupied = voxels.centres[voxels.state() == vj.OCCUPIED]
    assert ply.save(far, tmp_path / "far.ply") == 3
    assert b"property double x" in (tmp_path / "far.ply").read_bytes()[:400]
    np.testing.assert_array_equal(np.asarray(trimesh.load(tmp_path / "far.ply").vertices), occupied)
    near = vj.VoxelMap(vj.MapConfig(voxel_size=0.1))
    near.integrate_scan(np.zeros(3), [[1.0, 0.0, 0.0]])
    ply.save(near, tmp_path / "near.ply")
    assert b"property float x" in (tmp_path / "near.ply").read_bytes()[:400]  # the common case stays compact
