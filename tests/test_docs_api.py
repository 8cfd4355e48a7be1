"""The README's Python examples run as written, and the names it promises exist."""

import functools
import importlib
import pkgutil
import re
from pathlib import Path

import numpy as np
import pytest

import vogjax as vj

README = Path(__file__).resolve().parent.parent / "README.md"


def python_block(after: str) -> str:
    """The first ```python block of the README after the line `after`."""
    text = README.read_text()
    start = text.index(after)
    match = re.search(r"```python\n(.*?)```", text[start:], re.S)
    return match.group(1)


def test_subpackages_resolve_on_first_use():
    assert vj.planner.NbvPlanner is importlib.import_module("vogjax.planner").NbvPlanner
    assert vj.kernels is importlib.import_module("vogjax.kernels")
    for name in vj._SUBPACKAGES:
        assert getattr(vj, name).__name__ == f"vogjax.{name}"
    with pytest.raises(AttributeError):
        _ = vj.no_such_thing


def test_kernels_all_names_every_module():
    import vogjax.kernels as kernels

    modules = sorted(info.name for info in pkgutil.iter_modules(kernels.__path__))
    assert sorted(kernels.__all__) == modules
    for name in kernels.__all__:
        assert getattr(kernels, name).__name__ == f"vogjax.kernels.{name}"
    with pytest.raises(AttributeError):
        _ = kernels.no_such_module


def test_quickstart_runs_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # it saves map.vog in the working folder
    exec(compile(python_block("## Quickstart"), "README Quickstart", "exec"), {})
    assert vj.VoxelMap.load(tmp_path / "map.vog").voxels()[0].shape[0] > 0


def test_quickstart_config_comment():
    block = python_block("## Quickstart")
    assert "import warp as wp" in block
    cfg, paper = vj.MapConfig(), vj.MapConfig.paper()
    assert (cfg.clamp_min, cfg.clamp_max) == (0.1192, 0.971) and (paper.clamp_min, paper.clamp_max) == (0.0, 1.0)
    assert "0.1192/0.971" in block and "MapConfig.paper(): no clamping" in block


def test_global_map_example_runs_in_order():
    """`add`, then `merge` (the full merge rebuilds), then `update_poses`, as the README shows."""
    block = python_block("## Submaps, the virtual map and the global map")
    assert block.index("g.add(vog, [i], marginals)") < block.index("g.merge(vog, marginals)")
    cfg = vj.MapConfig(voxel_size=0.1, max_range=11.0)
    vog = vj.VogMap(cfg, device="cpu")
    i = vog.add_submap(np.eye(4))
    rng = np.random.default_rng(0)
    vog.submap(i).integrate_scans(np.zeros((2, 3)), rng.normal(size=(64, 3)) * 2, np.repeat(np.arange(2), 32))
    marginals = np.eye(6)[None]  # (N,6,6), GTSAM order
    g = vj.GlobalMap(cfg, device="cpu")
    g.add(vog, [i], marginals)
    g.merge(vog, marginals)
    T_new = np.eye(4)
    T_new[0, 3] = 0.5
    vog.set_poses([i], T_new[None])
    report = g.update_poses(vog, marginals, eps_move_m=0.05)  # as written ("auto" eps_cov: this one is the largest)
    assert report.seconds >= 0
    report = g.update_poses(vog, marginals, eps_move_m=0.05, eps_cov=0.0)
    assert list(report.reapplied) == [i]
    fresh = vj.GlobalMap(cfg, device="cpu")
    fresh.merge(vog, marginals)
    for a, b in zip(g.voxels(), fresh.voxels()):
        np.testing.assert_array_equal(a, b)


def test_planner_examples_take_the_shapes_they_show():
    from vogjax import planner, scenes
    from vogjax.maps.confidence_cost import edge_risk
    from vogjax.sensors import ProfilingSonar

    block = python_block("### The planner (`vogjax.planner`)")
    assert "starts[:, :3], ends[:, :3]" in block
    m = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=6.0), device="cpu")
    m.integrate_scan(np.zeros(3), np.random.default_rng(0).normal(size=(64, 3)) * 2)
    sonar = ProfilingSonar()
    starts = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])  # x, y, z, yaw
    ends = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 1.5]])
    p = np.zeros(3)
    e = planner.edge_gain(m, starts, ends, sonar, step_m=0.1, max_range_m=5.0)
    assert len(e.unknown) == 2
    ok = planner.edges_clear(m, starts[:, :3], ends[:, :3], box_m=(1, 1, 0.5), vehicle=p, clearance_m=1.5)
    assert ok.shape == (2,)
    # the risk hook as the confidence-rich map section writes it
    scene = scenes.load("boxes")
    crm = vj.ConfidenceMap(vj.CrmConfig(voxel_size=0.2, max_range=6.0, range_sigma_m=0.05), device="cpu")
    nbv = planner.NbvPlanner(
        planner.PlannerConfig(risk_weight=1.0),
        bounds=scene.bounds,
        sensor=sonar,
        region=scene.region(),
        risk=functools.partial(edge_risk, crm),
    )
    assert nbv.risk(starts[:, :3], ends[:, :3]).shape == (2,)
