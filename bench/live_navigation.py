"""Live navigation on the base station (issue 31): a rendered drone flight with IMU, GPS and
barometer streamed in real time to `evp serve` over loopback, GPS spoofed from mid-flight, and the
bundled sample streamed in real time.

Usage: python bench/live_navigation.py [--duration 120] [--spoof-start 60] [--dataset DIR] [--cases fused plain two sample] [--keep DIR] [--slam KEY=VALUE ...]

The issue's flight is 300 s with spoofing from 150 s (`--duration 300 --spoof-start 150`: ~1.5 min
to render at 30 fps on two free cores, then 5 min of streaming per case); the default is the 120 s
flight of docs/navigation.md with spoofing from 60 s.

Renders `evp sim drone-flight` at 30 fps, 640x380 (60 m, 6 m/s lawnmower, seed 0) with GPS pulled
off at 5 m/s from `--spoof-start` (or reads `--dataset`, a render of the same kind), then for each
case starts `evp serve` (TLS) with the flight's navigation settings (those of
bench/gps_spoofing.py) and runs `evp stream --realtime` of the flight, a phone's pace:

- `fused`: the station fuses the streamed IMU, GPS and barometer (the stream sends the camera's
  IMU extrinsic). Frames answered, frame-sent to answer-received latency p50 / p95, the age of the
  last visual correction in the answers (p50 / p95), when the answers became georeferenced, the
  spoofing alarm's delay after the spoof's start, and the horizontal error of the answered
  georeferenced positions against the truth (no alignment: ENU at the take-off point) over the
  spoofed part (from the spoof's start to the end of the cruise);
- `two`: two vehicles streaming the flight at once to one station (two sessions, two estimators
  on the same cores), the `fused` figures of the vehicle that did worse on each;
- `without fusion`: the same stream to a station with `navigation.enabled: false` (SLAM's poses
  answered at once, as before the filter); the `fused` row gives its p95 as a ratio to this one.

The sample row streams `data/sample/davis_slider_depth` (no IMU) in real time to a default station.
The station, its estimator processes and the client share the machine: latencies are those of
that machine under whatever else runs on it (the README gives the load average at the start).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the station runner the tests use
from results import Results  # noqa: E402

from evp.batch.jobs import parse_set  # noqa: E402
from evp.config import Settings, with_overrides  # noqa: E402
from evp.errors import EvpError, UsageError  # noqa: E402
from evp.experiments.seed002_flights import AERIAL_NAVIGATION, CLIMB_M_S  # noqa: E402
from evp.fusion.geodesy import EnuFrame  # noqa: E402
from evp.io.navigation_outputs import truth_in_enu  # noqa: E402
from evp.io.registry import open_dataset  # noqa: E402
from evp.station.store import SessionStore  # noqa: E402
from tests.conftest import SAMPLE  # noqa: E402
from tests.station.conftest import running_station  # noqa: E402

# bench/gps_spoofing.py's settings for this flight, and a delayed horizon that covers how late
# SLAM's pose comes live: a visual update older than the newest IMU sample by more than
# history_s is refused as too old, and the filter then runs on the IMU alone (measured on the
# loaded 2-core machine: the last visual correction 0.2-1 s old, p95).
LIVE_FLIGHT_NAVIGATION = {**AERIAL_NAVIGATION, "history_s": 2.5}

COLUMNS = [
    ("stream", "{stream}"),
    ("case", "{case}"),
    ("frames", "{frames}"),
    ("answered", "{answered_percent:.1f} %"),
    ("latency p50 / p95 ms", "{latency_ms_p50:.0f} / {latency_ms_p95:.0f}"),
    ("p95 / without fusion", "{p95_ratio:.2f}"),
    ("vision age p50 / p95 ms", "{visual_age_ms_p50:.0f} / {visual_age_ms_p95:.0f}"),
    ("georeferenced at (s)", "{georeferenced_s:.1f}"),
    ("spoofing alarm after (s)", "{alarm_delay_s:.1f}"),
    ("horizontal error, spoofed part, mean / max (m)", "{spoofed_error_mean_m:.2f} / {spoofed_error_max_m:.2f}"),
    ("load avg", "{load:.1f}"),
]


def _render(folder: Path, duration: float, spoof_start: float) -> Path:
    from evp.sim import sensors
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    gps = sensors.GpsConfig(spoof_start_s=spoof_start)
    generate("drone-flight", SimOptions(duration_s=duration, fps=30.0, seed=0, gps=gps), folder, workers=2)
    return folder


def _stream(work: Path, name: str, source: Path, settings: dict, vehicles: int = 1) -> list[tuple[dict, list[dict], list[dict]]]:
    """`evp serve` with ``settings``, ``vehicles`` runs of `evp stream --realtime` of ``source``
    at once: per vehicle, the stream's summary, every answer, and the session's events."""
    config = work / f"{name}.yaml"
    config.write_text(yaml.safe_dump(settings))
    outs = [work / f"{name}-stream{'' if vehicles == 1 else k}" for k in range(vehicles)]
    data = work / f"{name}-station"
    with running_station(data, "--config", str(config)) as station:
        command = [sys.executable, "-m", "evp.cli", "stream", str(source), "--url", station.url, "--realtime", "--quiet", "--encoding", "jpeg"]
        command += ["--cafile", str(data / "tls" / "cert.pem")]
        streams = [subprocess.Popen([*command, "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for out in outs]
        for stream in streams:
            _, stderr = stream.communicate(timeout=3600)
            if stream.returncode != 0:
                raise SystemExit(f"evp stream failed: {stderr[-2000:]}")
    runs = []
    store = SessionStore(f"sqlite:///{data / 'evp.sqlite'}")
    try:
        for out in outs:
            summary = json.loads((out / "summary.json").read_text())
            answers = [json.loads(line) for line in (out / "answers.jsonl").read_text().splitlines()]
            runs.append((summary, answers, store.rows("events", summary["session_id"])))
    finally:
        store.close()
    return runs


def _latency_figures(summary: dict, answers: list[dict]) -> dict:
    ages = np.array([a["visual_age_s"] for a in answers if a["visual_age_s"] is not None]) * 1000.0
    return {
        "frames": summary["frames_sent"],
        "answered_percent": 100.0 * summary["poses_received"] / summary["frames_sent"],
        "latency_ms_p50": summary["latency_ms_p50"],
        "latency_ms_p95": summary["latency_ms_p95"],
        "visual_age_ms_p50": float(np.percentile(ages, 50)) if len(ages) else None,
        "visual_age_ms_p95": float(np.percentile(ages, 95)) if len(ages) else None,
        "load": os.getloadavg()[0],
    }


def _worst_vehicle(figures: list[dict]) -> dict:
    """Several vehicles' figures as one row: each figure from the vehicle that did worst on it."""
    worst: dict = {}
    for key in figures[0]:
        values = [f[key] for f in figures if f.get(key) is not None]
        if values:
            worst[key] = min(values) if key == "answered_percent" else max(values)
    return worst


