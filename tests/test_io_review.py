"""From a review of the readers and importers: frames left empty, memory bounded by chunks and
validation steps, damaged map and run files, zero ranges, an import that would replace its bag.
Each case failed on the code before it."""

import subprocess
import sys

import h5py
import numpy as np
import pytest

import vogjax as vj
from vogjax.io import dataset as ds_module
from vogjax.io.dataset import Dataset, DatasetWriter
from vogjax.io.mapfile import read_map_file, write_map_file
from vogjax.io.rosbag import import_bag

from . import test_import as bags
from . import test_import_depth as depth


def runs_equal(a, b) -> bool:
    with Dataset(a) as x, Dataset(b) as y:
        if len(x) != len(y):
            return False
        first, second = x.read(0, len(x)), y.read(0, len(y))
        return all(
            np.array_equal(getattr(first, name), getattr(second, name), equal_nan=True)
            for name in ("time_s", "pose_nav", "sonar_directions", "ranges", "no_return")
        )


def test_clouds_without_a_frame_need_the_frame_named(tmp_path):
    """A cloud whose header names no frame was taken as the vehicle's, its points unmounted."""
    bag = tmp_path / "noframe.bag"
    bags.cloud_bag(bag, "ros1", frame="")
    with pytest.raises(ValueError, match="no frame_id: pass --frame"):
        import_bag(bag, tmp_path / "a.h5", points_topic="/points", odometry_topic="/odom", progress=False)
    assert not (tmp_path / "a.h5").exists()
    # named, it is the same bag whose clouds say so
    kwargs = dict(points_topic="/points", odometry_topic="/odom", frame="base_link", progress=False)
    import_bag(bag, tmp_path / "b.h5", **kwargs)
    named = tmp_path / "named.bag"
    bags.cloud_bag(named, "ros1", frame="base_link", with_tf=False)
    import_bag(named, tmp_path / "c.h5", **kwargs)
    assert runs_equal(tmp_path / "b.h5", tmp_path / "c.h5")


def test_depth_images_without_a_frame_are_in_the_camera_infos(tmp_path, monkeypatch):
    """Depth images naming no frame, their CameraInfo naming the optical frame: the optical-frame
    points were stored as the vehicle's (an identity mount, z ahead taken as x ahead)."""
    original = depth.image_message

    def without_frame(*args, **kwargs):
        msg = original(*args, **kwargs)
        msg.header.frame_id = ""
        return msg

    named = tmp_path / "named.bag"
    depth.plane_bag(named, "ros1", "32FC1")
    monkeypatch.setattr(depth, "image_message", without_frame)
    bag = tmp_path / "noframe.bag"
    depth.plane_bag(bag, "ros1", "32FC1")
    with pytest.raises(ValueError, match="in frame 'camera'.*pass --frame camera"):
        import_bag(bag, tmp_path / "a.h5", depth_topic=depth.DEPTH, odometry_topic="/odom", progress=False)
    import_bag(bag, tmp_path / "b.h5", depth_topic=depth.DEPTH, odometry_topic="/odom", frame="camera", progress=False)
    import_bag(
        named, tmp_path / "c.h5", depth_topic=depth.DEPTH, odometry_topic="/odom", frame="camera", progress=False
    )
    assert runs_equal(tmp_path / "b.h5", tmp_path / "c.h5")


def test_a_laser_range_of_zero_is_no_return_at_the_sensor():
    """Many drivers write 0 for "no measurement": beside range_min 0 it became a hit in the
    sensor's own voxel, where a cloud's point at the sensor is an invalid beam."""
    from types import SimpleNamespace as NS

    from vogjax.io.rosbag import laser_beams

    header = NS(stamp=NS(sec=1, nanosec=0), frame_id="base_link")
    message = NS(
        header=header,
        ranges=np.float32([0.0, 0.0, 3.0, 20.0]),
        intensities=np.float32([]),
        angle_min=0.0,
        angle_increment=0.5,
        range_min=0.0,
        range_max=10.0,
    )
    scan = laser_beams(message, "/scan")
    assert scan.invalid == 2
    assert scan.ranges[~scan.no_return].tolist() == [3.0] and scan.no_return.sum() == 1


def test_an_import_does_not_replace_its_bag(tmp_path, capsys):
    from vogjax import cli

    bag = tmp_path / "drive.bag"
    bags.cloud_bag(bag, "ros1")
    before = bag.read_bytes()
    command = ["import", str(bag), "--points", "/points", "--odometry", "/odom", "--frame", "lidar"]
    with pytest.raises(SystemExit) as stop:
        cli.main([*command, "--out", str(bag), "--overwrite"])
    assert stop.value.code == 2
    assert "is the bag being imported" in capsys.readouterr().err
    assert bag.read_bytes() == before


