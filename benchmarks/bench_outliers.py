"""Wrong loop closures injected into a run: how far they bend the Gaussian pose graph and the
screened, robust one (`PoseGraphConfig`). The same simulated run is mapped clean and with a
share (5%, 10%, 20%) of the detector's accepted closures made wrong, each moved 1-3 m in a
random x-y direction and turned 5-20 degrees in yaw before the pose graph sees it; per back
end, the optimised base-pose error (as it stands and registered by the x-y-yaw fit) and the
registered online AUC against the clean run of the same back end. Writes outliers_cpu.json.

    python benchmarks/bench_outliers.py --out benchmarks/results [--run RUN.h5] [--seeds 0 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from vogjax import scenes
from vogjax.config import PipelineConfig
from vogjax.config.pipeline import TimingConfig
from vogjax.config.slam import PoseGraphConfig
from vogjax.geometry import exp_se3
from vogjax.io.dataset import Dataset
from vogjax.pipeline import Mapper
from vogjax.report.evaluate import evaluate_run

BACK_ENDS = {
    "gaussian": PoseGraphConfig(screen="none", robust_loss="none"),
    "robust": PoseGraphConfig(),
}


def wrong_closure(T_i_k: np.ndarray, rng) -> np.ndarray:
    """T_i_k moved 1-3 m in a random x-y direction and turned 5-20 degrees about z (in frame k)."""
    angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(1.0, 3.0)
    yaw = np.radians(rng.uniform(5.0, 20.0)) * rng.choice([-1.0, 1.0])
    offset = exp_se3(np.array([0.0, 0.0, yaw, 0.0, 0.0, 0.0]))
    offset[:2, 3] = distance * np.array([np.cos(angle), np.sin(angle)])
    return T_i_k @ offset


def map_with_outliers(run: Path, config: PipelineConfig, share: float, seed: int) -> tuple:
    """The run mapped with `share` of the accepted closures made wrong (drawn with `seed`):
    (Result, the injected (i, k) pairs, seconds)."""
    rng = np.random.default_rng(seed)
    injected = set()
    start = time.perf_counter()
    with Dataset(run) as ds:
        mapper = Mapper(config, ds.metadata)
        detect = mapper.detector.detect

        def corrupted(*args):
            accepted, rejected = detect(*args)
            out = []
            for closure in accepted:
                if rng.random() < share:
                    closure = dataclasses.replace(closure, T_i_k=wrong_closure(closure.T_i_k, rng))
                    injected.add((closure.i, closure.k))
                out.append(closure)
            return out, rejected

        mapper.detector.detect = corrupted
        for batch in ds.batches(config.batch_scans):
            mapper.add(batch)
        result = mapper.result()
    return result, injected, time.perf_counter() - start


def score(result, injected: set, scene) -> dict:
    trajectory = result.metrics["trajectory_rmse_m"]
    metrics, _ = evaluate_run(result, scene, 20_000)
    entered = {(c.i, c.k) for c in result.loop_closures}
    return {
        "accepted": len(result.loop_closures),
        "injected": len(injected),
        "injected_entered": len(injected & entered),
        "refused_inconsistent": sum(r.reason == "inconsistent" for r in result.rejected),
        "ate_m": trajectory["optimized"],
        "ate_aligned_m": trajectory["optimized_aligned"],
        "auc_aligned": metrics["auc_aligned"]["online"],
        "auc_true_pose": metrics["auc"]["true_pose"],
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    parser.add_argument("--run", type=Path, default=None, help="a simulated run (default: 3-lap propeller, seed 0)")
    parser.add_argument("--shares", type=float, nargs="+", default=[0.05, 0.1, 0.2])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="draws of the injected closures")
    parser.add_argument("--preset", default=None, help="'paper' for Sodhi et al.'s settings")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        run = args.run
        if run is None:
            from vogjax.sim import simulate_run  # MuJoCo only when simulating

            run = Path(folder) / "propeller.h5"
            simulate_run("propeller", run, laps=3, progress=False)
        with Dataset(run) as ds:
            scene = scenes.load(ds.metadata["scene"])
        base = PipelineConfig.paper() if args.preset == "paper" else PipelineConfig()
        base = base.replace(timing=TimingConfig(every_submaps=0))
        rows = {}
        for name, graph in BACK_ENDS.items():
            config = base.replace(pose_graph=graph)
            result, injected, seconds = map_with_outliers(run, config, 0.0, 0)
            clean = {**score(result, injected, scene), "seconds": seconds}
            runs = {}
            for share in args.shares:
                draws = []
                for seed in args.seeds:
                    result, injected, seconds = map_with_outliers(run, config, share, seed)
                    draws.append({**score(result, injected, scene), "seed": seed, "seconds": seconds})
                ate, ate_aligned = (float(np.mean([d[key] for d in draws])) for key in ("ate_m", "ate_aligned_m"))
                auc = float(np.mean([d["auc_aligned"] for d in draws]))
                row = runs[f"{share:g}"] = {
                    "draws": draws,
                    "ate_rise": ate / clean["ate_m"] - 1,
                    "ate_aligned_rise": ate_aligned / clean["ate_aligned_m"] - 1,
                    "auc_aligned_drop": clean["auc_aligned"] - auc,
                }
                print(
                    f"{name:8s} {share:4.0%} wrong: ATE {ate:.3f} m (clean {clean['ate_m']:.3f}, "
                    f"{row['ate_rise']:+.0%}), registered {ate_aligned:.3f} m ({row['ate_aligned_rise']:+.0%}), "
                    f"AUC registered {auc:.3f} (clean {clean['auc_aligned']:.3f}); wrong ones entered "
                    f"{sum(d['injected_entered'] for d in draws)} of {sum(d['injected'] for d in draws)}",
                    flush=True,
                )
            rows[name] = {"clean": clean, "injected": runs}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    report = {
        "machine": {"cpu": platform.machine(), "python": platform.python_version(), "commit": commit},
        "run": str(args.run) if args.run else "propeller, 3 laps, seed 0",
        "preset": args.preset or "default",
        "seeds": args.seeds,
        "back_ends": {name: dataclasses.asdict(config) for name, config in BACK_ENDS.items()},
        "results": rows,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "outliers_cpu.json"
    path.write_text(json.dumps(report, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
