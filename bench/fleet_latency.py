"""Fleet placement (issue 36): the latency that placing each session's estimator on a Dask cluster
adds to the answers, against estimators on the station itself, in one run.

Usage: python bench/fleet_latency.py [--dataset DIR] [--duration 40] [--streams 1 2]

Renders a 30 fps drone flight (640x380, `--duration` s, seed 0; or reads `--dataset`), starts a
local Dask cluster (`distributed.LocalCluster`, one worker process per stream), and for each
stream count streams the flight that many times at once with `evp stream --realtime` to
`evp serve` twice: with the estimators on the station (`station.vision_process`, the default)
and on the cluster (`station.cluster`). Reports frames answered and frame-sent to
answer-received latency p50 / p95 of every answer of every stream, and the p95 difference.

Answers come at once from each session's estimator process on the station whichever way vision
is placed (the navigation filter's estimate, or SLAM's last pose carried to the frame's time), so
placement should add no latency to them; what it changes is where SLAM's CPU is spent and how old
the last visual correction is (vision age p50). Everything shares this machine: the cluster's
worker is local, so the figures show the overhead of the placement, not a bigger machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from results import Results  # noqa: E402

from tests.station.conftest import running_station  # noqa: E402

COLUMNS = [
    ("cores", "{cores}"),
    ("streams", "{streams}"),
    ("estimators", "{placement}"),
    ("answered", "{answered_percent:.1f} %"),
    ("latency p50 / p95 ms", "{latency_ms_p50:.0f} / {latency_ms_p95:.0f}"),
    ("p95 added by the cluster (ms)", "{added_p95_ms:+.0f}"),
    ("vision age p50 ms", "{visual_age_ms_p50:.0f}"),
    ("load avg", "{load:.1f}"),
]


def _render(folder: Path, duration: float) -> Path:
    from evp.sim.generate import generate
    from evp.sim.scenarios import SimOptions

    generate("drone-flight", SimOptions(duration_s=duration, fps=30.0, seed=0), folder, workers=os.cpu_count() or 1)
    return folder


def _stream_all(work: Path, name: str, source: Path, settings: dict, streams: int) -> dict:
    """``streams`` copies of ``source`` streamed at once to one station with ``settings``."""
    import json
    import subprocess

    config = work / f"{name}.yaml"
    config.write_text(yaml.safe_dump(settings))
    data = work / f"{name}-station"
    load = os.getloadavg()[0]
    with running_station(data, "--config", str(config)) as station:

        def one(k: int) -> list[dict]:
            out = work / f"{name}-stream{k}"
            command = [sys.executable, "-m", "evp.cli", "stream", str(source), "--url", station.url, "--realtime", "--quiet", "--encoding", "jpeg"]
            command += ["--cafile", str(data / "tls" / "cert.pem"), "--out", str(out)]
            result = subprocess.run(command, capture_output=True, text=True, timeout=3600)
            if result.returncode != 0:
                raise SystemExit(f"evp stream failed: {result.stderr[-2000:]}")
            return [json.loads(line) for line in (out / "answers.jsonl").read_text().splitlines()], json.loads((out / "summary.json").read_text())

        with ThreadPoolExecutor(streams) as pool:
            runs = list(pool.map(one, range(streams)))
    answers = [a for run, _ in runs for a in run]
    sent = sum(summary["frames_sent"] for _, summary in runs)
    latencies = np.array([a["latency_ms"] for a in answers if a["latency_ms"] is not None])
    ages = np.array([a["visual_age_s"] for a in answers if a["visual_age_s"] is not None]) * 1000.0
    return {
        "answered_percent": 100.0 * len(answers) / sent,
        "latency_ms_p50": float(np.percentile(latencies, 50)),
        "latency_ms_p95": float(np.percentile(latencies, 95)),
        "visual_age_ms_p50": float(np.percentile(ages, 50)) if len(ages) else None,
        "load": load,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", type=Path, help="a 30 fps drone-flight render to use instead of rendering one")
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument("--streams", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    from distributed import LocalCluster

    command = f"python bench/fleet_latency.py --duration {args.duration:g} --streams {' '.join(map(str, args.streams))}"
    print(f"command: {command}  (load average {os.getloadavg()[0]:.1f})")
    table = Results("fleet_latency", command).table(
        "placement",
        COLUMNS,
        key=["cores", "streams", "placement"],
        caption="evp stream --realtime to evp serve over loopback (TLS, JPEG), 30 fps 640x380; station, cluster and clients share the machine",
    )
    print(table.header())
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        source = args.dataset or _render(work / "flight", args.duration)
        with LocalCluster(n_workers=max(args.streams), threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            for streams in args.streams:
                local = _stream_all(work, f"local{streams}", source, {"estimator": "slam"}, streams)
                print(table.add({"cores": os.cpu_count(), "streams": streams, "placement": "on the station", **local}), flush=True)
                placed = _stream_all(work, f"cluster{streams}", source, {"estimator": "slam", "station": {"cluster": cluster.scheduler_address}}, streams)
                placed["added_p95_ms"] = placed["latency_ms_p95"] - local["latency_ms_p95"]
                print(table.add({"cores": os.cpu_count(), "streams": streams, "placement": "on the cluster (Dask actor)", **placed}), flush=True)


if __name__ == "__main__":
    main()
