"""Batch reprocessing of a recorded run: every batch of scans into the mapper, in order."""

from __future__ import annotations

from os import PathLike

from tqdm import tqdm

from vogjax import devices
from vogjax.config import PipelineConfig
from vogjax.io.dataset import Dataset
from vogjax.maps import parallel
from vogjax.pipeline.mapper import Mapper
from vogjax.pipeline.result import Result


def run(dataset: str | PathLike | Dataset, config: PipelineConfig | None = None, progress: bool = True) -> Result:
    """Reprocess a run into maps; with `config.slam_thread` on (or "auto" with the maps on a CUDA
    GPU or two or more CPU cores) each submap's SLAM runs on a second thread beside the map work
    (the same results, bit for bit).

    Parameters
    ----------
    dataset : str or os.PathLike or Dataset
        The run file, or an open `vogjax.io.dataset.Dataset`.
    config : PipelineConfig or None, optional
        The pipeline's settings (default: the papers').
    progress : bool, optional
        Show a progress bar (on stderr).

    Returns
    -------
    Result
        The maps, poses, loop closures and timings.

    Raises
    ------
    ValueError
        If the run is missing, damaged or holds no scans.
    """
    config = config or PipelineConfig()
    own = not isinstance(dataset, Dataset)
    ds = Dataset(dataset) if own else dataset
    try:
        if len(ds) == 0:
            raise ValueError(f"dataset {str(ds.path)!r} holds no scans")
        mapper = Mapper(config, ds.metadata, overlap=_overlap(config))
        try:
            with tqdm(total=len(ds), unit="scan", desc="mapping", disable=not progress) as bar:
                for batch in ds.batches(config.batch_scans):
                    mapper.add(batch)
                    bar.update(len(batch))
            result = mapper.result()
        except BaseException:
            mapper.abandon()  # an error or an interrupt: no SLAM step left to wait for
            raise
        mapper.close()
        return result
    finally:
        if own:
            ds.close()


def _overlap(config: PipelineConfig) -> bool:
    """Whether SLAM gets its own thread: `slam_thread` "on", or "auto" where a second core can
    take it (the maps on CUDA, whose kernels need no CPU core, or a CPU of two or more cores)."""
    if config.slam_thread == "auto":
        return devices.resolve(None).is_cuda or parallel.usable_cores() >= 2
    return config.slam_thread == "on"
