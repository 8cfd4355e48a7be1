"""The report layer: measures, timing curves, figures and the `vogjax map` job. It reads a
pipeline `Result` (maps, poses, timings) and writes what people look at.

    reports = vj.report.map_runs(["run.h5"], "out")
"""

from vogjax.report.evaluate import evaluate_run
from vogjax.report.job import map_run, map_runs
from vogjax.report.metrics import Roc, misclassified, reconstruction_rmse, register_to_surface, roc
from vogjax.report.summary import summary_table

__all__ = [
    "Roc",
    "evaluate_run",
    "map_run",
    "map_runs",
    "misclassified",
    "reconstruction_rmse",
    "register_to_surface",
    "roc",
    "summary_table",
]
