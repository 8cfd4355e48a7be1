"""Fuzzing files (issue 17): map files (.vog), run files (HDF5) and settings (TOML).

Damaged files (flipped bits, truncation, trailing bytes), crafted files that pass the checksum
but hold impossible contents, run files with wrong attributes and fields, hostile appends, and
settings documents with wrong types, unknown keys and huge values. Each must load as exactly
what was written (or a self-consistent map) or give a ValueError naming the file or setting.
Helpers and settings: tests/test_fuzz_maps.py.
"""

from __future__ import annotations

import json
import math
import struct
import tomllib

import h5py
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import vogjax as vj
from vogjax.config import JobConfig
from vogjax.io.dataset import Dataset, DatasetWriter
from vogjax.io.mapfile import read_map_file, write_map_file
from vogjax.maps.blocks import pack_blocks, unpack_blocks

from . import submap_helpers as helpers
from .test_fuzz_maps import CFG, JUNK, REFUSED, attempt, crm_base, fuzz, refuses, same

# ------------------------------------------------------------------------------ map files

PREFIX = struct.Struct("<8sIQ")


class Saved:
    """A saved file and what it holds (a short repr: hypothesis prints fixtures of failing cases)."""

    def __init__(self, path, data: bytes, contents):
        self.path, self.data, self.contents = path, data, contents

    def __iter__(self):
        return iter((self.path, self.data, self.contents))

    def __repr__(self) -> str:
        return f"Saved({self.path.name})"


class Files(dict):
    def __repr__(self) -> str:
        return f"Files({', '.join(self)})"


@pytest.fixture(scope="module")
def map_files(tmp_path_factory):
    """One saved map of each kind, with the map it came from."""
    folder = tmp_path_factory.mktemp("maps")
    vog = helpers.random_vog(np.random.default_rng(0), 2, CFG, scans=2, beams=30, spread=2.0)
    gmap = vj.GlobalMap(CFG)
    gmap.merge(vog)
    maps = {"VoxelMap": vog.submap(0), "GlobalMap": gmap, "ConfidenceMap": crm_base()}
    files = Files()
    for kind, m in maps.items():
        path = folder / f"{kind}.vog"
        m.save(path)
        files[kind] = Saved(path, path.read_bytes(), m)
    return files


CLASSES = {"VoxelMap": vj.VoxelMap, "GlobalMap": vj.GlobalMap, "ConfidenceMap": vj.ConfidenceMap}


def map_contents(m):
    """Everything a loaded map answers that tells maps apart."""
    contents = [m.config, m.voxels()]
    if isinstance(m, vj.GlobalMap):
        contents += [m.sums(), m.applied_ids, [m.applied_pose(i) for i in m.applied_ids]]
    return contents


def header_end(data: bytes) -> int:
    return PREFIX.size + PREFIX.unpack_from(data)[2]


@fuzz(60)
@given(data=st.data())
def test_damaged_map_files(map_files, tmp_path_factory, data):
    """Flipped bits in the prefix or the checksummed payload, truncation, trailing or inserted
    bytes: a ValueError naming the file, or (a flip that changes nothing read) the same map.
    (Flips in the JSON header: test_map_header_damage_is_detected.)"""
    kind = data.draw(st.sampled_from(list(map_files)))
    path, original, m = map_files[kind]
    damaged = bytearray(original)
    start = header_end(original)
    for _ in range(data.draw(st.integers(1, 3))):
        how = data.draw(
            st.sampled_from(["flip_payload", "flip_payload", "flip_prefix", "truncate", "append", "insert", "zero_run"])
        )
        if how in ("flip_payload", "flip_prefix", "truncate", "zero_run", "insert") and len(damaged) <= start:
            how = "append"
        if how == "flip_payload":
            damaged[data.draw(st.integers(start, len(damaged) - 1))] ^= 1 << data.draw(st.integers(0, 7))
        elif how == "flip_prefix":
            damaged[data.draw(st.integers(0, PREFIX.size - 1))] ^= 1 << data.draw(st.integers(0, 7))
        elif how == "truncate":
            damaged = damaged[: data.draw(st.integers(0, len(damaged) - 1))]
        elif how == "append":
            damaged += data.draw(st.binary(min_size=1, max_size=16))
        elif how == "insert":
            at = data.draw(st.integers(start, len(damaged)))
            damaged[at:at] = data.draw(st.binary(min_size=1, max_size=8))
        else:
            at = data.draw(st.integers(start, max(start, len(damaged) - 1)))
            damaged[at : at + 64] = bytes(len(damaged[at : at + 64]))
    target = tmp_path_factory.mktemp("damaged") / "map.vog"
    target.write_bytes(bytes(damaged))
    loaded = attempt(lambda: CLASSES[kind].load(target), [str(target)], None, "either", f"{kind}.load")
    if loaded is not REFUSED:
        assert same(map_contents(loaded), map_contents(m)), "a damaged file loaded as another map"


