"""The jobs ``evp sweep`` runs: ``evp run`` on one dataset with some settings changed."""

from __future__ import annotations

import tempfile
from pathlib import Path

from evp.config import load_settings, with_overrides
from evp.errors import DatasetError
from evp.io.registry import open_dataset
from evp.run_setup import estimate, refine_and_write, resolve_settings

# the figures of metrics.json a sweep's table keeps (the rest stays in each run's own files)
METRICS = ("frames", "tracked_frames", "tracked_fraction", "rmse", "matched_poses", "reference_path_length_m", "scale")


def run_dataset(dataset: str, overrides: dict, config: str | None = None, out: str | None = None) -> dict:
    """``evp run DATASET [--config]`` with ``overrides`` (dotted settings) on this worker; the run's
    files go to ``out`` when given (a folder the worker can write), else to a temporary folder."""

    data = open_dataset(Path(dataset))
    if data.num_frames == 0:
        raise DatasetError(Path(dataset), data.no_frames_reason())
    settings = resolve_settings(with_overrides(load_settings(config), overrides), data)
    result, navigation, estimator = estimate(data, settings)
    with tempfile.TemporaryDirectory(prefix="evp-sweep-") as scratch:
        metrics = refine_and_write(result, navigation, estimator, data, settings, Path(out) if out else Path(scratch))
    record = {name: metrics[name] for name in METRICS if name in metrics}
    navigation_metrics = metrics.get("navigation", {})
    if "ate_se3_rmse_m" in navigation_metrics:
        record["navigation_ate_se3_m"] = navigation_metrics["ate_se3_rmse_m"]
    return record
