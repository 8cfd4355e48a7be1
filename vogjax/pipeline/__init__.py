"""Batch reprocessing: a recorded run -> submaps -> SLAM -> the loop-closure-consistent global map.

    result = vj.pipeline.run("run.h5", vj.PipelineConfig())

`Mapper` is the same loop fed scan batch by scan batch (live, from a vehicle); `run` feeds it a
recorded run.
"""

from vogjax.config import PipelineConfig
from vogjax.pipeline.mapper import Mapper
from vogjax.pipeline.result import Result, SubmapRecord
from vogjax.pipeline.run import run
from vogjax.pipeline.warmup import warm_up

__all__ = ["Mapper", "PipelineConfig", "Result", "SubmapRecord", "run", "warm_up"]