# crafted files: the checksum is right, the contents are not what a map can hold


def craft_voxelmap(metadata, arrays, how):
    if not isinstance(metadata, dict):
        return metadata, arrays
    keys, values = arrays.get("block_keys", np.zeros(2, np.int64)), arrays.get("log_odds", np.zeros((2, 512)))
    if how == "keys_int32":
        arrays["block_keys"] = keys.astype(np.int32)
    elif how == "values_float64":
        arrays["log_odds"] = values.astype(np.float64)
    elif how == "duplicate_key" and len(keys) > 1:
        keys[1] = keys[0]
    elif how == "rows":
        arrays["log_odds"] = values[:-1]
    elif how == "missing":
        del arrays["log_odds"]
    elif how in ("config_type", "config_range", "config_unknown") and "config" in metadata:
        key, value = {
            "config_type": ("voxel_size", "0.1"),
            "config_range": ("prob_hit", 1.5),
            "config_unknown": ("voxel_sise", 0.1),
        }[how]
        metadata["config"][key] = value
    elif how == "metadata_list":
        return [], arrays
    elif how == "no_config" and isinstance(metadata, dict):
        metadata.pop("config", None)
    elif how == "values_2d":
        arrays["log_odds"] = values.reshape(len(values), 8, -1)
    elif how == "pickled":
        arrays["log_odds"] = np.array([object()] * 2, dtype=object)
    elif how == "nan_values" and values.ndim == 2:  # never observed: fine
        values[0, :] = np.nan
    return metadata, arrays


def craft_globalmap(metadata, arrays, how):
    counts, sums = arrays["count"], arrays["sum"]
    if not isinstance(metadata, dict):
        return metadata, arrays
    applied = metadata.get("applied", {"0": {}})
    if how in ("revision_text", "pose_missing") and "0" not in applied:
        return metadata, arrays
    if how == "count_dtype":
        arrays["count"] = counts.astype(np.int64)
    elif how == "sum_dtype":
        arrays["sum"] = sums.astype(np.float64)
    elif how == "revision_text":
        applied["0"]["revision"] = "x"
    elif how == "id_text" and "0" in applied:
        applied["x"] = applied.pop("0")
    elif how == "pose_missing":
        applied["0"].pop("pose", None)
    elif how == "no_applied":
        metadata.pop("applied", None)
    elif how == "shapes":
        arrays["count"] = counts[:, :100]
    else:
        return craft_voxelmap(metadata, {"block_keys": arrays["block_keys"], "log_odds": arrays["sum"]}, how)[0], arrays
    return metadata, arrays


CRAFTS = {
    "VoxelMap": (
        craft_voxelmap,
        [
            "keys_int32",
            "values_float64",
            "duplicate_key",
            "rows",
            "missing",
            "config_type",
            "config_range",
            "config_unknown",
            "metadata_list",
            "no_config",
            "values_2d",
            "pickled",
            "nan_values",
        ],
    ),
    "GlobalMap": (
        craft_globalmap,
        [
            "count_dtype",
            "sum_dtype",
            "revision_text",
            "id_text",
            "pose_missing",
            "no_applied",
            "shapes",
            "config_type",
            "config_range",
            "metadata_list",
            "no_config",
        ],
    ),
}


def consistent(m) -> None:
    """A loaded map answers its own voxels back: each listed voxel is found by a point query at
    its centre with the same value, values are finite and within the clamps, keys are packed."""
    centres, values = m.voxels()
    cfg = m.config
    assert np.all(np.isfinite(values))
    assert np.all((values >= cfg.log_clamp_min) & (values <= cfg.log_clamp_max))
    assert np.array_equal(m.log_odds(centres), values)
    keys, _ = m.store.host_blocks()
    assert np.array_equal(pack_blocks(unpack_blocks(keys)), keys)


