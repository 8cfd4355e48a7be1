"""Inputs a fuzzing review found accepted, crashing or answered wrongly, each pinned down: a
ValueError naming the argument (or file), raised before anything changes, or the right answer.
"""

from __future__ import annotations

import fractions
import hashlib
import io
import json
import os
import struct
import zipfile

import h5py
import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.io import atomic
from vogjax.io.dataset import MAX_BEAMS, Dataset, DatasetWriter, ScanBatch
from vogjax.io.mapfile import map_kind, read_map_file, write_map_file
from vogjax.io.tum import load_tum, save_tum
from vogjax.kernels import hashing
from vogjax.maps.confidence_cost import choose_path, edge_risk, most_likely_ranges, path_cost

from .test_fuzz_files import BEAMS, METADATA, run_fields
from .test_fuzz_maps import refuses

CFG = vj.MapConfig(voxel_size=0.25, max_range=3.0)
CRM = vj.CrmConfig(voxel_size=0.25, max_range=2.0, range_sigma_m=0.1, num_bins=8)


def snapshot(m) -> tuple:
    centres, values = m.voxels()
    return centres.tobytes(), values.tobytes()


# ------------------------------------------------------------------ global map: the key range


def far_pose(x_m: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x_m
    return pose


def one_submap_vog(x_m: float) -> vj.VogMap:
    vog = vj.VogMap(CFG)
    i = vog.add_submap(far_pose(x_m))
    vog.submap(i).integrate_scan(np.zeros(3), [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return vog


def key_range_m() -> float:
    return hashing.VOXEL_KEY_LIMIT * CFG.voxel_size


def test_merge_refuses_a_submap_posed_beyond_the_key_range():
    # packed block keys are 21 bits per axis: a submap beyond them would wrap around and land
    # (before this check) about twice the key range away, near the origin
    gmap = vj.GlobalMap(CFG)
    gmap.merge(one_submap_vog(0.0))
    before = snapshot(gmap)
    far = one_submap_vog(2 * key_range_m() + 100.0)
    refuses(lambda: gmap.merge(far), "poses: submap 0")
    assert snapshot(gmap) == before
    refuses(lambda: vj.GlobalMap(CFG).merge(one_submap_vog(1e12)), "poses: submap 0")


def test_add_and_update_refuse_a_submap_moved_beyond_the_key_range():
    vog = one_submap_vog(0.0)
    vog.add_submap(far_pose(key_range_m() + 10.0))
    vog.submap(1).integrate_scan(np.zeros(3), [[1.0, 0.0, 0.0]])
    gmap = vj.GlobalMap(CFG)
    gmap.add(vog, [0])
    before = snapshot(gmap)
    refuses(lambda: gmap.add(vog, [1]), "poses: submap 1")
    vog.set_poses([0], far_pose(-key_range_m())[None])
    refuses(lambda: gmap.update_poses(vog), "poses: submap 0")
    assert snapshot(gmap) == before
    assert gmap.applied_ids == (0,)


def test_a_submap_near_the_edge_of_the_key_range_still_merges():
    x_m = key_range_m() - 100.0  # 400 voxels inside: the box and the rotation margin fit
    vog = one_submap_vog(x_m)
    gmap = vj.GlobalMap(CFG)
    assert gmap.merge(vog) > 0
    point = np.array([[x_m + 1.1, 0.1, 0.1]])
    assert gmap.state(point)[0] == vog.state(point)[0] == vj.OCCUPIED


def test_a_view_refuses_one_submap_twice():
    vog = one_submap_vog(0.0)
    refuses(lambda: vog.view([0, 0]), "ids")
    assert vog.view([0]).log_odds([[1.1, 0.1, 0.1]])[0] == vog.log_odds([[1.1, 0.1, 0.1]])[0]


def test_applied_pose_takes_integer_ids_only():
    gmap = vj.GlobalMap(CFG)
    gmap.merge(one_submap_vog(0.0))
    assert np.array_equal(gmap.applied_pose(0), np.eye(4))
    assert np.array_equal(gmap.applied_pose(np.int64(0)), np.eye(4))
    for bad in (True, 0.0, [0], "0"):
        refuses(lambda bad=bad: gmap.applied_pose(bad), "i")


# ------------------------------------------------------------------ settings


def test_huge_integers_are_refused_naming_the_setting():
    refuses(lambda: vj.MapConfig(voxel_size=10**400), "MapConfig.voxel_size")
    refuses(lambda: vj.CrmConfig(max_range=10**400), "CrmConfig.max_range")
    refuses(lambda: vj.MapConfig.from_dict({"voxel_size": 10**400}), "voxel_size")
    refuses(lambda: vj.VoxelMap(CFG).raycast(np.zeros((1, 3)), [[1.0, 0.0, 0.0]], 10**400), "max_range")


def test_voxel_size_is_bounded():
    # above float32's range the key-range check divided inf by inf and let infinite keys through
    refuses(lambda: vj.MapConfig(voxel_size=1e39), "MapConfig.voxel_size")
    refuses(lambda: vj.CrmConfig(voxel_size=1e39), "CrmConfig.voxel_size")
    assert vj.MapConfig(voxel_size=1000.0, max_range=11.0).voxel_size == 1000.0


def test_crm_max_range_is_capped_like_the_voxel_map():
    longest = MAX_RANGE_VOXELS * 0.1
    assert vj.CrmConfig(voxel_size=0.1, max_range=longest).max_range == longest
    refuses(lambda: vj.CrmConfig(voxel_size=0.1, max_range=longest * 1.01), "CrmConfig.max_range")
    refuses(lambda: vj.MapConfig(voxel_size=0.1, max_range=longest * 1.01), "MapConfig.max_range")


@pytest.mark.parametrize("value", [np.float32(0.25), np.float64(0.25), fractions.Fraction(1, 4)])
def test_numpy_scalars_and_fractions_are_stored_as_floats(tmp_path, value):
    config = vj.MapConfig(voxel_size=value, max_range=3.0)
    assert type(config.voxel_size) is float and config.voxel_size == float(value)
    vmap = vj.VoxelMap(config)
    vmap.integrate_scan(np.zeros(3), [[1.0, 0.0, 0.0]])
    vmap.save(tmp_path / "m.vog")  # the header is JSON: a NumPy scalar made this a TypeError
    assert vj.VoxelMap.load(tmp_path / "m.vog").config == config


def test_numpy_integers_are_stored_as_ints(tmp_path):
    config = vj.CrmConfig(voxel_size=0.25, max_range=2.0, num_bins=np.int64(8))
    assert type(config.num_bins) is int and config == CRM.replace(range_sigma_m=0.05)
    crm = vj.ConfidenceMap(config)
    crm.save(tmp_path / "c.vog")
    assert vj.ConfidenceMap.load(tmp_path / "c.vog").config == config


# ------------------------------------------------------------------ confidence-map queries


def test_confidence_queries_refuse_walks_longer_than_the_line_limit():
    # every voxel on the way is walked (unknown ones have a mean too): 100 rays of 830 km took 23 s
    crm = vj.ConfidenceMap(CRM)
    longest = 65536 * CRM.voxel_size
    refuses(lambda: crm.raycast(np.zeros((2, 3)), [[1.0, 1.0, 1.0]] * 2, longest * 1.5), "max_range")
    refuses(lambda: most_likely_ranges(crm, np.zeros((1, 3)), [[1.0, 0.0, 0.0]], longest * 1.5), "max_range")
    refuses(lambda: edge_risk(crm, np.zeros((1, 3)), [[longest * 1.5, 0.0, 0.0]]), "ends")
    rays = crm.raycast(np.zeros((1, 3)), [[1.0, 0.0, 0.0]], 10.0)
    assert rays.num_unknown[0] == 40  # 10 m of 0.25 m voxels, all never observed


def test_an_empty_path_is_no_path():
    crm = vj.ConfidenceMap(CRM)
    refuses(lambda: path_cost(crm, np.zeros((0, 3))), "waypoints")
    refuses(lambda: choose_path(crm, [np.zeros((0, 3)), np.zeros((1, 3))]), "waypoints")
    refuses(lambda: choose_path(crm, [np.zeros((1, 3))], T_world_sensor=5, sensor=vj.SonarConfig()), "T_world_sensor")
    best, costs = choose_path(crm, [np.zeros((2, 3)), np.zeros((1, 3))])
    assert best == 1 and costs[0] == pytest.approx(2 * costs[1])


# ------------------------------------------------------------------ map files


def saved_map(tmp_path):
    vmap = vj.VoxelMap(CFG)
    vmap.integrate_scan(np.zeros(3), [[1.0, 0.0, 0.0]])
    path = tmp_path / "m.vog"
    vmap.save(path)
    return path


def with_header(path, header: bytes, payload: bytes, version: int = 2):
    prefix = struct.pack("<8sIQ", b"VOGJAXMP", version, len(header))
    contents = prefix + header + payload
    path.write_bytes(contents + hashlib.sha256(contents).digest())
    return path


def test_a_deeply_nested_header_is_a_damaged_header(tmp_path):
    header = b'{"kind": "VoxelMap", "x": ' + b"[" * 100000 + b"]" * 100000 + b"}"
    path = with_header(tmp_path / "deep.vog", header, b"")
    refuses(lambda: vj.VoxelMap.load(path), "damaged header")
    refuses(lambda: map_kind(path), "damaged header")


def test_an_array_larger_than_its_bytes_is_refused_before_allocating(tmp_path):
    metadata, arrays = read_map_file(saved_map(tmp_path), "VoxelMap")
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        header = f"{{'descr': '<i8', 'fortran_order': False, 'shape': ({2**40},), }}"
        header += " " * (118 - len(header) - 1) + "\n"
        archive.writestr(
            "block_keys.npy", b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + b"\0" * 64
        )
        stored = io.BytesIO()
        np.save(stored, arrays["log_odds"])
        archive.writestr("log_odds.npy", stored.getvalue())
    payload = buffer.getvalue()
    head = json.dumps(
        {
            "kind": "VoxelMap",
            "metadata": metadata,
            "payload_bytes": len(payload),
            "payload_sha256": hashlib.sha256(payload).hexdigest(),
        }
    ).encode()
    path = with_header(tmp_path / "huge.vog", head, payload)
    refuses(lambda: vj.VoxelMap.load(path), "declares shape (1099511627776,)")


def test_map_format_version_zero_is_refused(tmp_path):
    path = saved_map(tmp_path)
    data = bytearray(path.read_bytes()[:-32])
    data[8:12] = struct.pack("<I", 0)
    target = tmp_path / "v0.vog"
    target.write_bytes(bytes(data))
    refuses(lambda: vj.VoxelMap.load(target), "format version 0")


def test_a_config_number_too_large_for_a_float_is_refused(tmp_path):
    metadata, arrays = read_map_file(saved_map(tmp_path), "VoxelMap")
    metadata["config"]["voxel_size"] = 10**400
    write_map_file(tmp_path / "big.vog", "VoxelMap", metadata, arrays)
    refuses(lambda: vj.VoxelMap.load(tmp_path / "big.vog"), "voxel_size")


def test_paths_must_be_paths(tmp_path):
    refuses(lambda: vj.VoxelMap(CFG).save(None), "path")
    refuses(lambda: vj.VoxelMap.load(123), "path")
    refuses(lambda: vj.GlobalMap.load(None), "path")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no named pipes here")
def test_save_does_not_replace_a_pipe(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    refuses(lambda: vj.VoxelMap(CFG).save(fifo), "not a regular file")
    assert fifo.is_fifo()


def test_a_folder_that_takes_no_files_is_refused_before_writing(tmp_path, monkeypatch):
    # as root, os.access passes /proc and read-only mounts: a probe file is what tells
    def no_files(*args, **kwargs):
        raise PermissionError(13, "Read-only file system")

    monkeypatch.setattr(atomic.tempfile, "TemporaryFile", no_files)
    refuses(lambda: vj.VoxelMap(CFG).save(tmp_path / "m.vog"), "cannot create files in folder")
    assert not list(tmp_path.iterdir())


def test_the_command_line_turns_os_errors_into_one_line(tmp_path, monkeypatch, capsys):
    from vogjax.commands import export

    def disk_full(args):
        raise OSError(28, "No space left on device", str(tmp_path / "out.bt"))

    monkeypatch.setattr(export, "run", disk_full)
    with pytest.raises(SystemExit) as stop:
        cli.main(["export", "--out", str(tmp_path / "out.bt"), str(tmp_path / "m.vog")])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "No space left on device" in err and "out.bt" in err


# ------------------------------------------------------------------ run files


def run_file(tmp_path):
    path = tmp_path / "run.h5"
    with DatasetWriter(path, BEAMS, METADATA) as writer:
        writer.append(**run_fields(np.random.default_rng(0), count=4))
    return path


def test_a_run_file_declaring_too_many_beams_is_refused_before_reading(tmp_path):
    path = run_file(tmp_path)
    with h5py.File(path, "r+") as f:
        scans = f["time_s"].shape[0]
        for name in ("sonar_directions", "ranges", "no_return"):
            dtype, tail = f[name].dtype, f[name].shape[2:]
            del f[name]
            f.create_dataset(name, shape=(scans, MAX_BEAMS + 1) + tail, dtype=dtype, chunks=(1, 1024) + tail)
    assert path.stat().st_size < 1 << 20  # a small file that would read as gigabytes
    refuses(lambda: Dataset(path), "beams per scan")


@pytest.mark.parametrize("version", [0, -7])
def test_run_format_versions_below_one_are_refused(tmp_path, version):
    path = run_file(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["format_version"] = np.int64(version)
    refuses(lambda: Dataset(path), "format_version")


def test_deeply_nested_run_metadata_is_refused(tmp_path):
    path = run_file(tmp_path)
    with h5py.File(path, "r+") as f:
        f.attrs["metadata"] = "[" * 100000 + "]" * 100000
        del f.attrs["metadata_sha256"]
    refuses(lambda: Dataset(path), str(path))


def test_a_folder_is_no_run_file(tmp_path):
    refuses(lambda: Dataset(tmp_path), "is not a file")


# ------------------------------------------------------------------ TUM trajectories


def test_tum_files_need_unit_quaternions_and_increasing_times(tmp_path):
    path = tmp_path / "t.tum"
    path.write_text("0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 0\n")
    refuses(lambda: load_tum(path), "pose 2 has a quaternion of norm 0")
    path.write_text("1 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n")
    refuses(lambda: load_tum(path), "timestamps must increase")
    refuses(lambda: save_tum(tmp_path / "c.tum", np.array([0, 1j]), np.tile(np.eye(4), (2, 1, 1))), "times_s")


def test_an_empty_batch_takes_an_empty_list_of_scan_indices():
    vmap = vj.VoxelMap(CFG)
    vmap.integrate_scans(np.zeros((1, 3)), np.zeros((0, 3)), [])
    assert len(vmap.voxels()[0]) == 0


# ------------------------------------------------------------------ the mapper takes checked batches


def scan_batch(first: int, count: int, start_s: float = 0.0, truth: bool = True) -> ScanBatch:
    fields = run_fields(np.random.default_rng(first), count=count, first_time=start_s)
    if not truth:
        fields["pose_truth"] = None
    return ScanBatch(first, **fields)


def mapper_state(mapper) -> tuple:
    return (mapper.scans, len(mapper._scan_time), sum(len(p) for p in mapper._pending), snapshot(mapper.standard_map))


def test_the_mapper_checks_each_batch_before_changing_anything():
    import dataclasses

    mapper = vj.pipeline.Mapper(vj.PipelineConfig().replace(scans_per_submap=5, map=CFG))
    mapper.add(scan_batch(0, 4))
    before = mapper_state(mapper)
    good = scan_batch(4, 4, start_s=10.0)
    nan_pose = good.pose_nav.copy()
    nan_pose[1, 0, 3] = np.nan
    scaled = good.pose_nav.copy()
    scaled[1, :3, :3] *= 3.0
    bad = {
        "pose_nav holds NaN": dataclasses.replace(good, pose_nav=nan_pose),
        "not rigid": dataclasses.replace(good, pose_nav=scaled),
        "strictly increasing": dataclasses.replace(good, time_s=good.time_s - 20.0),
        "pose_truth is missing": dataclasses.replace(good, pose_truth=None),
        "beams per scan": ScanBatch(
            4,
            **{
                k: v
                for k, v in run_fields(np.random.default_rng(1), 4, 10.0).items()
                if k not in ("sonar_directions", "ranges", "no_return")
            },
            sonar_directions=np.tile(np.float32([1, 0, 0]), (4, 2, 1)),
            ranges=np.ones((4, 2), np.float32),
            no_return=np.zeros((4, 2), bool),
        ),
    }
    for message, batch in bad.items():
        refuses(lambda batch=batch: mapper.add(batch), message)
        assert mapper_state(mapper) == before, message
    refuses(lambda: mapper.add({"time_s": np.zeros(1)}), "batch must be a ScanBatch")
    mapper.add(good)
    assert mapper.scans == 8
    result = mapper.result()
    assert np.array_equal(result.scan_time_s, np.r_[scan_batch(0, 4).time_s, good.time_s])


# ------------------------------------------------------------------ the planner


def test_a_stale_overlay_reads_a_submap_added_since_from_base_only():
    from vogjax import planner

    cfg = vj.MapConfig(voxel_size=0.2)
    vog, base = vj.VogMap(cfg), vj.GlobalMap(cfg)
    y, z = np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-1.5, 0.7, 23))
    a, b = vog.add_submap(np.eye(4)), vog.add_submap(np.eye(4))
    for _ in range(3):
        vog.submap(a).integrate_scan(np.zeros(3), np.c_[np.full(y.size, 4.05), y.ravel(), z.ravel()])
    vog.submap(b).integrate_scan(np.zeros(3), np.c_[np.full(y.size, 2.05), y.ravel(), z.ravel()])
    base.add(vog, [a])
    overlay = planner.Overlay(base, vog, [b])

    def gain(m):
        g = planner.view_gain(m, np.eye(4)[None], vj.SonarConfig(), max_range_m=5.0)
        return g.unknown[0], g.free[0], g.occupied[0]

    expected = gain(overlay)
    base.add(vog, [b])
    assert gain(base) == expected
    assert gain(overlay) == expected  # b counted once, not on top of base's copy of it


def test_the_planner_refuses_what_would_read_as_explored():
    from vogjax import planner, sensors

    m = vj.VoxelMap(vj.MapConfig(voxel_size=0.2))
    cfg = planner.PlannerConfig(max_nodes=3, tolerance_nodes=6, gain_range_m=2.0, gain_step_m=0.5)
    bounds = [[-3, -3, -3], [3, 3, 3]]
    refuses(lambda: planner.NbvPlanner(cfg, bounds=bounds, region=[[3, 3, 3], [-3, -3, -3]]), "region")
    refuses(lambda: planner.NbvPlanner(cfg.replace(gain_range_m=0.3), bounds=bounds), "gain_range_m")
    refuses(lambda: planner.view_gain(m, np.eye(4)[None], vj.SonarConfig(), max_range_m=0.3), "max_range_m")
    refuses(lambda: planner.NbvPlanner(cfg, bounds=bounds, sensor=sensors.PointCloudSensor()), "sensor")


def test_a_refused_plan_leaves_the_planner_as_it_was():
    from vogjax import planner

    m = vj.VoxelMap(vj.MapConfig(voxel_size=0.2))
    cfg = planner.PlannerConfig(max_nodes=3, tolerance_nodes=6, gain_range_m=2.0, gain_step_m=0.5)
    bounds = [[-3, -3, -3], [3, 3, 3]]
    fresh = planner.NbvPlanner(cfg, bounds=bounds).plan(m, np.eye(4))
    nbv = planner.NbvPlanner(cfg, bounds=bounds)
    far_map = vj.VoxelMap(vj.MapConfig(voxel_size=1e-4, max_range=0.4))  # 838 m of keys: the bounds fit, ...
    nbv.bounds = np.array([[-1e3, -3, -3], [1e3, 3, 3]])  # ... these do not
    refuses(lambda: nbv.plan(far_map, np.eye(4)), "bounds")
    nbv.bounds = np.array(bounds, np.float64)
    again = nbv.plan(m, np.eye(4))
    assert np.array_equal(again.tree_states, fresh.tree_states)


def test_gain_and_collision_work_is_bounded():
    from vogjax import planner
    from vogjax.planner.collision import MAX_SWEPT_VOXELS
    from vogjax.planner.gain import MAX_EDGE_VIEWS

    m = vj.VoxelMap(vj.MapConfig(voxel_size=0.2))
    sonar = vj.SonarConfig(beams=4)
    # 2 m at 1e-7 m took 75 s and 10 GB
    refuses(lambda: planner.edge_gain(m, [[0, 0, 0, 0]], [[2, 0, 0, 0]], sonar, step_m=1e-7, max_range_m=1.0), "step_m")
    views = planner.edge_views(np.zeros((1, 4)), [[2.0 * MAX_EDGE_VIEWS * 1e-4, 0, 0, 0]], np.eye(4), 2e-4, 1.0)[1]
    assert len(views) == MAX_EDGE_VIEWS  # at the limit: accepted
    refuses(lambda: planner.edge_views(np.zeros((1, 4)), np.ones((1, 4)), np.eye(4), 0.0, 5.0), "step_m")
    # 1e5 m of rays at 0.2 m voxels took minutes; a map's beams stop at MAX_RANGE_VOXELS
    refuses(lambda: planner.view_gain(m, np.eye(4)[None], sonar, max_range_m=MAX_RANGE_VOXELS * 0.2 + 1), "max_range_m")
    assert planner.view_gain(m, np.eye(4)[None], sonar, max_range_m=5.0).unknown[0] > 0
    side = int(np.cbrt(MAX_SWEPT_VOXELS)) * 0.2 * 2
    refuses(lambda: planner.edges_clear(m, [[0, 0, 0]], [[side, side, side]], (1, 1, 1), (0, 0, 0)), "ends")


def test_sonar_and_tree_sizes_are_bounded():
    from vogjax import planner
    from vogjax.config.planner import MAX_TREE_NODES

    refuses(lambda: vj.SonarConfig(beams=10**12), "SonarConfig.beams")
    refuses(lambda: vj.SonarConfig(beams=1 << 12, subrays=1 << 9), "SonarConfig.beams times SonarConfig.subrays")
    refuses(
        lambda: planner.PlannerConfig(max_nodes=MAX_TREE_NODES + 1, tolerance_nodes=MAX_TREE_NODES + 1),
        "PlannerConfig.max_nodes",
    )


def test_nearest_nodes_in_chunks_are_the_brute_force_ones():
    from vogjax.planner.nbv import _nearest

    rng = np.random.default_rng(3)
    nodes = np.round(rng.uniform(-2, 2, (3000, 3)))  # many exact ties: the first must win
    targets = np.round(rng.uniform(-2, 2, (1500, 3)))
    brute = np.argmin(np.linalg.norm(nodes[None] - targets[:, None], axis=2), axis=1)
    assert np.array_equal(_nearest(nodes, targets), brute)


def test_an_archive_that_lies_about_its_members_is_refused(tmp_path):
    metadata, arrays = read_map_file(saved_map(tmp_path), "VoxelMap")

    def saved_with(payload: bytes, name: str):
        head = json.dumps(
            {
                "kind": "VoxelMap",
                "metadata": metadata,
                "payload_bytes": len(payload),
                "payload_sha256": hashlib.sha256(payload).hexdigest(),
            }
        ).encode()
        return with_header(tmp_path / name, head, payload)

    # a member whose central-directory size (zip64) claims 8 TiB it does not hold
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (1 << 40,)})
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        archive.writestr("log_odds.npy", header.getvalue() + b"\0" * 64)
    data = bytearray(buffer.getvalue())
    directory = data.find(b"PK\x01\x02")
    (name_length,) = struct.unpack_from("<H", data, directory + 28)
    struct.pack_into("<I", data, directory + 24, 0xFFFFFFFF)  # uncompressed size: see the zip64 field
    struct.pack_into("<H", data, directory + 30, 12)
    at = directory + 46 + name_length
    data[at:at] = struct.pack("<HHQ", 1, 8, (1 << 43) + 4096)
    end = data.find(b"PK\x05\x06")
    (size,) = struct.unpack_from("<I", data, end + 12)
    struct.pack_into("<I", data, end + 12, size + 12)
    assert zipfile.ZipFile(io.BytesIO(bytes(data))).infolist()[0].file_size == (1 << 43) + 4096
    refuses(lambda: vj.VoxelMap.load(saved_with(bytes(data), "inflated.vog")), "the payload does not hold")
    # a member flagged encrypted (zipfile raised RuntimeError)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        stored = io.BytesIO()
        np.save(stored, arrays["log_odds"])
        archive.writestr("log_odds.npy", stored.getvalue())
    data = bytearray(buffer.getvalue())
    for signature, flag_at in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = data.find(signature) + flag_at
        struct.pack_into("<H", data, at, struct.unpack_from("<H", data, at)[0] | 0x1)
    refuses(lambda: vj.VoxelMap.load(saved_with(bytes(data), "encrypted.vog")), "encrypted")


def test_report_numbers_that_are_not_defined_are_null():
    from vogjax.report.document import finite_or_null

    report = {
        "auc": {"online": np.float32("nan"), "standard": 0.9},
        "errors": [1.0, float("inf")],
        "counts": np.array([1, 2]),
        "name": "run",
    }
    cleaned = finite_or_null(report)
    assert cleaned == {"auc": {"online": None, "standard": 0.9}, "errors": [1.0, None], "counts": [1, 2], "name": "run"}
    json.dumps(cleaned, allow_nan=False)  # strict JSON


def test_ctrl_c_is_one_line_and_status_130(tmp_path, monkeypatch, capsys):
    from vogjax.commands import export

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(export, "run", interrupted)
    with pytest.raises(SystemExit) as stop:
        cli.main(["export", "--out", str(tmp_path / "out.bt"), str(tmp_path / "m.vog")])
    assert stop.value.code == 130
    assert capsys.readouterr().err.strip() == "vogjax export: interrupted"


def test_a_beam_too_short_for_a_float32_direction_clears_nothing():
    """1.4e-30 m from the origin to the next voxel down: its float32 length underflows to 0, and
    its walk used to clear voxels up to 40 cm away along y (OctoMap loops forever on it). Like a
    beam within one voxel, it marks its endpoint only; a line query answers its end voxel."""
    origin, point = np.zeros(3, np.float32), np.array([[-1e-30, -1e-30, 0.0]], np.float32)
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.1), device="cpu")
    vmap.integrate_scan(origin, point)
    centres, log_odds = vmap.voxels()
    assert np.floor(centres / 0.1).astype(int).tolist() == [[-1, -1, 0]] and log_odds[0] > 0
    assert vmap.line_query(origin[None], point)[1].tolist() == [1]
    # a short beam that float32 can still give a direction walks as before: its origin voxel free
    vmap.integrate_scan(origin, np.array([[-1e-12, -1e-12, 0.0]], np.float32))
    centres, log_odds = vmap.voxels()
    assert sorted(np.floor(centres / 0.1).astype(int).tolist()) == [[-1, -1, 0], [0, 0, 0]]
    assert log_odds[np.all(np.floor(centres / 0.1) == 0, axis=1)][0] < 0
