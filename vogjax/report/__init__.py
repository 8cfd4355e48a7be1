"""The report layer: measures, timing curves, figures and the `vogjax map` job.

It reads a pipeline `Result` (maps, poses, timings) and writes what people look at. The package
exports the job (`map_runs`, `map_run`), the evaluation against ground truth (`evaluate_run`)
and the measures it uses; the rest has a module each: `vogjax.report.timing` (the timing
curves of Figs. 8 and 9), `vogjax.report.plots` (figures), `vogjax.report.viewer` (the rerun
viewer), `vogjax.report.workers` (many runs at once with Ray) and `vogjax.report.fields` (what
each field of report.json means).

Examples
--------
Map a recorded run into ``out/run/`` and read its headline figures:

    reports = vj.report.map_runs(["run.h5"], "out")
    reports[0]["auc"]
"""

from vogjax.report.evaluate import evaluate_run
from vogjax.report.job import derive_settings, map_run, map_runs
from vogjax.report.metrics import Roc, misclassified, reconstruction_rmse, register_to_surface, roc
from vogjax.report.summary import summary_table

__all__ = [
    "Roc",
    "derive_settings",
    "evaluate_run",
    "map_run",
    "map_runs",
    "misclassified",
    "reconstruction_rmse",
    "register_to_surface",
    "roc",
    "summary_table",
]
