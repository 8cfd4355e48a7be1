"""Injected faults (issue 17): `vogjax simulate` and `vogjax map` killed (SIGKILL) at random points.

Per command: a complete run first (the earlier output), then KILLS runs of the same command into
the same place started together and killed at seeded random points (one inside its write window,
the others anywhere), then one more run left to finish. Checked: the earlier output is intact
(byte-identical, or, if a kill came after the rename, a complete new output with the same
contents), the next run succeeds, and no temporary (`.NAME.PID.tmp`, vogjax/io/atomic.py) is
left after it. VOGJAX_FAULT_KILLS raises the number of killed runs per command (default 2),
VOGJAX_FAULT_SEED picks other kill points.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from vogjax.io import atomic

KILLS = int(os.environ.get("VOGJAX_FAULT_KILLS", "2") or 2)
SEED = int(os.environ.get("VOGJAX_FAULT_SEED", "17") or 17)
SCANS = 300
SETTINGS = "[timing]\nrays = 500\nevery_submaps = 0\n[report]\nsurface_points = 2000\n"
RUN_LIMIT_S = 300


def vogjax(*args) -> list:
    return [sys.executable, "-m", "vogjax.cli", *map(str, args)]


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    """The environment of every run: the Warp kernel cache (conftest) and a JAX compilation cache
    shared by the runs of this module, so only the first one compiles MJX."""
    environment = dict(os.environ)
    environment["JAX_COMPILATION_CACHE_DIR"] = str(tmp_path_factory.mktemp("jax_cache"))
    environment["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    environment["JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES"] = "0"
    return environment


def leftovers(folder: Path, name: str) -> list[str]:
    """Temporaries of target `name` in `folder` (vogjax.io.atomic's naming)."""
    pattern = re.compile(rf"^\.{re.escape(name)}\.\d+(\.old)?\.tmp$")
    return sorted(p.name for p in folder.iterdir() if pattern.match(p.name))


class Watched:
    """A run of the command, polled every 2 ms for its temporary; killed with SIGKILL on request."""

    def __init__(self, argv, env, folder: Path, name: str):
        self.folder, self.name = folder, name
        self.start = time.perf_counter()
        self.process = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        self.temporary_at = None  # seconds after start when its temporary appeared
        self.published_at = None  # ... and when it was gone again (renamed to the target)
        self.finished_at = None
        self._done = threading.Event()
        self._poller = threading.Thread(target=self._poll, daemon=True)
        self._poller.start()

    def _poll(self):
        pattern = re.compile(rf"^\.{re.escape(self.name)}\.{self.process.pid}\.tmp$")
        while self.process.poll() is None and not self._done.is_set():
            present = any(pattern.match(n) for n in os.listdir(self.folder))
            if self.temporary_at is None and present:
                self.temporary_at = time.perf_counter() - self.start
            elif self.temporary_at is not None and self.published_at is None and not present:
                self.published_at = time.perf_counter() - self.start
            time.sleep(0.002)
        self.finished_at = time.perf_counter() - self.start

    def kill_at(self, seconds: float = None, after_temporary: float = None) -> bool:
        """Kill at `seconds` after start, or `after_temporary` seconds after the temporary
        appeared; True if it was killed, False if it had finished first."""
        while self.process.poll() is None:
            now = time.perf_counter() - self.start
            if (seconds is not None and now >= seconds) or (
                after_temporary is not None
                and self.temporary_at is not None
                and now >= self.temporary_at + after_temporary
            ):
                os.kill(self.process.pid, signal.SIGKILL)
                break
            if now > RUN_LIMIT_S:
                raise AssertionError("a run went on for too long")
            time.sleep(0.001)
        self.process.wait()
        self._done.set()
        self._poller.join()
        return self.process.returncode == -signal.SIGKILL

    def finish(self) -> tuple[int, str]:
        _, err = self.process.communicate(timeout=RUN_LIMIT_S)
        self._done.set()
        self._poller.join()
        return self.process.returncode, err.decode(errors="replace")


def complete_run(argv, env, folder, name) -> Watched:
    run = Watched(argv, env, folder, name)
    code, err = run.finish()
    assert code == 0, f"{' '.join(map(str, argv))} failed:\n{err[-2000:]}"
    return run


def write_window(run: Watched) -> float:
    """Seconds its temporary existed (from creation to the rename)."""
    end = run.published_at or run.finished_at
    return max(end - (run.temporary_at or end), 0.05)


def killed_runs(argv, env, folder, name, reference: Watched, rng) -> list[dict]:
    """KILLS runs started together, each killed at a seeded point: the first inside its write
    window (early in it: in runs started together the window shrinks to about half the earlier
    run's), the others at a random time."""
    window = write_window(reference)
    plans = [{"after_temporary": float(rng.uniform(0.0, 0.3) * window)}] + [
        {"seconds": float(rng.uniform(0.15, 1.1) * reference.finished_at)} for _ in range(KILLS - 1)
    ]
    runs = [Watched(argv, env, folder, name) for _ in plans]
    outcomes = [None] * len(runs)

    def kill(k):
        outcomes[k] = runs[k].kill_at(**plans[k])

    threads = [threading.Thread(target=kill, args=(k,)) for k in range(len(runs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return [
        {**plan, "killed": killed, "temporary_at": run.temporary_at, "published_at": run.published_at}
        for plan, killed, run in zip(plans, outcomes, runs)
    ]


def record(name: str, facts: dict) -> None:
    """Kill points and outcomes, for the reliability note (printed with -s)."""
    print(f"\n[faults] {name}: {json.dumps(facts)}")


# ------------------------------------------------------------------------------ vogjax simulate


def run_contents(path: Path) -> dict:
    from vogjax.io.dataset import Dataset

    with Dataset(path) as run:
        run.validate()
        batch = next(run.batches(10**6))
        return {
            "metadata": run.metadata,
            **{k: getattr(batch, k) for k in ("time_s", "pose_nav", "pose_truth", "ranges", "no_return")},
        }


def same_contents(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k], equal_nan=True) if isinstance(a[k], np.ndarray) else a[k] == b[k] for k in a
    )


@pytest.fixture(scope="module")
def simulated(tmp_path_factory, env):
    """The earlier output of `vogjax simulate` (also the run the map test maps), and its run."""
    folder = tmp_path_factory.mktemp("simulate")
    out = folder / "run.h5"
    argv = vogjax("simulate", "--scene", "boxes", "--scans", SCANS, "--out", out, "--overwrite")
    return folder, out, argv, complete_run(argv, env, folder, out.name)


def test_killed_simulations_leave_the_earlier_run_and_nothing_stale(simulated, env):
    rng = np.random.default_rng(SEED)
    folder, out, argv, earlier = simulated
    earlier_bytes, earlier_contents = out.read_bytes(), run_contents(out)
    kills = killed_runs(argv, env, folder, out.name, earlier, rng)
    assert any(k["killed"] for k in kills), "every run finished before its kill point"
    # the earlier run is intact: the same bytes, or (killed after its rename) a whole new run
    if out.read_bytes() != earlier_bytes:
        assert same_contents(run_contents(out), earlier_contents), "the run file was left damaged"
    stale = leftovers(folder, out.name)
    complete_run(argv, env, folder, out.name)
    assert same_contents(run_contents(out), earlier_contents)
    assert leftovers(folder, out.name) == [], "temporaries of killed runs survived the next run"
    record(
        "simulate",
        {
            "earlier_s": round(earlier.finished_at, 2),
            "write_window_s": round(write_window(earlier), 3),
            "kills": kills,
            "stale_before_next_run": len(stale),
            "stale_after": 0,
        },
    )


# ------------------------------------------------------------------------------ vogjax map


def folder_bytes(folder: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def complete_map_folder(folder: Path, names: set) -> None:
    import vogjax as vj

    assert {p.name for p in folder.iterdir()} == names, "a results folder with missing or extra files"
    assert json.loads((folder / "report.json").read_text())["submaps"] >= 1
    assert vj.GlobalMap.load(folder / "global_map.vog").applied_ids


def test_killed_map_jobs_leave_the_earlier_results_and_nothing_stale(tmp_path, env, simulated):
    rng = np.random.default_rng(SEED + 1)
    shutil.copy(simulated[1], tmp_path / "run.h5")
    (tmp_path / "settings.toml").write_text(SETTINGS)
    maps = tmp_path / "maps"
    maps.mkdir()
    argv = vogjax(
        "map", tmp_path / "run.h5", "--out", maps, "--config", tmp_path / "settings.toml", "--quiet", "--overwrite"
    )
    earlier = complete_run(argv, env, maps, "run")
    results = maps / "run"
    earlier_files = folder_bytes(results)
    kills = killed_runs(argv, env, maps, "run", earlier, rng)
    assert any(k["killed"] for k in kills), "every run finished before its kill point"
    # the earlier results are intact: the same bytes, or (killed after the rename) whole new ones
    assert results.is_dir(), "the results folder is gone"
    if folder_bytes(results) != earlier_files:
        complete_map_folder(results, set(earlier_files))
    stale = leftovers(maps, "run")
    complete_run(argv, env, maps, "run")
    complete_map_folder(results, set(earlier_files))
    assert leftovers(maps, "run") == [], "temporaries of killed runs survived the next run"
    assert [p.name for p in maps.iterdir()] == ["run"]
    record(
        "map",
        {
            "earlier_s": round(earlier.finished_at, 2),
            "write_window_s": round(write_window(earlier), 3),
            "kills": kills,
            "stale_before_next_run": len(stale),
            "stale_after": 0,
        },
    )


# ------------------------------------------------------------------------------ publishing a folder over one

KILLED_AFTER_THE_SWAP = """
import os, signal, sys
from pathlib import Path
from vogjax.io import atomic

def killed(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)  # the folders swapped, the old one not yet removed
atomic.shutil.rmtree = killed
with atomic.AtomicPath(Path(sys.argv[1]), folder=True) as temporary:
    (temporary / "file.txt").write_text("new")
"""

KILLED_BETWEEN_RENAMES = """
import os, signal, sys
from pathlib import Path
from vogjax.io import atomic

real = os.replace
def replace(source, target):
    real(source, target)
    os.kill(os.getpid(), signal.SIGKILL)  # right after the first rename: the old folder moved aside
atomic._exchange = lambda a, b: False  # a system without renameat2's exchange
atomic.os.replace = replace
with atomic.AtomicPath(Path(sys.argv[1]), folder=True) as temporary:
    (temporary / "file.txt").write_text("new")
"""


def killed_publish(tmp_path, script: str) -> Path:
    target = tmp_path / "results"
    target.mkdir()
    (target / "file.txt").write_text("old")
    process = subprocess.run([sys.executable, "-c", script, str(target)], capture_output=True)
    assert process.returncode == -signal.SIGKILL, process.stderr.decode()
    return target


@pytest.mark.skipif(atomic._RENAMEAT2 is None, reason="no renameat2 on this system")
def test_a_kill_after_the_swap_of_a_folder_keeps_the_new_folder(tmp_path):
    target = killed_publish(tmp_path, KILLED_AFTER_THE_SWAP)
    assert (target / "file.txt").read_text() == "new"
    atomic.remove_stale(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_a_kill_between_the_renames_of_a_folder_is_repaired_by_the_next_write(tmp_path):
    target = killed_publish(tmp_path, KILLED_BETWEEN_RENAMES)
    assert not target.exists()  # the window the exchange closes where the system has it
    atomic.remove_stale(target)
    assert (target / "file.txt").read_text() == "new"  # the new folder was complete: published
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_a_kill_before_the_new_folder_is_complete_keeps_the_old_one(tmp_path):
    target = tmp_path / "results"
    target.mkdir()
    (target / "file.txt").write_text("old")
    script = KILLED_BETWEEN_RENAMES.replace(
        '(temporary / "file.txt").write_text("new")',
        '(temporary / "file.txt").write_text("new"); os.kill(os.getpid(), 9)',
    )
    process = subprocess.run([sys.executable, "-c", script, str(target)], capture_output=True)
    assert process.returncode == -signal.SIGKILL
    atomic.remove_stale(target)
    assert (target / "file.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_leftovers_of_an_earlier_process_with_this_pid_are_repaired(tmp_path):
    """In containers a run often gets the pid of the killed one: its leftovers must still be
    repaired, not taken for this process's own temporary and deleted."""
    target = tmp_path / "results"
    pid = os.getpid()
    new, old = tmp_path / f".results.{pid}.tmp", tmp_path / f".results.{pid}.old.tmp"
    new.mkdir()
    (new / "file.txt").write_text("new")
    old.mkdir()
    (old / "file.txt").write_text("old")
    publication = atomic.AtomicPath(target, folder=True)
    publication.abort()  # this write fails: the repaired folder stays
    assert (target / "file.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]
