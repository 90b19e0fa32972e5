"""The mapping thread maps what is queued in order, drains at finish, surfaces the mapper's errors
there, and leaves no thread behind (the threads wait on events; nothing sleeps)."""

import threading

import pytest

from evp.runtime.mapping_worker import MappingWorker

WAIT_S = 30.0  # an upper bound for a thread to reach an event, never a delay


class _Mapper:
    """Stands for LocalMapper: records what it maps; each keyframe waits for ``go`` when given."""

    def __init__(self, go: threading.Event | None = None):
        self.go = go
        self.started = threading.Event()
        self.mapped: list[object] = []

    def process(self, item) -> None:
        self.started.set()
        if self.go is not None:
            assert self.go.wait(WAIT_S)
        if item == "bad":
            raise ValueError("mapping failed")
        self.mapped.append(item)


class _Adjuster:
    """Stands for the adjustment process: an interrupt releases the mapper's wait, as it cuts a
    bundle adjustment short."""

    def __init__(self, go: threading.Event):
        self.go = go
        self.closed = False

    def interrupt(self) -> None:
        self.go.set()

    def close(self) -> None:
        self.closed = True


def _mapping_threads() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if thread.name == "evp-local-mapping"]


def test_maps_the_queue_in_order_and_finish_drains_it():
    go = threading.Event()
    mapper = _Mapper(go)
    adjuster = _Adjuster(go)
    worker = MappingWorker(mapper, adjuster)
    assert mapper.adjuster is adjuster and worker.idle
    for item in (1, 2, 3):
        worker.submit(item)
    assert mapper.started.wait(WAIT_S)
    assert not worker.idle and worker.pending == 2 and mapper.keyframes_waiting()  # newer keyframes wait: the mapper skips work for this one
    go.set()
    worker.finish()
    assert mapper.mapped == [1, 2, 3] and len(worker.mapping_ms) == 3 and worker.max_queue >= 2
    assert worker.idle and not mapper.keyframes_waiting() and adjuster.closed
    assert not _mapping_threads()


def test_an_error_in_the_thread_is_raised_by_finish_and_mapping_goes_on():
    mapper = _Mapper()
    worker = MappingWorker(mapper, _Adjuster(threading.Event()))
    for item in ("bad", 2):
        worker.submit(item)
    with pytest.raises(ValueError, match="mapping failed"):
        worker.finish()
    assert mapper.mapped == [2] and not _mapping_threads()
    worker.finish()  # raised once; finishing again is a no-op


def test_close_drops_what_is_queued_cuts_the_running_keyframe_short_and_ends_the_thread():
    go = threading.Event()
    mapper = _Mapper(go)
    adjuster = _Adjuster(go)
    worker = MappingWorker(mapper, adjuster)
    for item in (1, 2, 3):
        worker.submit(item)
    assert mapper.started.wait(WAIT_S)
    worker.close()  # the interrupt releases keyframe 1; 2 and 3 are dropped
    assert mapper.mapped == [1] and adjuster.closed
    assert not _mapping_threads()
    worker.close()  # idempotent
