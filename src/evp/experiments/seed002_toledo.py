"""Seed 002's method on real imagery: the Toledo survey (``../shared/data/aerial_nadir_odm_toledo_fc350``,
47 nadir photos of a DJI FC350 at ~120 m, one every ~10.5 s, each with its EXIF GPS) through
``evp align``: the nadir visual odometry, aligned to GPS on the first half of the fixes, scored
against GPS on the second half, in 3D+baro mode (the survey has no barometer: the transformed
altitude is kept, and 2D+baro, which takes its altitude from the barometer, cannot run); GPS is
consumer-grade, so the error against it is bounded below by its own metre-level noise.

The paper's flights are not this one; its offline mean errors (Table II, 0.87-3.62 m in 2D+baro,
1.03-6.70 m in 3D+baro) are the scale to read ours against. The data folder is
``$EVP_SHARED_DATA/aerial_nadir_odm_toledo_fc350`` (default: ``../shared/data`` from the working
folder); without it the job fails, and the report says so."""

from __future__ import annotations

from pathlib import Path

from evp.batch.jobs import Job, Outcome
from evp.config import Settings
from evp.eval.flight_report import flight_summary
from evp.experiments.batched import Report, Row, figure, markdown_table
from evp.experiments.shared_data import shared_data_folder
from evp.fusion.flight import process_flight
from evp.io.registry import open_dataset
from evp.pipeline import run_dataset
from evp.run_setup import camera_for, make_estimator, resolve_settings

TASK = "evp.experiments.seed002_toledo:align_survey"
FOLDER = "aerial_nadir_odm_toledo_fc350"
ALIGN_FRACTION = 0.5
PAPER_TABLE_II_MEAN_RANGE_M = {"2d+baro": (0.87, 3.62), "3d+baro": (1.03, 6.70)}


def data_folder() -> Path:
    return shared_data_folder(FOLDER)


def jobs(variant: str | None, quick: bool) -> list[Job]:
    return [Job("toledo", TASK, {"dataset": str(data_folder().resolve()), "align_fraction": ALIGN_FRACTION})]


def align_survey(dataset: str, align_fraction: float) -> dict:
    """``evp align DATASET --align-fraction F`` in both modes, on one visual track."""

    data = open_dataset(Path(dataset))
    settings = resolve_settings(Settings(), data)
    segments = run_dataset(data, make_estimator(camera_for(data, settings), settings, data)).segments()
    record: dict = {"photos": data.num_frames, "estimator": settings.estimator}
    for mode in ("2d+baro", "3d+baro"):
        if mode == "2d+baro" and not data.baro:
            record[mode] = {"not_run": "no barometer: 2D+baro has no altitude (3D+baro keeps the transformed one)"}
            continue
        align = settings.align.model_copy(update={"mode": mode})
        summary = flight_summary(process_flight(data.gps, data.baro, segments, align, settings.gps_monitor, align_fraction))
        record[mode] = {k: summary[k] for k in ("mean", "max", "q1", "q3", "iqr", "std", "rmse", "n_evaluated")} | {"warnings": summary["warnings"]}
    return record


def report(variant: str | None, outcomes: dict[str, Outcome], quick: bool, out: Path) -> Report:
    outcome = outcomes["toledo"]
    rows, lines = [], []
    if outcome.ok:
        for mode, (low, high) in PAPER_TABLE_II_MEAN_RANGE_M.items():
            r = outcome.record[mode]
            if "not_run" in r:
                lines.append([mode, f"{low:.2f}-{high:.2f}", f"not run: {r['not_run']}", *["-"] * 6])
                continue
            lines.append([mode, f"{low:.2f}-{high:.2f}", *(figure(r[k]) for k in ("mean", "max", "q1", "q3", "iqr", "std")), f"{r['n_evaluated']}"])
            rows.append(Row(mode, r, {"table2_mean_range_m": [low, high]}))
    body = [
        (__doc__ or "").split("\n\n", 1)[0].replace("\n", " "),
        "",
        *markdown_table(["mode", "paper's offline means (m)", "mean (m)", "max", "Q1", "Q3", "IQR", "std", "fixes scored"], lines),
        "",
        f"Warnings: {'; '.join(sorted({w for m in PAPER_TABLE_II_MEAN_RANGE_M for w in outcome.record[m].get('warnings', [])}))}"
        if outcome.ok
        else f"The job failed: {outcome.error}",
    ]
    return Report("Seed 002 on real data: the Toledo survey", body, rows, {"dataset": str(data_folder()), "align_fraction": ALIGN_FRACTION})
