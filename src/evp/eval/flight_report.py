"""The report of ``evp align``: statistics of the horizontal errors against GPS after the
alignment phase (the whole flight and near the target altitude), the alignment chosen, the
monitor's events; with ``--out``, a folder of files and figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evp.eval.flight_plots import plot_flight_errors
from evp.eval.statistics import error_statistics
from evp.fusion.flight import NEAR_TARGET_M, FlightResult
from evp.fusion.gps_input import AlignmentError
from evp.io.flight_files import write_geo_track, write_trust_csv


def flight_summary(result: FlightResult) -> dict:
    """JSON-ready statistics, alignment, events and warnings of a flight."""
    if result.errors_m.size == 0:
        first, last = (t - result.gps.times[0] for t in result.alignment.window)
        raise AlignmentError(
            f"no GPS fix after the alignment phase ({first:.1f}..{last:.1f} s after the first fix) has a visual position to compare with: "
            "the visual track ends within it; a shorter phase leaves fixes to check (--align-fraction 0.33: the first third)"
        )
    out: dict = dict(error_statistics(result.errors_m))
    out["n_evaluated"] = int(result.errors_m.size)
    target = result.alignment.chosen["target_altitude_m"]
    near = np.abs(result.error_heights_m - target) < NEAR_TARGET_M
    out["near_target_altitude"] = error_statistics(result.errors_m[near]) if near.any() else None
    out["alignment"] = {
        "mode": result.alignment.transform.mode,
        "window_gps_s": list(result.alignment.window),
        "clock_offset_s": result.alignment.clock_offset_s,
        "pairs_used": result.alignment.pairs_used,
        "validation_rmse_m": result.alignment.validation_rmse_m,
        "scale_m_per_unit": result.alignment.transform.scale,
        **result.alignment.chosen,
    }
    out["events"] = [{"t": e.timestamp, "kind": e.kind, "message": e.message} for e in result.monitor.events]
    out["warnings"] = result.alignment.warnings
    return out


def write_flight_report(result: FlightResult, out: Path) -> dict:
    """The geo-referenced track, figures, ``metrics.json`` and ``gps_trust.csv`` in ``out``; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    summary = flight_summary(result)
    write_geo_track(result, out)
    plot_flight_errors(result, out)
    (out / "metrics.json").write_text(json.dumps(summary, indent=2))
    write_trust_csv(result.trust, out / "gps_trust.csv")
    return summary