@fuzz(40)
@given(data=st.data())
def test_crafted_map_files(map_files, tmp_path_factory, data):
    """Files with a valid checksum but crafted contents (wrong dtypes and shapes, duplicate keys,
    missing arrays, pickles, bad configs and applied poses): a ValueError naming the file, or a
    map that answers its own voxels back. (Unchecked contents: test_crafted_contents_are_refused.)"""
    kind = data.draw(st.sampled_from(["VoxelMap", "GlobalMap"]))
    path, _, _ = map_files[kind]
    metadata, arrays = read_map_file(path, kind)
    metadata = json.loads(json.dumps(metadata))
    arrays = {k: v.copy() for k, v in arrays.items()}
    craft, kinds = CRAFTS[kind]
    damages = data.draw(st.lists(st.sampled_from(kinds), min_size=1, max_size=2, unique=True))
    for how in ["pickled"] if "pickled" in damages else damages:
        metadata, arrays = craft(metadata, arrays, how)
    target = tmp_path_factory.mktemp("crafted") / "map.vog"
    try:
        write_map_file(target, kind, metadata, arrays)
    except ValueError:  # np.savez refuses object arrays only when loading; nothing to test
        return
    loaded = attempt(lambda: CLASSES[kind].load(target), [str(target)], None, "either", f"{kind}.load")
    if loaded is not REFUSED:
        consistent(loaded)


# ------------------------------------------------------------------------------ run files

SCANS, BEAMS = 300, 6  # two chunks of 256 scans per field


def run_fields(rng, count=SCANS, first_time=0.0):
    """Synthetic scans that make physical sense."""
    poses = np.tile(np.eye(4), (count, 1, 1))
    yaw = rng.uniform(-np.pi, np.pi, count)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    poses[:, :3, 3] = rng.normal(size=(count, 3))
    directions = rng.normal(size=(count, BEAMS, 3))
    directions /= np.linalg.norm(directions, axis=2, keepdims=True)
    ranges = rng.uniform(0.5, 10.0, (count, BEAMS)).astype(np.float32)
    no_return = rng.random((count, BEAMS)) < 0.2
    ranges[no_return] = np.nan
    return {
        "time_s": first_time + np.arange(count) * 0.2,
        "pose_truth": poses,
        "pose_nav": poses.copy(),
        "sonar_origin": np.tile(np.float32([0.9, 0.0, -0.1]), (count, 1)),
        "sonar_directions": directions.astype(np.float32),
        "ranges": ranges,
        "no_return": no_return,
    }


METADATA = {"scene": "boxes", "seed": 3, "sensor": {"kind": "sonar", "beams": BEAMS}}


@pytest.fixture(scope="module")
def run_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("runs") / "run.h5"
    fields = run_fields(np.random.default_rng(0))
    with DatasetWriter(path, BEAMS, METADATA) as writer:
        writer.append(**fields)
    return Saved(path, path.read_bytes(), fields)


def read_run(path):
    with Dataset(path) as ds:
        ds.validate()
        batch = next(ds.batches(10**6))
        return (
            ds.metadata,
            ds.has_truth,
            {
                name: getattr(batch, name)
                for name in (
                    "time_s",
                    "pose_truth",
                    "pose_nav",
                    "sonar_origin",
                    "sonar_directions",
                    "ranges",
                    "no_return",
                )
            },
        )


def chunk_spans(path):
    """(offset, size) of every stored chunk of every field."""
    spans = []
    with h5py.File(path, "r") as f:
        for name in f:
            ds = f[name]
            spans += [
                (info.byte_offset, info.size)
                for info in (ds.id.get_chunk_info(i) for i in range(ds.id.get_num_chunks()))
            ]
    return spans