def _navigation_figures(dataset, answers: list[dict], events: list[dict], spoof_start: float) -> dict:
    """When the answers became georeferenced, the alarm's delay, and the horizontal error of the
    georeferenced answers against the truth over the spoofed cruise."""
    t0 = dataset.frame_times[0]
    georeferenced = [a for a in answers if a["georeferenced"]]
    figures: dict = {"georeferenced_s": georeferenced[0]["timestamp"] - t0 if georeferenced else None}
    alarms = [e for e in events if e["code"] == "spoofing_alarm"]
    if alarms:  # the event names the fix's time: "GPS at 123.456 s: ..."
        figures["alarm_delay_s"] = float(alarms[0]["text"].split(" s:")[0].split("GPS at ")[1]) - (t0 + spoof_start)
    first_fix = next(f for f in dataset.gps if np.isfinite(f.latitude_deg))
    truth = truth_in_enu(dataset, EnuFrame.at(first_fix))
    cruise_end = dataset.frame_times[-1] - 60.0 / CLIMB_M_S - 2.0  # before the landing, as bench/gps_spoofing.py
    inside = [a for a in georeferenced if t0 + spoof_start <= a["timestamp"] <= cruise_end]
    if inside:
        times = np.array([a["timestamp"] for a in inside])
        estimated = np.array([a["t"][:2] for a in inside])
        expected = np.column_stack([np.interp(times, truth.timestamps, truth.positions[:, k]) for k in range(2)])
        errors = np.linalg.norm(estimated - expected, axis=1)
        figures |= {"spoofed_error_mean_m": float(errors.mean()), "spoofed_error_max_m": float(errors.max())}
    return figures


