"""`vogjax demo`: simulate a propeller survey with drifting navigation, map it with loop
closures, and print what the pipeline achieved against ground truth."""

from __future__ import annotations

from pathlib import Path

from vogjax import report as reporting
from vogjax import scenes
from vogjax.config import SonarConfig
from vogjax.io.atomic import check_writable
from vogjax.sim import simulate_run
from vogjax.sim.mission import MAX_LAPS


def run(out: Path, scene: str = "propeller", laps: int = 2, progress: bool = True) -> dict:
    out = Path(out)
    if scene not in scenes.NAMES:
        raise ValueError(f"scene must be one of {', '.join(scenes.NAMES)}, got {scene!r}")
    if isinstance(laps, bool) or not isinstance(laps, int) or not 1 <= laps <= MAX_LAPS:
        raise ValueError(f"laps must be an integer in [1, {MAX_LAPS}], got {laps!r}")
    run_path = out / f"{scene}.h5"
    # every output up front, before the survey is flown: the folder, its run file and the
    # report folder DIR/<scene> (all three replaced if they are there, but of the right kind)
    check_writable(out, folder=True)
    check_writable(run_path)
    check_writable(out / run_path.stem, folder=True)
    out.mkdir(parents=True, exist_ok=True)
    # 1. simulate the survey: MJX vehicle, sonar with 2 cm range noise, drifting navigation
    summary = simulate_run(
        scene, run_path, laps=laps, sensor=SonarConfig(range_noise_m=0.02), overwrite=True, progress=progress
    )
    print(f"simulated {summary.scans} scans ({summary.duration_s:.0f} s of survey) of the {scene} scene")
    # 2. map it: submaps, loop closures, iSAM2, the online global map; evaluate and draw
    report = reporting.map_runs([run_path], out, progress=progress, overwrite=True)[0]  # the demo's own
    # 3. summarise
    print()
    print(reporting.summary_table([report]))
    print(f"\nfigures, map and report.json in {out / run_path.stem}")
    return report