@fuzz(60)
@given(data=st.data())
def test_flipped_bits_in_run_chunks(run_file, tmp_path_factory, data):
    """Bits flipped inside the data chunks (Fletcher-32 checksummed): a ValueError naming the
    file, or exactly the scans written. (Flips in the chunk index and the metadata attribute:
    test_damaged_run_index_is_detected, test_damaged_run_metadata_is_detected.)"""
    path, original, fields = run_file
    spans = chunk_spans(path)
    damaged = bytearray(original)
    for _ in range(data.draw(st.integers(1, 3))):
        offset, size = data.draw(st.sampled_from(spans))
        damaged[offset + data.draw(st.integers(0, size - 1))] ^= 1 << data.draw(st.integers(0, 7))
    if data.draw(st.integers(0, 4)) == 0:
        damaged = damaged[: data.draw(st.integers(0, len(damaged) - 1))]
    target = tmp_path_factory.mktemp("damaged") / "run.h5"
    target.write_bytes(bytes(damaged))
    result = attempt(lambda: read_run(target), [str(target)], None, "either", "Dataset")
    if result is not REFUSED:
        assert same(result, (METADATA, True, fields))


ATTRIBUTES = {  # (array-valued format and has_truth, text format_version: test_attributes_of_the_wrong_kind_...)
    "format": ["vogjax-run", "vogjax-runs", "", 7],
    "format_version": [2, 1, 3, 99, -1, 2.5, "2", np.array([2, 2]), True],
    "has_truth": [True, False, "no", 2],
    "metadata": [
        json.dumps(METADATA),
        "[]",
        "null",
        "{",
        "",
        '"text"',
        "5",
        json.dumps({"scene": 5}),
        b"\xff\xfe",
        np.array([1, 2]),
    ],
}


@fuzz(60)
@given(data=st.data())
def test_run_file_attributes(run_file, tmp_path_factory, data):
    """Wrong, missing and mistyped file attributes: a ValueError naming the file, or the scans
    as written with the metadata and has_truth the attributes say."""
    path, original, fields = run_file
    target = tmp_path_factory.mktemp("attrs") / "run.h5"
    target.write_bytes(original)
    changed = {}
    with h5py.File(target, "r+") as f:
        for name in data.draw(st.lists(st.sampled_from(list(ATTRIBUTES)), min_size=1, max_size=2, unique=True)):
            if data.draw(st.integers(0, 5)) == 0:
                del f.attrs[name]
                changed[name] = "missing"
            else:
                value = data.draw(st.sampled_from(ATTRIBUTES[name]))
                f.attrs[name] = value
                changed[name] = value
    result = attempt(lambda: read_run(target), [str(target)], None, "either", "Dataset")
    if result is REFUSED:
        return
    metadata, has_truth, scans = result
    assert isinstance(metadata, dict)
    assert changed.get("format", "vogjax-run") == "vogjax-run"
    assert (
        same(scans, fields)
        if has_truth
        else same(
            {k: v for k, v in scans.items() if k != "pose_truth"},
            {k: v for k, v in fields.items() if k != "pose_truth"},
        )
    )


FIELD_DAMAGE = [
    "dtype",
    "shape",
    "length",
    "missing",
    "nan_range",
    "negative_range",
    "far_range",
    "time_back",
    "time_nan",
    "nonrigid",
    "direction",
    "no_return_int",
    "origin_far",
    "scalar",
    "empty",
]


