"""The SLAM engine with what ``slam.mapping`` asks for: local mapping in a thread of its own with
bundle adjustments in a helper process (``thread``, live runs), or in the tracking thread
(``inline``, deterministic); ORB extraction and two-view initialisation share a helper thread
either way."""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager, nullcontext

from evp.config import OrbSettings, SlamSettings
from evp.runtime.adjustment_process import AdjustmentProcess
from evp.runtime.mapping_worker import MappingWorker
from evp.runtime.parallel import HelperThreads
from evp.slam.gyro_prior import GyroRotations
from evp.slam.local_mapping import InlineMapping, LocalMapper, Mapping
from evp.slam.map import Map
from evp.slam.system import SlamSystem
from evp.types import CameraModel
from evp.vision.vocabulary import Vocabulary


class SlamRuntime:
    """A :class:`~evp.slam.scheduler.Scheduler`: the helper thread always; with
    ``mapping_thread``, the map's lock, the mapping thread and the adjustment process too."""

    def __init__(self, mapping_thread: bool) -> None:
        self.map_lock: AbstractContextManager = threading.RLock() if mapping_thread else nullcontext()
        self.parallel = HelperThreads()
        self._mapping_thread = mapping_thread
        self._worker: MappingWorker | None = None

    def start_mapping(self, mapper: LocalMapper) -> Mapping:
        if not self._mapping_thread:
            return InlineMapping(mapper)
        self._worker = MappingWorker(mapper, AdjustmentProcess())
        return self._worker

    def close(self) -> None:
        """Stop the mapping thread (dropping what it has not mapped), the adjustment process and
        the helper thread; :meth:`SlamSystem.finish` calls it after mapping what was queued."""
        if self._worker is not None:
            self._worker.close()
        self.parallel.close()


def build_slam(
    camera: CameraModel, orb: OrbSettings, settings: SlamSettings, vocabulary: Vocabulary, initial_map: Map | None = None, gyro: GyroRotations | None = None
) -> SlamSystem:
    """The SLAM system scheduled as ``settings.mapping`` says, starting from ``initial_map`` (a
    saved map to relocalise in) when given, its tracking aided by ``gyro`` when given;
    ``finish()`` releases its threads and process (or ``scheduler.close()``, for a run that failed)."""
    runtime = SlamRuntime(mapping_thread=settings.mapping == "thread")
    try:
        return SlamSystem(camera, orb, settings, vocabulary=vocabulary, scheduler=runtime, initial_map=initial_map, gyro=gyro)
    except BaseException:
        runtime.close()
        raise
