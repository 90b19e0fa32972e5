"""The base station over loopback: frame-sent to pose-received latency at 640x380 and 30 fps, and
how many 30 fps streams one machine sustains, with the SLAM estimator and with the light VO.

Each row starts `evp serve` (TLS, as deployed) and K concurrent `evp stream --realtime` of the
rendered circle (640x380, 30 fps, JPEG q90), or of a real sequence at its own rate: a phone's
pace, so the station drops what it cannot keep up with. The station, its estimator processes and
the clients share the machine.

Usage: python bench/station_latency.py [--duration 20] [--streams 1 2 3] [--estimators slam klt-vo] [--source SEQUENCE]

Prints per estimator and stream count: frames per stream, the share answered with a pose (lowest
to highest stream), poses per second over all streams, latency p50 and p95 of the worst stream,
and how many streams were sustained (at least 90 % answered). Needs the station extra (installed
by scripts/setup.sh); no shared data unless `--source`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the station runner the tests use
from results import Results  # noqa: E402

from tests.station.conftest import running_station  # noqa: E402

SUSTAINED = 0.90


def _circle(folder: Path, duration: float) -> Path:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    generate("circle-indoor", SimOptions(duration_s=duration, fps=30.0, seed=1), folder, workers=1)
    return folder


def _streams(url: str, source: Path, count: int, cafile: Path) -> list[dict]:
    command = [sys.executable, "-m", "evp.cli", "stream", str(source), "--url", url, "--realtime", "--quiet", "--encoding", "jpeg", "--cafile", str(cafile)]
    processes = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) for _ in range(count)]
    summaries = []
    for process in processes:
        out, _ = process.communicate(timeout=900)
        summaries.append(json.loads(out.strip().splitlines()[-1]))
    return summaries


COLUMNS = [
    ("source", "{source}"),
    ("estimator", "{estimator}"),
    ("streams", "{streams}"),
    ("frames each", "{frames_each}"),
    ("frames answered with a pose", "{answered_min_percent:.0f}-{answered_max_percent:.0f} %"),
    ("poses/s (all streams)", "{poses_per_s:.1f}"),
    ("latency p50 ms (worst stream)", "{latency_ms_p50:.0f}"),
    ("latency p95 ms", "{latency_ms_p95:.0f}"),
    ("streams sustained", "{sustained}/{streams}"),
]


def _record(estimator: str, count: int, source: Path, work: Path) -> dict:
    config = work / f"{estimator}.yaml"
    config.write_text(f"estimator: {estimator}\n")
    with running_station(work / f"station-{estimator}-{count}", "--config", str(config)) as station:
        time.sleep(1.0)
        summaries = _streams(station.url, source, count, station.data / "tls" / "cert.pem")
    answered = [s["poses_received"] / max(1, s["frames_sent"]) for s in summaries]
    p50 = max(s["latency_ms_p50"] for s in summaries)
    p95 = max(s["latency_ms_p95"] for s in summaries)
    sustained = sum(a >= SUSTAINED for a in answered)
    frames = summaries[0]["frames_sent"]
    poses_per_s = sum(s["poses_received"] / s["duration_s"] for s in summaries)
    return {
        "estimator": estimator,
        "streams": count,
        "frames_each": frames,
        "answered_min_percent": 100 * min(answered),
        "answered_max_percent": 100 * max(answered),
        "poses_per_s": poses_per_s,
        "latency_ms_p50": p50,
        "latency_ms_p95": p95,
        "sustained": sustained,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of 30 fps video per stream")
    parser.add_argument("--streams", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--estimators", nargs="+", default=["slam", "klt-vo"])
    parser.add_argument(
        "--source", type=Path, help="a real sequence to stream instead of the rendered circle (e.g. ../shared/data/euroc_mh_01_easy_moving_360)"
    )
    args = parser.parse_args()
    command = f"python bench/station_latency.py {' '.join(sys.argv[1:])}".rstrip()
    print(f"command: {command}")
    table = Results("station_latency", command).table(
        "streams", COLUMNS, key=["source", "estimator", "streams"], caption="Loopback, TLS, JPEG q90; the station and its clients share the machine"
    )
    print(table.header())
    label = args.source.name if args.source else f"rendered circle 640x380 30 fps, {args.duration:g} s"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        source = args.source or _circle(work / "circle", args.duration)
        for estimator in args.estimators:
            for count in args.streams:
                print(table.add({"source": label, **_record(estimator, count, source, work)}), flush=True)


if __name__ == "__main__":
    main()