@fuzz(60)
@given(data=st.data())
def test_run_file_fields(run_file, tmp_path_factory, data):
    """Fields replaced with wrong dtypes, shapes and lengths, or values that make no physical
    sense: a ValueError naming the file (on opening or on reading), never another exception."""
    path, original, fields = run_file
    target = tmp_path_factory.mktemp("fields") / "run.h5"
    target.write_bytes(original)
    how = data.draw(st.sampled_from(FIELD_DAMAGE))
    name = data.draw(st.sampled_from(list(fields)))
    row = data.draw(st.integers(0, SCANS - 1))
    with h5py.File(target, "r+") as f:
        value = f[name][()]
        if how == "dtype":
            value = value.astype(np.int32 if value.dtype != np.int32 else np.float64)
        elif how == "shape":
            value = value.reshape(SCANS, -1) if value.ndim > 1 else value[:, None]
            value = np.concatenate([value, value], axis=1)
        elif how == "length":
            value = value[: -data.draw(st.integers(1, 5))]
        elif how == "scalar":
            value = np.float64(1.0)
        elif how == "empty":
            value = value[:0]
        if how in ("dtype", "shape", "length", "missing", "scalar", "empty"):
            del f[name]
            if how != "missing":
                f.create_dataset(name, data=value)
        else:
            field = {
                "nan_range": "ranges",
                "negative_range": "ranges",
                "far_range": "ranges",
                "time_back": "time_s",
                "time_nan": "time_s",
                "nonrigid": "pose_nav",
                "direction": "sonar_directions",
                "no_return_int": "no_return",
                "origin_far": "sonar_origin",
            }[how]
            stored = f[field]
            value = stored[()]
            if how == "nan_range":
                value[row, ~f["no_return"][row]] = np.nan
            elif how == "negative_range":
                value[row, ~f["no_return"][row]] = -1.0
            elif how == "far_range":
                value[row, ~f["no_return"][row]] = 2e4
            elif how == "time_back":
                value[row] = value[row - 1] if row else -1.0
                if row == 0:
                    value[1] = value[0]
            elif how == "time_nan":
                value[row] = np.nan
            elif how == "nonrigid":
                value[row, 0, 0] = 1.01
            elif how == "direction":
                value[row, 0] *= 2
            elif how == "origin_far":
                value[row, 0] = 2e4
            if how == "no_return_int":
                del f[field]
                f.create_dataset(field, data=value.astype(np.int8))
            else:
                stored[...] = value
    expect = "invalid"
    if how in ("nan_range", "negative_range", "far_range") and not np.any(~fields["no_return"][row]):
        expect = "either"  # every beam of that scan had no return: nothing changed
    attempt(lambda: read_run(target), [str(target)], None, expect, "Dataset")


@fuzz(40)
@given(data=st.data())
def test_dataset_writer_appends(tmp_path_factory, data):
    """Hostile appends are refused naming the field and leave the run as it was: the file
    published holds exactly the scans that were accepted."""
    target = tmp_path_factory.mktemp("writer") / "run.h5"
    rng = np.random.default_rng(1)
    accepted = []
    last_time = -1.0
    with DatasetWriter(target, BEAMS, METADATA) as writer:
        for _ in range(data.draw(st.integers(1, 4))):
            fields = run_fields(rng, data.draw(st.integers(0, 5)), first_time=last_time + 1.0)
            how = data.draw(
                st.sampled_from(
                    ["valid"] * 3 + ["missing", "extra", "junk", "nan_time", "back_in_time", "beams", "pose", "range"]
                )
            )
            if how == "missing":
                del fields["ranges"]
            elif how == "extra":
                fields["depth"] = np.zeros(len(fields["time_s"]))
            elif how == "junk":  # (None, and scalar times: test_missing_fields_are_refused_naming_them)
                name = data.draw(st.sampled_from(list(fields)))
                fields[name] = data.draw(
                    st.sampled_from(
                        [
                            j
                            for j in JUNK
                            if j is not None
                            and not isinstance(j, (list, tuple))
                            and (name != "time_s" or isinstance(j, (str, bytes)))
                        ]
                    )
                )
            elif how == "nan_time" and len(fields["time_s"]):  # (all fields are arrays here)
                fields["time_s"][0] = np.nan
            elif how == "back_in_time" and len(fields["time_s"]):
                fields["time_s"] = fields["time_s"] - 1e3
            elif how == "beams":
                fields["ranges"] = np.zeros((len(fields["time_s"]), BEAMS + 1), np.float32)
            elif how == "pose" and len(fields["time_s"]):
                fields["pose_nav"][0, :3, :3] *= 2
            elif how == "range" and len(fields["time_s"]):
                fields["ranges"][0] = 2e4
                fields["no_return"][0] = False
            count = len(fields["time_s"]) if isinstance(fields["time_s"], np.ndarray) else 0
            changed = how != "valid" and (count or how in ("missing", "extra", "junk", "beams"))
            if how == "back_in_time" and last_time < 0:
                changed = False  # nothing before them: any finite increasing times will do
            result = attempt(
                lambda: writer.append(**fields),
                ["scans for", "fields", "time_s", "ranges", "no_return", "pose", "sonar", str(target)],
                None,
                "invalid" if changed else "either",
                "DatasetWriter.append",
            )
            if result is not REFUSED:
                accepted.append(fields)
                if count:
                    last_time = float(fields["time_s"][-1])
    total = sum(len(f["time_s"]) for f in accepted)
    with Dataset(target) as ds:
        assert len(ds) == total
        if total:
            batch = next(ds.batches(10**6))
            expected = np.concatenate([f["time_s"] for f in accepted])
            assert np.array_equal(batch.time_s, expected)


