"""build_slam lends the engine what ``slam.mapping`` asks for, and finish() leaves no thread or
process of it behind."""

import multiprocessing
import threading

from evp.config import OrbSettings, SlamSettings
from evp.io.vocabulary_files import default_vocabulary_path, load_vocabulary
from evp.runtime.mapping_worker import MappingWorker
from evp.runtime.slam import build_slam
from evp.slam.local_mapping import InlineMapping
from evp.types import CameraModel

VOCABULARY = load_vocabulary(default_vocabulary_path())

CAMERA = CameraModel(width=320, height=240, fx=250.0, fy=250.0, cx=160.0, cy=120.0)


def _runtime_threads() -> list[str]:
    return [thread.name for thread in threading.enumerate() if thread.name.startswith(("evp-helper", "evp-local-mapping"))]


def _held_elsewhere(lock) -> bool:
    """Whether another thread finds the lock taken."""
    taken: list[bool] = []

    def try_lock() -> None:
        acquired = lock.acquire(blocking=False)
        if acquired:
            lock.release()
        taken.append(not acquired)

    other = threading.Thread(target=try_lock)
    other.start()
    other.join()
    return taken[0]


def test_thread_mapping_gets_a_worker_a_helper_process_and_a_real_lock_all_released_by_finish():
    slam = build_slam(CAMERA, OrbSettings(n_features=300), SlamSettings(mapping="thread"), VOCABULARY)
    assert isinstance(slam.mapping, MappingWorker) and slam.scheduler.parallel is not None
    with slam.map.lock:
        assert _held_elsewhere(slam.map.lock)
    assert multiprocessing.active_children()  # the bundle adjustment helper
    slam.finish()
    assert not _runtime_threads() and not multiprocessing.active_children()


def test_inline_mapping_gets_the_helper_thread_only():
    slam = build_slam(CAMERA, OrbSettings(n_features=300), SlamSettings(mapping="inline"), VOCABULARY)
    assert isinstance(slam.mapping, InlineMapping) and not multiprocessing.active_children()
    slam.finish()
    assert not _runtime_threads()
