"""Monocular keyframe visual odometry: KLT feature tracks, essential-matrix initialisation, PnP
tracking against points triangulated between keyframes.

This is EVP's light estimator (the role SVO plays in seed 002): no global map, no loop closing,
no relocalisation. The scale is fixed at initialisation (median scene depth = 1) and carried
from keyframe to keyframe through the triangulated points.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from evp.config import VoSettings
from evp.estimator import Estimator
from evp.geometry.transforms import se3, se3_inverse
from evp.geometry.two_view import check_points, triangulate
from evp.optim.reprojection import CHI2_2DOF
from evp.types import CameraModel, Frame, LensModel, PoseEstimate, TrackingState
from evp.vision.images import grey_image

LK_PARAMS = dict(winSize=(11, 11), maxLevel=3, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))


@dataclass
class _Keyframe:
    image: np.ndarray
    T_world_cam: np.ndarray
    keypoints: np.ndarray  # (N, 2) pixels in the keyframe
    points_world: np.ndarray  # (N, 3), NaN where not triangulated yet
    index: int


class KltVisualOdometry(Estimator):
    """``feed(frame) -> PoseEstimate``; poses are ``T_world_cam`` with the first keyframe as world."""

    def __init__(self, camera: CameraModel, settings: VoSettings | None = None):
        self.camera = camera
        self.settings = settings or VoSettings()
        self._keyframe: _Keyframe | None = None
        self._previous: np.ndarray | None = None
        self._tracks: np.ndarray | None = None  # current pixel position of each keyframe feature
        self._initialised = False
        self._T_world_cam = np.eye(4)
        self._velocity = np.eye(4)  # T_prev_cur of the last step (constant-velocity prior)
        self._frame_count = 0
        self._scale_depth = 1.0  # median depth the map is scaled to (kept across re-initialisation)
        # OpenCV's pinhole PnP models radial-tangential lenses only: a fisheye's tracks go to it undistorted
        self._pnp_radtan = camera.lens is LensModel.RADTAN
        self._pnp_distortion = camera.distortion if self._pnp_radtan else np.zeros(5)

    # --- public ---------------------------------------------------------------------------

    def feed(self, frame: Frame) -> PoseEstimate:
        grey = grey_image(frame, self.camera)
        self._frame_count += 1
        if self._keyframe is None:
            self._start_keyframe(grey, self._T_world_cam, np.zeros((0, 2)), np.zeros((0, 3)))
            return self._estimate(frame, TrackingState.NOT_INITIALIZED, 0)
        tracked = self._track(grey)
        if not self._initialised:
            return self._try_initialise(frame, grey, tracked)
        return self._track_pose(frame, grey, tracked)

    # --- steps ------------------------------------------------------------------------------

    def _detect(self, grey: np.ndarray, existing: np.ndarray, count: int) -> np.ndarray:
        if count <= 0:
            return np.zeros((0, 2))
        mask = np.full(grey.shape, 255, np.uint8)
        radius = int(round(self.settings.min_feature_distance_px))
        for x, y in existing:
            cv2.circle(mask, (int(x), int(y)), radius, 0, -1)
        corners = cv2.goodFeaturesToTrack(grey, count, 0.001, self.settings.min_feature_distance_px, mask=mask, blockSize=7)
        return np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(float)

    def _start_keyframe(self, grey: np.ndarray, T_world_cam: np.ndarray, keypoints: np.ndarray, points_world: np.ndarray) -> None:
        fresh = self._detect(grey, keypoints, self.settings.max_features - len(keypoints))
        keypoints = np.vstack([keypoints, fresh])
        points_world = np.vstack([points_world, np.full((len(fresh), 3), np.nan)])
        self._keyframe = _Keyframe(grey, T_world_cam.copy(), keypoints, points_world, self._frame_count)
        self._tracks = keypoints.copy()
        self._previous = grey

    def _track(self, grey: np.ndarray) -> np.ndarray:
        """Boolean mask of keyframe features still tracked; updates their pixel positions."""
        kf = self._keyframe
        alive = np.all(np.isfinite(self._tracks), axis=1)
        if not alive.any():
            self._previous = grey
            return alive
        p0 = self._tracks[alive].astype(np.float32).reshape(-1, 1, 2)
        p1, ok1, _ = cv2.calcOpticalFlowPyrLK(self._previous, grey, p0, None, **LK_PARAMS)
        back, ok2, _ = cv2.calcOpticalFlowPyrLK(grey, self._previous, p1, None, **LK_PARAMS)
        good = (ok1.ravel() == 1) & (ok2.ravel() == 1) & (np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < 1.0)
        p1 = p1.reshape(-1, 2)
        inside = (p1[:, 0] >= 0) & (p1[:, 1] >= 0) & (p1[:, 0] < grey.shape[1]) & (p1[:, 1] < grey.shape[0])
        good &= inside
        indices = np.flatnonzero(alive)
        self._tracks[indices[~good]] = np.nan
        self._tracks[indices[good]] = p1[good]
        self._previous = grey
        del kf
        return np.all(np.isfinite(self._tracks), axis=1)

    def _try_initialise(self, frame: Frame, grey: np.ndarray, tracked: np.ndarray) -> PoseEstimate:
        kf = self._keyframe
        s = self.settings
        stale = self._frame_count - kf.index > s.init_max_frames
        if tracked.sum() < s.init_min_points or stale:
            # too few tracks survive, or this reference never gave a sound two-view geometry
            # (e.g. it was taken while climbing along the optical axis): restart from this frame
            self._start_keyframe(grey, self._T_world_cam, np.zeros((0, 2)), np.zeros((0, 3)))
            return self._estimate(frame, TrackingState.NOT_INITIALIZED, 0)
        parallax = np.median(np.linalg.norm(self._tracks[tracked] - kf.keypoints[tracked], axis=1))
        if parallax < s.init_min_parallax_px:
            return self._estimate(frame, TrackingState.NOT_INITIALIZED, 0)
        x0 = self.camera.undistort_points(kf.keypoints[tracked])
        x1 = self.camera.undistort_points(self._tracks[tracked])
        threshold = s.ransac_threshold_px / self.camera.fx
        E, inliers = cv2.findEssentialMat(x0, x1, np.eye(3), cv2.RANSAC, 0.999, threshold)
        if E is None or E.shape != (3, 3):
            return self._estimate(frame, TrackingState.NOT_INITIALIZED, 0)
        _, R, t, pose_inliers = cv2.recoverPose(E, x0, x1, np.eye(3), mask=inliers.copy())
        T_cur_kf = se3(R, t.ravel())
        points_kf, good, cos = self._triangulate(x0, x1, np.eye(4), T_cur_kf)
        good &= pose_inliers.ravel() > 0
        # refuse weak or ambiguous two-view geometry rather than start a wrong map
        if good.sum() < max(s.init_min_points, 0.5 * len(x0)) or _median_angle_deg(cos[good]) < s.init_min_angle_deg:
            return self._estimate(frame, TrackingState.NOT_INITIALIZED, 0)
        scale = self._scale_depth / np.median(points_kf[good, 2])
        T_cur_kf[:3, 3] *= scale
        points_world = (points_kf * scale) @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]
        all_points = kf.points_world.copy()
        rows = np.flatnonzero(tracked)[good]
        all_points[rows] = points_world[good]
        kf.points_world = all_points
        self._T_world_cam = kf.T_world_cam @ se3_inverse(T_cur_kf)
        self._velocity = np.eye(4)
        self._initialised = True
        self._new_keyframe(grey, tracked)
        return self._estimate(frame, TrackingState.OK, int(good.sum()))

    def _track_pose(self, frame: Frame, grey: np.ndarray, tracked: np.ndarray) -> PoseEstimate:
        kf = self._keyframe
        s = self.settings
        with_3d = tracked & np.all(np.isfinite(kf.points_world), axis=1)
        if with_3d.sum() < s.min_tracked_points:
            return self._lost(frame, grey)
        guess = se3_inverse(self._T_world_cam @ self._velocity)  # T_cam_world
        rvec, _ = cv2.Rodrigues(guess[:3, :3])
        pixels = self._tracks[with_3d] if self._pnp_radtan else self.camera.undistort_pixels(self._tracks[with_3d])
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            kf.points_world[with_3d],
            pixels,
            self.camera.K,
            self._pnp_distortion,
            rvec.copy(),
            guess[:3, 3].copy(),
            useExtrinsicGuess=True,
            iterationsCount=100,
            reprojectionError=2.0 * s.ransac_threshold_px,
            confidence=0.999,
            flags=cv2.SOLVEPNP_ITERATIVE,
        )
        if not ok or inliers is None or len(inliers) < s.min_tracked_points:
            return self._lost(frame, grey)
        inliers = inliers.ravel()
        rvec, tvec = self._refine_pose(kf.points_world[with_3d][inliers], pixels[inliers], guess, rvec, tvec)
        if rvec is None:
            return self._lost(frame, grey)
        T_cam_world = se3(cv2.Rodrigues(rvec)[0], tvec.ravel())
        outliers = np.flatnonzero(with_3d)[np.setdiff1d(np.arange(with_3d.sum()), inliers)]
        self._tracks[outliers] = np.nan
        T_world_cam = se3_inverse(T_cam_world)
        step = np.linalg.norm(T_world_cam[:3, 3] - self._T_world_cam[:3, 3])
        if step > s.max_step_depth_ratio * self._scale_depth:
            return self._lost(frame, grey)  # an implausible jump: a wrong PnP solution, not motion
        self._velocity = se3_inverse(self._T_world_cam) @ T_world_cam
        self._T_world_cam = T_world_cam
        tracked = np.all(np.isfinite(self._tracks), axis=1)
        parallax = np.median(np.linalg.norm(self._tracks[tracked] - kf.keypoints[tracked], axis=1))
        map_points = np.all(np.isfinite(kf.points_world), axis=1).sum()
        if parallax > s.keyframe_parallax_px or len(inliers) < s.keyframe_min_map_ratio * map_points:
            self._triangulate_new(tracked)
            self._new_keyframe(grey, np.all(np.isfinite(self._tracks), axis=1))
        return self._estimate(frame, TrackingState.OK, len(inliers))

    def _lost(self, frame: Frame, grey: np.ndarray) -> PoseEstimate:
        """Start again from here, keeping the last pose as the origin of the new map."""
        kf = self._keyframe
        finite = kf.points_world[np.all(np.isfinite(kf.points_world), axis=1)]
        if len(finite):
            depths = (finite - self._T_world_cam[:3, 3]) @ self._T_world_cam[:3, 2]
            self._scale_depth = float(np.median(depths[depths > 0])) if np.any(depths > 0) else self._scale_depth
        self._initialised = False
        self._start_keyframe(grey, self._T_world_cam, np.zeros((0, 2)), np.zeros((0, 3)))
        return self._estimate(frame, TrackingState.LOST, 0)

    def _triangulate_new(self, tracked: np.ndarray) -> None:
        """Triangulate tracked keyframe features that have no 3-D point yet (both poses known)."""
        kf = self._keyframe
        todo = tracked & ~np.all(np.isfinite(kf.points_world), axis=1)
        if not todo.any():
            return
        x0 = self.camera.undistort_points(kf.keypoints[todo])
        x1 = self.camera.undistort_points(self._tracks[todo])
        T_cur_kf = se3_inverse(self._T_world_cam) @ kf.T_world_cam
        points_kf, good, _ = self._triangulate(x0, x1, np.eye(4), T_cur_kf)
        points_world = points_kf @ kf.T_world_cam[:3, :3].T + kf.T_world_cam[:3, 3]
        rows = np.flatnonzero(todo)[good]
        kf.points_world[rows] = points_world[good]

    def _triangulate(self, x0: np.ndarray, x1: np.ndarray, T0: np.ndarray, T1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points in frame 0 from normalised coordinates; mask of those in front of both cameras,
        with enough parallax and a reprojection error under twice the RANSAC threshold; and the
        cosine of each point's parallax angle."""
        points = triangulate(T0, T1, x0, x1)
        sigma2 = (2.0 * self.settings.ransac_threshold_px) ** 2 / CHI2_2DOF  # chi2 bound = (2 x threshold)^2
        min_parallax_cos = np.cos(np.radians(self.settings.min_triangulation_angle_deg))
        good, cos = check_points(points, T0, T1, x0, x1, self.camera.fx, sigma2, sigma2, min_parallax_cos)
        return points, good, cos

    def _refine_pose(self, points: np.ndarray, pixels: np.ndarray, guess_T_cam_world: np.ndarray, rvec: np.ndarray, tvec: np.ndarray):
        """Levenberg-Marquardt on the RANSAC inliers, started from the motion-model guess.

        OpenCV's RANSAC result varies in the last digits from run to run (its hypotheses are
        drawn in parallel); starting the refinement from the deterministic guess makes replays
        identical. The RANSAC pose is the fallback when it fits the inliers better.
        """
        K, dist = self.camera.K, self._pnp_distortion
        candidates = []
        for start_r, start_t in ((cv2.Rodrigues(guess_T_cam_world[:3, :3])[0], guess_T_cam_world[:3, 3].reshape(3, 1)), (rvec, tvec)):
            r, t = cv2.solvePnPRefineLM(points, pixels, K, dist, start_r.copy(), start_t.copy())
            if np.isfinite(r).all() and np.isfinite(t).all():
                projected, _ = cv2.projectPoints(points, r, t, K, dist)
                candidates.append((float(np.sum((projected.reshape(-1, 2) - pixels) ** 2)), r, t))
        if not candidates:
            return None, None
        best = candidates[0] if candidates[0][0] <= candidates[-1][0] * (1 + 1e-6) else candidates[-1]
        return best[1], best[2]

    def _new_keyframe(self, grey: np.ndarray, tracked: np.ndarray) -> None:
        kf = self._keyframe
        keep = tracked & np.all(np.isfinite(kf.points_world), axis=1)
        self._start_keyframe(grey, self._T_world_cam, self._tracks[keep], kf.points_world[keep])

    def _estimate(self, frame: Frame, state: TrackingState, inliers: int) -> PoseEstimate:
        quality = int(min(100, 100 * inliers / max(1, self.settings.max_features // 3)))
        return PoseEstimate(frame.timestamp, self._T_world_cam.copy(), state, quality)


def _median_angle_deg(parallax_cos: np.ndarray) -> float:
    """Median angle between the two viewing rays of triangulated points."""
    return float(np.degrees(np.median(np.arccos(np.clip(parallax_cos, -1.0, 1.0))))) if len(parallax_cos) else 0.0