# ------------------------------------------------------------------------------ settings (TOML)


def settings_tables(job: JobConfig | None = None) -> dict:
    """TOML table name -> the Config it sets, as README documents the settings file."""
    job = job or JobConfig()
    p = job.pipeline
    return {
        "map": p.map,
        "nav_noise": p.nav_noise,
        "pipeline": p,
        "loop_closure": p.loop_closure,
        "loop_closure.icp": p.loop_closure.icp,
        "loop_closure.correlative": p.loop_closure.correlative,
        "timing": p.timing,
        "report": job.report,
    }


def plain_fields(config) -> dict:
    import dataclasses

    return {
        f.name: getattr(config, f.name)
        for f in dataclasses.fields(config)
        if not dataclasses.is_dataclass(getattr(config, f.name))
    }


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    return str(value)


HUGE_VALUES = [1e308, -1e308, math.inf, math.nan, 9223372036854775807, -9223372036854775808, 10**15, 5e-324]


@fuzz(150)
@given(data=st.data())
def test_settings_documents(tmp_path_factory, data):
    """Settings files with valid values, wrong types, unknown keys and tables, and huge values:
    either every value given is what the loaded settings hold, or a ValueError names the table
    and key (or the file, for TOML that does not parse)."""
    tables = settings_tables()
    document, expected, wrong = {}, {}, []
    for table in data.draw(
        st.lists(st.sampled_from(list(tables) + ["maps", "loop_closure.icpp"]), min_size=1, max_size=3, unique=True)
    ):
        if table not in tables:
            document[table] = {"x": 1}
            wrong.append(table)
            continue
        fields = plain_fields(tables[table])
        document[table] = {}
        for key in data.draw(st.lists(st.sampled_from(list(fields) + ["unknown_key"]), max_size=3, unique=True)):
            default = fields.get(key)
            kind = data.draw(st.sampled_from(["default", "default", "type", "huge", "scaled", "array", "table"]))
            if key == "unknown_key":
                value, bad = 1, True
            elif kind == "default":
                value, bad = default, False
                if value is None:
                    value = "covariance"
            elif kind == "type":
                value = {bool: "yes", int: 2.5, float: "0.1", str: 3}.get(type(default), True)
                bad = True
            elif kind == "huge":
                value, bad = data.draw(st.sampled_from(HUGE_VALUES)), None
            elif kind == "scaled" and isinstance(default, (int, float)) and not isinstance(default, bool):
                value, bad = type(default)(default * data.draw(st.sampled_from([0, 2, -1, 1000]))), None
            elif kind == "array":
                value, bad = [default] if default is not None else [1], True
            else:
                value, bad = {"value": 1}, True
            document[table][key] = value
            if bad:
                wrong.append(f"{table}.{key}")
            elif bad is None:
                wrong.append(None)  # may or may not be accepted
            expected[(table, key)] = value
    text = (
        "\n".join(
            f"[{table}]\n" + "\n".join(f"{k} = {toml_value(v)}" for k, v in values.items())
            for table, values in document.items()
        )
        + "\n"
    )
    path = tmp_path_factory.mktemp("settings") / "settings.toml"
    path.write_text(text)
    names = [w for w in wrong if w] + [t for t in document] + ["map.", "pipeline", "loop_closure", "timing"]
    definite = [w for w in wrong if w]
    config = attempt(
        lambda: JobConfig.from_toml(path),
        names,
        None,
        "invalid" if definite else ("valid" if not wrong else "either"),
        "JobConfig.from_toml",
    )
    if config is REFUSED:
        return
    loaded = settings_tables(config)
    for (table, key), value in expected.items():
        held = getattr(loaded[table], key)
        if value == "covariance" and key == "scans_per_submap":
            assert held is None
        elif isinstance(value, float) and math.isnan(value):
            raise AssertionError(f"{table}.{key} = nan accepted")
        elif isinstance(held, float) and not isinstance(value, bool):
            assert held == float(value), (table, key, held, value)
        else:
            assert held == value and type(held) is type(value), (table, key, held, value)
    assert config == JobConfig.from_document(tomllib.loads(text))


