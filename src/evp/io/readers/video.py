"""A video file with optional companions beside it (same stem, or a generic name):

* calibration: ``<stem>.yaml`` or ``camera.yaml`` (any format EVP reads)
* frame times: ``<stem>.times.txt`` (one time per frame), else frame index / FPS
* telemetry: ``<stem>.csv`` or ``telemetry.csv`` (EVP telemetry CSV)
* ground truth: ``<stem>.groundtruth.txt`` or ``groundtruth.txt`` (TUM)
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from evp.calib.camera_files import read_camera
from evp.errors import DatasetError
from evp.io.dataset import Dataset, check_increasing
from evp.io.telemetry_csv import read_telemetry_csv, split_by_sensor
from evp.io.trajectory import read_timestamps, read_trajectory
from evp.types import Frame

VIDEO_SUFFIXES = {".mp4", ".avi", ".mov", ".mkv", ".m4v", ".webm", ".mjpeg", ".mjpg"}


def _companion(video: Path, *names: str) -> Path | None:
    return next((video.parent / n for n in names if (video.parent / n).is_file()), None)


def _video_frames(video: Path, times: np.ndarray):
    def load(errors: list[DatasetError] | None = None) -> Iterator[Frame]:
        capture = cv2.VideoCapture(str(video))
        try:
            for index, stamp in enumerate(times):
                ok, image = capture.read()
                if not ok:
                    error = DatasetError(video, f"cannot decode frame {index} (the rest of the video is unreadable)", record=str(index))
                    if errors is None:
                        raise error
                    errors.append(error)
                    return
                yield Frame(float(stamp), image, index, f"{video}#{index}")
        finally:
            capture.release()

    return load


class VideoReader:
    name = "video"
    description = "video file (+ <stem>.yaml calibration, <stem>.csv telemetry, <stem>.times.txt)"
    looks_for = "a video file (" + ", ".join(sorted(VIDEO_SUFFIXES)) + ")"

    def detect(self, path: Path) -> bool:
        return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES

    def read(self, path: Path) -> Dataset:
        capture = cv2.VideoCapture(str(path))
        if not capture.isOpened():
            raise DatasetError(path, "cannot open video (unsupported codec or corrupt file)")
        fps = capture.get(cv2.CAP_PROP_FPS) or 0.0
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        width = int(capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        capture.release()
        if count <= 0 or width <= 0:
            raise DatasetError(path, "video has no frames")
        times_file = _companion(path, f"{path.stem}.times.txt")
        if times_file:
            times = read_timestamps(times_file)
            if len(times) < count:
                raise DatasetError(times_file, f"{len(times)} times for {count} frames")
            times = times[:count]
            check_increasing(times_file, times, "frame")
        elif fps > 0:
            times = np.arange(count) / fps
        else:
            raise DatasetError(path, "video has no frame rate and no <stem>.times.txt beside it")
        dataset = Dataset(path.stem, self.name, path, None, times, _video_frames(path, times))
        calibration = _companion(path, f"{path.stem}.yaml", "camera.yaml")
        if calibration:
            camera = read_camera(calibration)
            if (camera.width, camera.height) != (width, height):
                dataset.notes.append(f"calibration {camera.width}x{camera.height} scaled to the video's {width}x{height}")
                camera = camera.scaled(width, height)
            dataset.camera = camera
        else:
            dataset.notes.append("no calibration beside the video (<stem>.yaml or camera.yaml): give --camera FILE|PROFILE")
        telemetry = _companion(path, f"{path.stem}.csv", "telemetry.csv")
        if telemetry:
            for sensor, records in split_by_sensor(read_telemetry_csv(telemetry)).items():
                setattr(dataset, sensor, records)
        truth = _companion(path, f"{path.stem}.groundtruth.txt", "groundtruth.txt")
        if truth:
            dataset.ground_truth = read_trajectory(truth)
            dataset.ground_truth_note = f"{truth.name} (TUM)"
        return dataset
