"""Base station over loopback: frame-sent to pose-received latency at 640x380 and 30 fps, and how
many 30 fps streams one machine sustains, for the SLAM estimator and the light VO.

Each row starts ``evp serve`` (TLS, as deployed) and K concurrent ``evp stream --realtime`` of the
rendered seed-000 circle (640x380, 30 fps, JPEG q90): a phone's pace, so the station drops what it
cannot keep up with. A stream counts as sustained when >= 90 % of its frames get a pose.

    python bench/station_latency.py [--duration 20] [--streams 1 2 3] [--estimators slam klt-vo] [--source SEQUENCE]
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
from tests.station.conftest import running_station  # noqa: E402

SUSTAINED = 0.90


def _circle(folder: Path, duration: float) -> Path:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    generate("circle-indoor", SimOptions(duration_s=duration, fps=30.0, seed=1), folder, workers=1)
    return folder


def _streams(url: str, source: Path, count: int) -> list[dict]:
    command = [sys.executable, "-m", "evp.cli", "stream", str(source), "--url", url, "--realtime", "--quiet", "--encoding", "jpeg"]
    processes = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True) for _ in range(count)]
    summaries = []
    for process in processes:
        out, _ = process.communicate(timeout=900)
        summaries.append(json.loads(out.strip().splitlines()[-1]))
    return summaries


def _row(estimator: str, count: int, source: Path, work: Path) -> str:
    config = work / f"{estimator}.yaml"
    config.write_text(f"estimator: {estimator}\n")
    with running_station(work / f"station-{estimator}-{count}", "--config", str(config)) as station:
        time.sleep(1.0)
        summaries = _streams(station.url, source, count)
    answered = [s["poses_received"] / max(1, s["frames_sent"]) for s in summaries]
    p50 = max(s["latency_ms_p50"] for s in summaries)
    p95 = max(s["latency_ms_p95"] for s in summaries)
    sustained = sum(a >= SUSTAINED for a in answered)
    frames = summaries[0]["frames_sent"]
    poses_per_s = sum(s["poses_received"] / s["duration_s"] for s in summaries)
    return (
        f"| {estimator} | {count} | {frames} | {min(answered) * 100:.0f}-{max(answered) * 100:.0f} % | "
        f"{poses_per_s:.1f} | {p50:.0f} | {p95:.0f} | {sustained}/{count} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of 30 fps video per stream")
    parser.add_argument("--streams", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--estimators", nargs="+", default=["slam", "klt-vo"])
    parser.add_argument(
        "--source", type=Path, help="a real sequence to stream instead of the rendered circle (e.g. ../shared/data/euroc_mh_01_easy_moving_360)"
    )
    args = parser.parse_args()
    print(f"command: python bench/station_latency.py {' '.join(sys.argv[1:])}")
    print(
        "| estimator | streams | frames each | frames answered with a pose | poses/s (all streams) | latency p50 ms (worst stream) | latency p95 ms | streams sustained |"
    )
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        source = args.source or _circle(work / "circle", args.duration)
        for estimator in args.estimators:
            for count in args.streams:
                print(_row(estimator, count, source, work), flush=True)


if __name__ == "__main__":
    main()
