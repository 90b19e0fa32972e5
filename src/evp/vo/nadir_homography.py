"""Visual odometry for a camera looking straight down at (nearly) flat ground: mosaic registration.

Images of flat ground are related by homographies. Each new image is registered to a growing mosaic
(the first image's pixel frame): it is matched against the last few images and against any earlier
image whose footprint it should overlap (the previous line of a survey), and one RANSAC homography
from all those matches places it. Registering to the mosaic rather than only to the previous image
keeps the drift of a long chain down. The image centre's place in the mosaic is the camera's ground
position and the homography's scale its height ratio; the arbitrary scale and heading are what the
GPS alignment estimates. Works with sparse survey photos (seconds and tens of metres apart).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evp.estimator import Estimator
from evp.geometry.transforms import se3
from evp.types import CameraModel, Frame, PoseEstimate, TrackingState
from evp.vision.images import to_grey
from evp.vo.survey_adjustment import adjust_survey, tracks_from_matches

EPIPOLAR_PIXELS = 3.0  # a match's distance from its epipolar line; Toledo's ATE is the same from 1.5 to 6
NADIR = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # camera looking down, image x = world x


@dataclass
class _Placed:
    timestamp: float
    pixels: np.ndarray  # keypoints as detected (distorted pixels)
    points: np.ndarray  # keypoints undistorted
    points_mosaic: np.ndarray  # keypoints mapped into the mosaic frame
    descriptors: np.ndarray
    centre_mosaic: np.ndarray
    footprint: float  # image diagonal in mosaic pixels
    T_world_cam: np.ndarray  # as answered live


def _apply(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    mapped = np.column_stack([points, np.ones(len(points))]) @ H.T
    return mapped[:, :2] / mapped[:, 2:3]


class NadirHomographyOdometry(Estimator):
    """``feed(frame) -> PoseEstimate``; world = the first image's ground plane in its pixels
    (x right, y up), z up, the first camera at height f."""

    def __init__(self, camera: CameraModel, max_features: int = 2000, min_inliers: int = 30, recent: int = 3):
        self.camera = camera
        self.min_inliers = min_inliers
        self.recent = recent
        self._detector = cv2.SIFT_create(nfeatures=max_features)
        self._matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})  # KD-trees: SIFT matching in ms
        self._placed: list[_Placed] = []
        self._matches: list[tuple[int, int, np.ndarray]] = []  # (photo, earlier photo, keypoint pairs)
        self.lens: CameraModel | None = None  # the lens the survey adjustment self-calibrated (focal length, k1, k2)
        self._adjusted: np.ndarray | None = None  # poses of the last adjustment (minutes with the lens search)
        self._lost = False

    def _features(self, frame: Frame) -> tuple[np.ndarray, np.ndarray | None]:
        keypoints, descriptors = self._detector.detectAndCompute(to_grey(frame.image), None)
        return np.array([k.pt for k in keypoints]).reshape(-1, 2), descriptors

    def _candidates(self) -> list[int]:
        """Indices of the last few images, plus earlier ones near where the new image should land."""
        count = len(self._placed)
        recent = list(range(max(0, count - self.recent), count))
        if count < 2:
            return recent
        last, before = self._placed[-1], self._placed[-2]
        predicted = 2 * last.centre_mosaic - before.centre_mosaic  # constant velocity
        near = [i for i in range(count - len(recent)) if np.linalg.norm(self._placed[i].centre_mosaic - predicted) < 0.6 * last.footprint]
        return near + recent

    def feed(self, frame: Frame) -> PoseEstimate:
        # FLANN shuffles its KD-trees with OpenCV's per-thread RNG and takes no seed of its own (RANSAC
        # draws nothing from it): seeded per image, so a replay matches the same pairs
        cv2.setRNGSeed(len(self._placed))
        pixels, descriptors = self._features(frame)
        if descriptors is None or len(pixels) < self.min_inliers:
            self._lost = bool(self._placed)
            return self._estimate(frame, TrackingState.LOST if self._placed else TrackingState.NOT_INITIALIZED, 0)
        points = self.camera.undistort_pixels(pixels)
        if not self._placed:
            self._place(frame.timestamp, pixels, points, descriptors, np.eye(3), [])
            return self._estimate(frame, TrackingState.OK, 100)
        candidates = self._candidates()
        query, train = [], []
        for index in candidates:
            pairs = self._matcher.knnMatch(descriptors, self._placed[index].descriptors, k=2)
            good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.75 * n.distance]
            query.append(np.array([m.queryIdx for m in good], dtype=int))
            train.append(np.array([m.trainIdx for m in good], dtype=int))
        source = points[np.concatenate(query)]
        target = np.vstack([self._placed[i].points_mosaic[t] for i, t in zip(candidates, train)])
        H, inliers = cv2.findHomography(source, target, cv2.RANSAC, 3.0) if len(source) >= self.min_inliers else (None, None)
        if H is None or inliers.sum() < self.min_inliers:
            self._lost = True
            return self._estimate(frame, TrackingState.LOST, 0)
        matches = [(i, pairs) for i, q, t in zip(candidates, query, train) if (pairs := self._epipolar_matches(points, i, q, t)) is not None]
        self._place(frame.timestamp, pixels, points, descriptors, H, matches)
        state = TrackingState.RELOCALIZED if self._lost else TrackingState.OK
        self._lost = False
        return self._estimate(frame, state, int(min(100, inliers.sum() / 5)))

    def _epipolar_matches(self, points: np.ndarray, earlier: int, query: np.ndarray, train: np.ndarray) -> np.ndarray | None:
        """The matches with photo ``earlier`` that fit one fundamental matrix, as [this photo's
        keypoint, theirs] rows, or None when fewer than ``min_inliers`` do: the survey
        adjustment's tracks. Not the mosaic homography's inliers: a homography holds only points
        on one ground plane to within its threshold, so it would drop the relief (roofs, trees)
        and the lens distortion the adjustment is there to model (Toledo: 3.09 m against GPS
        from homography inliers, 2.41 m from these)."""
        if len(query) < self.min_inliers:
            return None
        earlier_points = self._placed[earlier].points
        F, inliers = cv2.findFundamentalMat(points[query], earlier_points[train], cv2.FM_RANSAC, EPIPOLAR_PIXELS, 0.999)
        if F is None or inliers.sum() < self.min_inliers:
            return None
        keep = inliers.ravel().astype(bool)
        return np.column_stack([query[keep], train[keep]])

    def _place(
        self, timestamp: float, pixels: np.ndarray, points: np.ndarray, descriptors: np.ndarray, H: np.ndarray, matches: list[tuple[int, np.ndarray]]
    ) -> None:
        """Add the photo (keypoints as detected and undistorted) to the mosaic; ``matches`` pair its
        keypoints with earlier photos' (their index, then [this photo's keypoint, theirs] rows)."""
        c = self.camera
        corners = _apply(H, np.array([[0.0, 0.0], [c.width, c.height]]))
        image = len(self._placed)
        self._matches += [(image, earlier, pairs) for earlier, pairs in matches]
        self._placed.append(
            _Placed(
                timestamp,
                pixels,
                points,
                _apply(H, points),
                descriptors,
                _apply(H, np.array([[c.cx, c.cy]]))[0],
                float(np.linalg.norm(corners[1] - corners[0])),
                self._pose(H),
            )
        )

    def refined_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and camera-to-world poses of the placed photos after adjusting them all
        together (``survey_adjustment``; the lens too when the camera has no lens model).
        About two minutes for 47 photos with the lens search, so the pipeline asks for it once, offline."""
        stamps = np.array([p.timestamp for p in self._placed])
        poses = np.array([p.T_world_cam for p in self._placed]).reshape(-1, 4, 4)
        if len(self._placed) < 2:
            return stamps, poses
        if self._adjusted is None or len(self._adjusted) != len(self._placed):
            tracks = tracks_from_matches([p.pixels for p in self._placed], self._matches)
            self._adjusted, lens = adjust_survey(self.camera, poses, tracks)
            self.lens = None if lens is self.camera else lens  # a calibrated lens is used as given
        return stamps, self._adjusted

    def _pose(self, H: np.ndarray) -> np.ndarray:
        """Camera pose from where the image centre and its x axis land in the mosaic, and the
        height from the footprint's area: mosaic pixels per image pixel are the height ratio to
        the first image. The whole footprint's area rather than one axis's length at the centre:
        it averages the homography's noisy perspective terms (uncalibrated lens, uneven ground)
        over the image and counts both axes (Toledo survey: 5.1 m against 6.1 m of ATE)."""
        c = self.camera
        centre, x_end = _apply(H, np.array([[c.cx, c.cy], [c.cx + 1.0, c.cy]]))
        x_axis = x_end - centre
        corners = _apply(H, np.array([[0.0, 0.0], [c.width, 0.0], [c.width, c.height], [0.0, c.height]]))
        scale = float(np.sqrt(cv2.contourArea(corners.astype(np.float32)) / (c.width * c.height)))
        heading = float(np.arctan2(-x_axis[1], x_axis[0]))
        position = np.array([centre[0] - c.cx, -(centre[1] - c.cy), c.fx * scale])
        yaw = np.array([[np.cos(heading), -np.sin(heading), 0.0], [np.sin(heading), np.cos(heading), 0.0], [0.0, 0.0, 1.0]])
        return se3(yaw @ NADIR, position)

    def _estimate(self, frame: Frame, state: TrackingState, quality: int) -> PoseEstimate:
        pose = self._placed[-1].T_world_cam if self._placed else self._pose(np.eye(3))
        return PoseEstimate(frame.timestamp, pose, state, quality)