def test_settings_files_that_are_no_toml(tmp_path):
    """Binary junk, a folder, a missing file: a ValueError naming the file."""
    cases = {
        "binary.toml": b"\xff\xfe\x00[map]",
        "bad.toml": b"[map\nvoxel_size = 0.1",
        "dup.toml": b"[map]\nvoxel_size = 0.1\nvoxel_size = 0.2\n",
    }  # (deep nesting: test_deeply_nested_settings_...)
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
        refuses(lambda: JobConfig.from_toml(tmp_path / name), name)
    refuses(lambda: JobConfig.from_toml(tmp_path), str(tmp_path))
    refuses(lambda: JobConfig.from_toml(tmp_path / "missing.toml"), "missing.toml")


# ------------------------------------------------------------------------------ findings, fixed (regression tests)


def flip_in_header(data: bytes, old: bytes, new: bytes) -> bytes:
    """`data` with the first `old` inside the JSON header replaced by `new` (same length)."""
    end = header_end(data)
    at = data.index(old, PREFIX.size, end)
    return data[:at] + new + data[at + len(old) :]


@pytest.mark.parametrize(
    "kind, old, new",
    [
        ("VoxelMap", b'"voxel_size": 0.25', b'"voxel_size": 4.25'),
        ("GlobalMap", b'"prob_hit": 0.75', b'"prob_hit": 0.71'),
        ("ConfidenceMap", b'"range_sigma_m": 0.1', b'"range_sigma_m": 0.3'),
    ],
)
def test_map_header_damage_is_detected(map_files, tmp_path, kind, old, new):
    path, original, m = map_files[kind]
    target = tmp_path / "map.vog"
    target.write_bytes(flip_in_header(original, old, new))
    try:
        loaded = CLASSES[kind].load(target)
    except ValueError as error:
        assert str(target) in str(error)
        return
    assert loaded.config == m.config, f"loaded with {loaded.config}"


def test_map_header_without_metadata_is_refused(map_files, tmp_path):
    path, original, _ = map_files["VoxelMap"]
    target = tmp_path / "map.vog"
    target.write_bytes(flip_in_header(original, b'"metadata"', b'"metadatA"'))
    try:
        refuses(lambda: vj.VoxelMap.load(target), str(target))
    except KeyError as error:
        raise AssertionError(f"KeyError {error}") from None


def crafted(map_files, tmp_path, kind, change):
    path, _, _ = map_files[kind]
    metadata, arrays = read_map_file(path, kind)
    metadata = json.loads(json.dumps(metadata))
    arrays = {k: v.copy() for k, v in arrays.items()}
    change(metadata, arrays)
    target = tmp_path / "crafted.vog"
    write_map_file(target, kind, metadata, arrays)
    return target


def non_rigid(metadata, arrays):
    metadata["applied"]["0"]["pose"][0][0] = 2.0


CRAFTED = {
    "voxelmap-key-minus-1": ("VoxelMap", lambda m, a: a["block_keys"].__setitem__(0, -1)),
    "voxelmap-key-minus-2": ("VoxelMap", lambda m, a: a["block_keys"].__setitem__(0, -2)),
    "voxelmap-key-unpacked": ("VoxelMap", lambda m, a: a["block_keys"].__setitem__(0, -5)),
    "voxelmap-log-odds-inf": ("VoxelMap", lambda m, a: a["log_odds"].__setitem__((0, 0), np.inf)),
    "voxelmap-log-odds-beyond-clamp": ("VoxelMap", lambda m, a: a["log_odds"].__setitem__((0, 0), 100.0)),
    "globalmap-key-minus-1": ("GlobalMap", lambda m, a: a["block_keys"].__setitem__(0, -1)),
    "globalmap-non-rigid-pose": ("GlobalMap", non_rigid),
    "globalmap-pose-3x3": ("GlobalMap", lambda m, a: m["applied"]["0"].__setitem__("pose", np.eye(3).tolist())),
    "globalmap-negative-counts": ("GlobalMap", lambda m, a: a["count"].__setitem__(a["count"] > 0, -1)),
    "globalmap-sums-without-counts": ("GlobalMap", lambda m, a: a["sum"].__setitem__(a["count"] == 0, 5)),
    "globalmap-applied-id-negative": ("GlobalMap", lambda m, a: m["applied"].__setitem__("-1", m["applied"]["0"])),
    "globalmap-volume-negative": ("GlobalMap", lambda m, a: m["applied"]["0"].__setitem__("volume", -1.0)),
    "globalmap-applied-list": ("GlobalMap", lambda m, a: m.__setitem__("applied", [])),
}


