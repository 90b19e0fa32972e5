"""The station fuzzed: 100k hostile messages of every kind, timestamps of any magnitude (issue 34).

Two phases, both with tests/station/fuzz.py's hostile mobile station (every text type, every
telemetry kind, absurd cameras, broken JSON, image frames out of order, of the wrong size,
corrupt, lying about their format or size, timestamps from -1e308 to 1e308, NaN and infinities):

- in-process: the messages go straight into a real Station's sessions (estimator processes,
  database, recordings), socket-free, so each frame's answers can be counted: every frame must get
  exactly one (a refusal at once, or a pose, `dropped` or error once estimated). Server crashes
  are messages whose handling raised or hit the session's safety net (an `internal` error);
  estimator crashes are the supervisor's restarts; memory growth is the process's RSS at the end
  against after the first tenth.
- over the network: the same kind of messages through a real `evp serve` (TLS WebSockets), a new
  session after each bye; a server crash is the serve process dying or a link it drops without a
  bye; afterwards a new session must still get a pose; memory growth is the serve process's RSS.

Usage: python bench/station_fuzz.py [--messages 100000] [--network-messages 20000] [--seed 34]

Targets: 0 server crashes, 0 estimator crashes, every frame answered exactly once, memory growth
<= 20 MB. No shared data needed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the fuzzer and station runner the tests use
from results import Results  # noqa: E402

from tests.station.conftest import insecure_tls, running_station  # noqa: E402
from tests.station.fuzz import CAMERA, HostileClient, fuzz_station  # noqa: E402

COLUMNS = [
    ("phase", "{phase}"),
    ("messages", "{messages}"),
    ("frames", "{frames}"),
    ("taken / refused", "{frames_estimated} / {frames_refused}"),
    ("sessions", "{sessions}"),
    ("server crashes", "{server_crashes}"),
    ("estimator crashes", "{estimator_crashes}"),
    ("frames answered exactly once", "{answered_once}"),
    ("memory growth MB", "{memory_growth_mb:.1f}"),
    ("still answering", "{still_answering}"),
    ("seconds", "{seconds:.0f}"),
]


def in_process(messages: int, seed: int, work: Path) -> dict:
    def progress(done: int, total: int) -> None:
        if done % 10000 == 0:
            print(f"  in-process: {done}/{total} messages", file=sys.stderr, flush=True)

    result = asyncio.run(fuzz_station(work / "in-process", messages, seed, progress, bye_every=10000, new_estimator_every=10000))
    for line in result.raised[:5]:
        print(f"  raised: {line}", file=sys.stderr)
    return {
        "phase": "in-process (answers counted)",
        "messages": result.messages,
        "frames": result.frames,
        "frames_estimated": result.frames_estimated,
        "frames_refused": result.frames_refused,
        "sessions": result.sessions,
        "server_crashes": result.server_crashes,
        "estimator_crashes": result.estimator_crashes,
        "answered_once": "yes" if result.every_frame_answered_once else f"no ({result.unanswered} unanswered, {result.answered_twice} twice)",
        "memory_growth_mb": result.memory_growth_mb,
        "still_answering": "yes",
        "seconds": result.seconds,
    }


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return 0.0


async def _network(url: str, messages: int, seed: int, pid: int) -> dict:
    import websockets

    client = HostileClient(seed, bye_every=5000, new_estimator_every=10**9)
    counts = {"sessions": 0, "dropped_links": 0, "frames": 0, "baseline": None}
    sent = 0
    start = time.monotonic()

    async def drain(connection) -> None:
        async for _ in connection:
            pass

    while sent < messages:
        connection = await websockets.connect(f"{url}/ws/mobile", ssl=insecure_tls(), max_size=2**25)
        counts["sessions"] += 1
        await connection.send(json.dumps({"type": "hello", "protocol": 1, "device": "fuzz"}))
        await connection.send(json.dumps({"type": "config", "camera": CAMERA}))
        reader = asyncio.create_task(drain(connection))
        client.seq, client.time, client.telemetry_time = 0, 1.0, 1.0
        try:
            while sent < messages:
                message = client.message()
                await connection.send(message)
                await asyncio.sleep(0)  # the reader answers the station's pings (a send need not yield)
                sent += 1
                counts["frames"] += isinstance(message, bytes)
                if sent == messages // 10:
                    await asyncio.sleep(2.0)
                    counts["baseline"] = _rss_mb(pid)
                if sent % 10000 == 0:
                    print(f"  network: {sent}/{messages} messages", file=sys.stderr, flush=True)
                if message == '{"type": "bye"}':
                    break
            else:
                await connection.send('{"type": "bye"}')
            await asyncio.wait_for(reader, 300)  # the station closes the link after a bye
        except (websockets.ConnectionClosedError, TimeoutError) as exc:
            counts["dropped_links"] += 1
            print(f"  link dropped after {sent} messages: {exc!r}", file=sys.stderr, flush=True)
        finally:
            reader.cancel()
            await connection.close()
    await asyncio.sleep(2.0)
    growth = _rss_mb(pid) - (counts["baseline"] or _rss_mb(pid))
    return {**counts, "messages": sent, "memory_growth_mb": growth, "seconds": time.monotonic() - start}


async def _still_answering(url: str) -> bool:
    """A new session with a good frame gets its pose."""
    import websockets

    from evp.station.protocol import encode_image

    client = HostileClient(1)
    async with websockets.connect(f"{url}/ws/mobile", ssl=insecure_tls(), max_size=2**25) as connection:
        await connection.send(json.dumps({"type": "hello", "protocol": 1, "device": "after"}))
        await connection.send(json.dumps({"type": "config", "camera": CAMERA}))
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            message = json.loads(await asyncio.wait_for(connection.recv(), 120))
            if message["type"] == "status" and message["state"] == "running":
                break
        await connection.send(encode_image(client.images[0], 0, 1.0, "png").pack())
        while time.monotonic() < deadline:
            message = json.loads(await asyncio.wait_for(connection.recv(), 120))
            if message["type"] == "pose" and message["seq"] == 0:
                return True
    return False


def over_network(messages: int, seed: int, work: Path) -> dict:
    with running_station(work / "network") as station:
        counts = asyncio.run(_network(station.url, messages, seed, station.process.pid))
        answering = asyncio.run(_still_answering(station.url))
        alive = station.process.poll() is None
    return {
        "phase": "network (evp serve, TLS WebSockets)",
        "messages": counts["messages"],
        "frames": counts["frames"],
        "sessions": counts["sessions"],
        "server_crashes": counts["dropped_links"] + (0 if alive else 1),
        "memory_growth_mb": counts["memory_growth_mb"],
        "still_answering": "yes" if answering else "no",
        "seconds": counts["seconds"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=int, default=100_000, help="in-process messages")
    parser.add_argument("--network-messages", type=int, default=20_000, help="messages through a real evp serve (0: skip)")
    parser.add_argument("--seed", type=int, default=34)
    args = parser.parse_args()
    command = f"python bench/station_fuzz.py {' '.join(sys.argv[1:])}".rstrip()
    print(f"command: {command}")
    table = Results("station_fuzz", command).table(
        "fuzz", COLUMNS, key=["phase"], caption="Targets: 0 server crashes, 0 estimator crashes, every frame answered exactly once, memory growth <= 20 MB"
    )
    print(table.header())
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        print(table.add(in_process(args.messages, args.seed, work)), flush=True)
        if args.network_messages:
            print(table.add(over_network(args.network_messages, args.seed + 1, work)), flush=True)


if __name__ == "__main__":
    main()
