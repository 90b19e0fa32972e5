"""The estimator process's handle: the event loop never waits for a process that does not read."""

from __future__ import annotations

import asyncio
import multiprocessing
import threading
import time

from evp.runtime.estimator_process import MAX_FRAMES_UNWRITTEN, EstimatorProcess, ProcessEvents

FRAME_BYTES = 400_000  # several times the pipe's buffer: one frame fills it


def _reads_when_told(connection, go) -> None:
    """Says it is ready, reads nothing until ``go``, then answers every frame and telemetry."""
    connection.send(("ready", None))
    go.wait(60)
    while (message := connection.recv()) is not None:
        connection.send(("pose", message[0]) if message[0] != "telemetry" else ("telemetry", message[1]))
    connection.send(("finished", None))


def test_a_process_that_does_not_read_never_blocks_the_loop_and_stale_frames_are_dropped():
    go = multiprocessing.get_context("spawn").Event()
    answered, dropped, told = [], [], []

    async def scenario() -> float:
        ready = asyncio.Event()
        events = ProcessEvents(ready.set, answered.append, lambda *a: None, lambda m: dropped.append(m[0]), lambda reason: None, lambda kind, p: told.append(p))
        process = EstimatorProcess(_reads_when_told, (go,), events, every_message=True)
        await asyncio.wait_for(ready.wait(), 60)
        safety = threading.Timer(20, go.set)  # a blocked loop would otherwise hang the test
        safety.start()
        start = time.monotonic()
        for seq in range(10):
            process.submit((seq, b"x" * FRAME_BYTES))
            process.send_side(("telemetry", seq))
        elapsed = time.monotonic() - start
        go.set()
        safety.cancel()
        await asyncio.sleep(0)
        await process.close()
        return elapsed

    elapsed = asyncio.run(scenario())
    assert elapsed < 5.0, f"the loop waited {elapsed:.1f} s for the process to read"
    assert sorted(answered + dropped) == list(range(10)), "each frame answered or dropped, once"
    assert len(dropped) >= 10 - 1 - MAX_FRAMES_UNWRITTEN and answered[-MAX_FRAMES_UNWRITTEN:] == [7, 8, 9]
    assert told == list(range(10)), "telemetry is never dropped, and keeps its order"