@pytest.mark.parametrize("case", list(CRAFTED))
def test_crafted_contents_are_refused(map_files, tmp_path, case):
    kind, change = CRAFTED[case]
    target = crafted(map_files, tmp_path, kind, change)
    try:
        refuses(lambda: CLASSES[kind].load(target), str(target))
    except (AttributeError, IndexError, TypeError) as error:
        raise AssertionError(f"{type(error).__name__}: {error}") from None


def chunk_key(path, field: str, chunk: int) -> tuple[int, int]:
    """(position, size) in the file of the B-tree key of a chunk: size, filter mask, offsets."""
    with h5py.File(path, "r") as f:
        info = f[field].id.get_chunk_info(chunk)
        rank = f[field].ndim
    key = (
        struct.pack("<II", info.size, info.filter_mask)
        + struct.pack(f"<{rank + 1}Q", *info.chunk_offset, 0)
        + struct.pack("<Q", info.byte_offset)
    )
    data = path.read_bytes()
    assert data.count(key) == 1
    return data.index(key), len(key)


def test_damaged_run_index_is_detected(run_file, tmp_path):
    field = "sonar_origin"
    path, original, fields = run_file
    at, _ = chunk_key(path, field, 1)
    damaged = bytearray(original)
    damaged[at + 8 + 1] ^= 1 << 3  # the second byte of the chunk's first offset: 256 -> 2304
    target = tmp_path / "run.h5"
    target.write_bytes(bytes(damaged))
    try:
        result = read_run(target)
    except ValueError as error:
        assert str(target) in str(error)
        return
    assert same(result[2][field], fields[field]), f"{field} read back changed, silently"


def test_damaged_run_metadata_is_detected(run_file, tmp_path):
    path, original, _ = run_file
    at = original.index(b'"scene": "boxes"')
    damaged = bytearray(original)
    damaged[at + len(b'"scene": "bo')] ^= 1 << 4  # "boxes" -> "bohes"
    target = tmp_path / "run.h5"
    target.write_bytes(bytes(damaged))
    try:
        metadata, _, _ = read_run(target)
    except ValueError as error:
        assert str(target) in str(error)
        return
    assert metadata == METADATA, f"metadata read back as {metadata}"


@pytest.mark.parametrize(
    "name, value", [("format", np.array([1, 2])), ("has_truth", np.array([True, False])), ("format_version", "abc")]
)
def test_attributes_of_the_wrong_kind_are_refused_naming_the_file(run_file, tmp_path, name, value):
    path, original, _ = run_file
    target = tmp_path / "run.h5"
    target.write_bytes(original)
    with h5py.File(target, "r+") as f:
        f.attrs[name] = value
    refuses(lambda: read_run(target), str(target))


def test_deeply_nested_settings_are_refused_naming_the_file(tmp_path):
    path = tmp_path / "deep.toml"
    path.write_text("a = " + "[" * 10_000 + "]" * 10_000 + "\n")
    try:
        refuses(lambda: JobConfig.from_toml(path), "deep.toml")
    except RecursionError as error:
        raise AssertionError(f"RecursionError: {error}") from None


@pytest.mark.parametrize(
    "name, value",
    [
        ("pose_nav", None),
        ("pose_truth", None),
        ("ranges", None),
        ("time_s", None),
        ("time_s", True),
        ("time_s", 5.0),
        ("sonar_directions", None),
    ],
)
def test_missing_fields_are_refused_naming_them(tmp_path, name, value):
    fields = run_fields(np.random.default_rng(0), 3)
    fields[name] = value
    with DatasetWriter(tmp_path / "run.h5", BEAMS, METADATA) as writer:
        try:
            refuses(lambda: writer.append(**fields), name)
        except (IndexError, TypeError) as error:
            raise AssertionError(f"{type(error).__name__}: {error}") from None
