"""Files of an aligned flight (``evp align --out``): the geo-referenced track as TUM, CSV and
GeoJSON, and the GPS trust states."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evp.fusion.flight import FlightResult
from evp.io.trajectory import write_trajectory


def write_geo_track(result: FlightResult, out: Path) -> None:
    aligned = result.alignment.aligned
    frame = result.gps.frame
    geodetic = frame.to_geodetic(np.nan_to_num(aligned.positions))
    write_trajectory(out / "aligned_enu.tum", aligned)
    with (out / "aligned.csv").open("w") as handle:
        handle.write("timestamp,east_m,north_m,up_m,latitude_deg,longitude_deg,altitude_m\n")
        for t, enu, geo in zip(aligned.timestamps, aligned.positions, geodetic):
            handle.write(",".join(repr(float(v)) for v in (t, *enu, *geo)) + "\n")
    geojson = {
        "type": "FeatureCollection",
        "features": [
            {
                "type": "Feature",
                "properties": {"name": "visual track aligned to GPS"},
                "geometry": {"type": "LineString", "coordinates": [[g[1], g[0], g[2]] for g in geodetic]},
            },
            {
                "type": "Feature",
                "properties": {"name": "GPS fixes"},
                "geometry": {"type": "MultiPoint", "coordinates": [[g[1], g[0], g[2]] for g in frame.to_geodetic(result.gps.enu)]},
            },
        ],
    }
    (out / "aligned.geojson").write_text(json.dumps(geojson))


def write_trust_csv(trust: list[tuple[float, str]], path: Path) -> None:
    """One row per GPS fix after the alignment phase: its time and the monitor's trust state."""
    path.write_text("gps_time,trust\n" + "".join(f"{t!r},{state}\n" for t, state in trust))