def _slam_settings(items: list[str]) -> dict:
    """``--slam`` as the stations' ``slam`` section, checked against the settings before a
    station starts (an unknown name or a wrong value is refused with its reason)."""
    overrides = {}
    for item in items:
        name, values = parse_set(f"slam.{item}")
        if len(values) != 1:
            raise UsageError(f"--slam {item}: one value a setting, not a list to sweep")
        overrides[name] = values[0]
    with_overrides(Settings(), overrides)
    return {name.removeprefix("slam."): value for name, value in overrides.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--spoof-start", type=float, default=60.0)
    parser.add_argument("--dataset", type=Path, help="a drone-flight render at 30 fps to use instead of rendering one")
    parser.add_argument(
        "--cases", nargs="+", default=["fused", "plain", "sample"], choices=["fused", "plain", "two", "sample"], help="which streams to run (fused needs plain's p95 for its ratio; two: two vehicles streaming the flight at once)"
    )
    parser.add_argument("--keep", type=Path, help="keep the stations' data and the streams' answers here")
    parser.add_argument("--slam", nargs="+", default=[], metavar="KEY=VALUE", help="the stations' slam settings other than the defaults (mapping=thread, loop_closing=false)")
    args = parser.parse_args()
    command = f"python bench/live_navigation.py --duration {args.duration:g} --spoof-start {args.spoof_start:g}" + (f" --slam {' '.join(args.slam)}" if args.slam else "")
    try:
        slam = _slam_settings(args.slam)
    except EvpError as exc:
        raise SystemExit(f"live_navigation: {exc}") from exc
    variant = "".join(f", slam.{item}" for item in args.slam)  # the rows of other settings are kept apart
    print(f"command: {command}  (load average {os.getloadavg()[0]:.1f})")
    table = Results("live_navigation", command).table(
        "streams",
        COLUMNS,
        key=["stream", "case"],
        caption="evp stream --realtime to evp serve over loopback (TLS, JPEG), 30 fps; station and client share the machine",
    )
    print(table.header())
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if {"fused", "plain", "two"} & set(args.cases):
            folder = args.dataset or _render(work / "flight", args.duration, args.spoof_start)
            dataset = open_dataset(folder)
            flight = f"rendered drone flight {args.duration:g} s, GPS spoofed from {args.spoof_start:g} s"
            baseline = None
            if "plain" in args.cases:
                [(summary, answers, _)] = _stream(work, "plain", folder, {"estimator": "slam", "slam": slam, "navigation": {"enabled": False}})
                baseline = _latency_figures(summary, answers)
                print(table.add({"stream": flight, "case": "without fusion" + variant, **baseline}), flush=True)
            for case, vehicles in (("fused", 1), ("two", 2)):
                if case not in args.cases:
                    continue
                runs = _stream(work, case, folder, {"estimator": "slam", "slam": slam, "navigation": LIVE_FLIGHT_NAVIGATION}, vehicles)
                fused = _worst_vehicle([_latency_figures(s, a) | _navigation_figures(dataset, a, e, args.spoof_start) for s, a, e in runs])
                fused["p95_ratio"] = None if baseline is None else fused["latency_ms_p95"] / baseline["latency_ms_p95"]
                name = ("fused" if vehicles == 1 else f"fused, {vehicles} vehicles at once (the worse vehicle's figure in each column)") + variant
                print(table.add({"stream": flight, "case": name, **fused}), flush=True)
        if "sample" in args.cases:
            [(summary, answers, _)] = _stream(work, "sample", SAMPLE, {})
            print(table.add({"stream": "bundled sample (davis_slider_depth, no IMU)", "case": "SLAM only", **_latency_figures(summary, answers)}), flush=True)


if __name__ == "__main__":
    main()
