"""One frame of seed 001's EKF-SLAM: predict the features into the image, find them there, fuse
them, and keep the map useful and bounded (delete features that keep failing, make room when the
state is full, add new ones where the image has too few)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.config import EkfSlamSettings
from evp.ekf_slam.filter import EkfSlamFilter, MapFeature, chi2_quantile
from evp.ekf_slam.tracking import Describer, PixelRays, detect_corners, new_feature_corners, search
from evp.types import CameraModel


@dataclass(frozen=True)
class FrameReport:
    """What one frame did: features predicted in the image, matched, used, added, deleted, and
    the update's NIS (0 without an update)."""

    predicted: int
    matched: int
    used: int
    added: int
    deleted: int
    nis: float


class WheelVisualSlam:
    """The filter with its image front end: :meth:`wheels` for each wheel sample, :meth:`image`
    for each frame (in time order)."""

    def __init__(self, camera: CameraModel, T_body_cam: np.ndarray, settings: EkfSlamSettings):
        self.camera = camera
        self.settings = settings
        self.rays = PixelRays(camera)
        self.filter = EkfSlamFilter(T_body_cam[:3, :3], T_body_cam[:3, 3].astype(float), settings, 0.5 * (camera.fx + camera.fy))

    def wheels(self, timestamp: float, speed_m_s: float, yaw_rate_rad_s: float) -> None:
        self.filter.predict(timestamp, speed_m_s, yaw_rate_rad_s)

    def image(self, timestamp: float, grey: np.ndarray) -> FrameReport:
        s, flt = self.settings, self.filter
        flt.extrapolate(timestamp)
        corners = detect_corners(grey, self.rays, s.fast_threshold)
        describer = Describer(grey, corners)
        visible, pixels = self._in_image()
        matched = used = 0
        nis = 0.0
        if visible:
            predictions = flt.predict_features(visible)
            covariance = predictions.innovation_covariance + np.eye(2) * flt.measurement_variance()
            matches = search(
                predictions.z,
                covariance,
                [(f.first_descriptor, f.descriptor) for f in visible],
                corners,
                describer,
                s.search_gate_probability,
                s.match_max_hamming,
            )
            matched = len(matches)
            found = {row for row, _ in matches}
            for row, feature in enumerate(visible):
                feature.attempts += 1
                if row in found:
                    feature.matches += 1
                    feature.last_seen = timestamp
            # the most uncertain predictions first: they teach the filter most (MonoSLAM)
            spread = np.trace(predictions.innovation_covariance, axis1=1, axis2=2)
            matches = [matches[i] for i in np.argsort([-spread[row] for row, _ in matches], kind="stable")[: s.max_updates_per_frame]]
            used = len(matches)
            if matches:
                nis = self._fuse(timestamp, visible, predictions, covariance, matches, corners)
                described = describer.describe(np.array([corner for _, corner in matches]))
                for row, corner in matches:
                    if corner in described:
                        visible[row].descriptor = described[corner]
        deleted = self._delete_failing()
        flt.make_euclidean()
        added = 0
        if matched < s.min_matched_features:
            added = self._add_features(timestamp, corners, describer, pixels if visible else np.zeros((0, 2)))
        return FrameReport(len(visible), matched, used, added, deleted, nis)

    def _fuse(self, timestamp: float, visible: list[MapFeature], predictions, covariance: np.ndarray, matches: list[tuple[int, int]], corners) -> float:
        """Fuse the matches in two steps (Civera et al. 2010's split): those whose innovation is
        small on the prediction first, then the others re-predicted from the corrected state and
        fused only if they still pass the search gate there; a wrong match that the prediction's
        uncertainty let in rarely survives the second test. Returns the summed NIS."""
        s, flt = self.settings, self.filter
        rows = np.array([row for row, _ in matches])
        measured = corners.normalised[[corner for _, corner in matches]]
        offsets = measured - predictions.z[rows]
        nis = np.einsum("ka,kab,kb->k", offsets, np.linalg.inv(covariance[rows]), offsets)
        low = nis <= chi2_quantile(s.low_innovation_probability, 2)
        total = flt.update(timestamp, predictions, rows[low], measured[low]) if low.any() else 0.0
        if (~low).any():
            rest = [visible[row] for row in rows[~low]]
            again = flt.predict_features(rest)
            offsets = measured[~low] - again.z
            covariance = again.innovation_covariance + np.eye(2) * flt.measurement_variance()
            passed = np.einsum("ka,kab,kb->k", offsets, np.linalg.inv(covariance), offsets) <= chi2_quantile(s.search_gate_probability, 2)
            if passed.any():
                total += flt.update(timestamp, again, np.flatnonzero(passed), measured[~low][passed])
        return total

    def _in_image(self) -> tuple[list[MapFeature], np.ndarray]:
        """The features predicted in front of the camera and inside the image's searchable part,
        with their predicted pixels."""
        features = self.filter.features
        if not features:
            return [], np.zeros((0, 2))
        R_wc, centre = self.filter.camera_pose()
        points = self.filter.feature_points()
        in_camera = (points - centre) @ R_wc
        front = in_camera[:, 2] > 0.05
        pixels = np.full((len(features), 2), -1.0)
        if front.any():
            pixels[front] = self.camera.project(in_camera[front])
        margin = self.settings.image_margin_px
        inside = (
            front
            & (pixels[:, 0] >= margin)
            & (pixels[:, 0] < self.camera.width - margin)
            & (pixels[:, 1] >= margin)
            & (pixels[:, 1] < self.camera.height - margin)
        )
        return [f for f, keep in zip(features, inside) if keep], pixels[inside]

    def _delete_failing(self) -> int:
        """MonoSLAM's rule: searched at least ``delete_min_attempts`` times and missed in more
        than ``delete_max_miss_ratio`` of them."""
        s = self.settings
        failing = {
            f.id for f in self.filter.features if f.attempts >= s.delete_min_attempts and (f.attempts - f.matches) > s.delete_max_miss_ratio * f.attempts
        }
        self.filter.remove_features(failing)
        return len(failing)

    def _add_features(self, timestamp: float, corners, describer: Describer, avoid_px: np.ndarray) -> int:
        s, flt = self.settings, self.filter
        wanted = min(s.new_features_per_frame, s.min_matched_features)
        room = s.max_features - len(flt.features)
        if room < wanted:
            self._make_room(wanted - room, timestamp)
            room = s.max_features - len(flt.features)
        chosen = new_feature_corners(corners, avoid_px, s.new_feature_min_distance_px, min(wanted, room))
        described = describer.describe(np.array(chosen, dtype=int))
        usable = [i for i in chosen if i in described]
        if usable:
            flt.add_features(corners.normalised[usable], [described[i] for i in usable], timestamp)
        return len(usable)

    def _make_room(self, count: int, timestamp: float) -> None:
        """A full state: the features not in view that were matched least well and longest ago
        leave (a feature that left the image for good goes first)."""
        visible = {f.id for f in self._in_image()[0]}
        candidates = [f for f in self.filter.features if f.id not in visible]
        candidates.sort(key=lambda f: (f.matches / max(f.attempts, 1), f.last_seen))
        self.filter.remove_features({f.id for f in candidates[:count]})