@pytest.mark.parametrize("count", ["1e400", "12.5", "true", '"123"', "-1"])
def test_a_map_header_with_a_count_no_integer_holds_is_damage(tmp_path, count):
    """A header of "payload_bytes": 1e400 (JSON's inf) raised OverflowError, a traceback on the
    command line; the whole-file checksum does not stop it (anyone can recompute it)."""
    import hashlib
    import io
    import struct

    from vogjax.io.mapfile import FORMAT_VERSION, MAGIC

    buffer = io.BytesIO()
    np.savez(buffer, a=np.zeros(3))
    payload = buffer.getvalue()
    digest = hashlib.sha256(payload).hexdigest()
    header = f'{{"kind": "voxel_map", "metadata": {{}}, "payload_bytes": {count}, "payload_sha256": "{digest}"}}'
    contents = struct.pack("<8sIQ", MAGIC, FORMAT_VERSION, len(header)) + header.encode() + payload
    path = tmp_path / "crafted.vog"
    path.write_bytes(contents + hashlib.sha256(contents).digest())
    with pytest.raises(ValueError, match="damaged header|truncated or has trailing data"):
        read_map_file(path, "voxel_map")
    write_map_file(tmp_path / "m.vog", "voxel_map", {"a": 1}, {"x": np.arange(3)})
    assert read_map_file(tmp_path / "m.vog", "voxel_map")[0] == {"a": 1}  # what it writes, it reads


@pytest.mark.parametrize("field", ["ranges", "time_s", "intensity"])
def test_a_run_field_that_is_a_group_is_damage(tmp_path, field):
    path = tmp_path / "run.h5"
    writer = DatasetWriter(path, 4, {"sensor": {"kind": "sonar"}}, optional=("intensity",))
    writer.close()
    with h5py.File(path, "a") as f:
        del f[field]
        f.create_group(field)
    with pytest.raises(ValueError, match=f"field {field} is not a dataset"):
        Dataset(path)


def test_a_run_of_wide_scans_is_chunked_by_its_values():
    """Chunks of 256 scans whatever the beams: one scan of a million beams cost 3 GB to write or
    read (HDF5 works in whole chunks)."""
    for beams, expected in ((4, 256), (256, 256), (1024, 64), (4096, 16), (1 << 20, 1)):
        assert ds_module._chunk_scans((beams,)) == expected
        assert ds_module._chunk_scans((beams, 3)) == max(1, min(256, (1 << 16) // (3 * beams)))
    assert ds_module._chunk_scans(()) == ds_module._chunk_scans((4, 4)) == 256


def test_writing_and_reading_one_wide_scan_stays_near_its_size(tmp_path):
    """Measured in a process of its own: the peak memory of one scan of 2^18 beams (5 MB of
    data) written and read back stays under 200 MB (it was about 800 MB)."""
    script = f"""
import resource, numpy as np
from vogjax.io.dataset import Dataset, DatasetWriter
beams = 1 << 18
before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
w = DatasetWriter({str(tmp_path / "wide.h5")!r}, beams, {{"sensor": {{"kind": "sonar"}}}})
d = np.zeros((1, beams, 3), np.float32); d[..., 0] = 1
w.append(time_s=np.array([0.0]), pose_truth=np.eye(4)[None], pose_nav=np.eye(4)[None],
         sonar_origin=np.zeros((1, 3), np.float32), sonar_directions=d,
         ranges=np.ones((1, beams), np.float32), no_return=np.zeros((1, beams), bool),
         invalid=np.zeros((1, beams), bool))
w.close()
with Dataset({str(tmp_path / "wide.h5")!r}) as ds:
    ds.read(0, 1)
print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert float(done.stdout.split()[-1]) < 200


def test_validation_reads_wide_runs_in_bounded_steps(tmp_path, monkeypatch):
    path = tmp_path / "run.h5"
    beams = 4096
    w = DatasetWriter(path, beams, {"sensor": {"kind": "sonar"}})
    count = 600
    d = np.zeros((count, beams, 3), np.float32)
    d[..., 0] = 1
    w.append(
        time_s=np.arange(count, dtype=np.float64),
        pose_truth=np.tile(np.eye(4), (count, 1, 1)),
        pose_nav=np.tile(np.eye(4), (count, 1, 1)),
        sonar_origin=np.zeros((count, 3), np.float32),
        sonar_directions=d,
        ranges=np.ones((count, beams), np.float32),
        no_return=np.zeros((count, beams), bool),
        invalid=np.zeros((count, beams), bool),
    )
    w.close()
    steps = []
    original = Dataset.read

    def read(self, first, last):
        steps.append(last - first)
        return original(self, first, last)

    monkeypatch.setattr(Dataset, "read", read)
    monkeypatch.setattr(vj.sensors, "from_metadata", lambda metadata: None)
    with Dataset(path) as ds:
        ds.validate()
    assert max(steps) * beams <= ds_module.VALIDATE_BEAMS and sum(steps) == count
