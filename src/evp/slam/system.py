"""The monocular SLAM system: ``feed(frame) -> PoseEstimate`` (ORB-SLAM's Tracking thread, with
local mapping scheduled beside it and relocalisation when lost).

Per frame: ORB extraction; before initialisation, two-view initialisation against a reference
frame; then the constant-velocity motion model with guided search (fallback: matching against the
reference keyframe), tracking of the local map (points of covisible keyframes) and pose-only
optimisation; when lost, relocalisation against the keyframes (the map is never reset). Frame
poses are stored relative to their reference keyframe, so the final trajectory follows the
keyframes refined by bundle adjustment (as ORB-SLAM saves it), while the live answer is the pose
known at that moment. Frames fed before initialisation are localised against the final map
for the refined trajectory too (``slam.start_backfill_frames``). Started from a saved map
(``initial_map``), it relocalises in it instead of initialising, and starts a map of its own only
after ``slam.map_relocalise_timeout_s`` without finding it. Given the camera's gyro (``gyro``, fed
through :meth:`observe`), tracking predicts each frame's rotation with it and holds the pose
optimisation to it (:mod:`evp.slam.gyro_prior`).
"""

from __future__ import annotations

import time
from collections import Counter, deque
from dataclasses import asdict, dataclass, field
from itertools import chain

import cv2
import numpy as np

from evp.config import OrbSettings, SlamSettings
from evp.estimator import Estimator
from evp.geometry.transforms import scale_motion, se3_inverse
from evp.geometry.two_view import TwoViewCandidate, complete_two_view, two_view_candidate
from evp.slam.gyro_prior import GyroRotations
from evp.slam.local_mapping import LocalMapper, NewKeyFrame
from evp.slam.loop_closing import LoopClosure
from evp.slam.map import KeyFrame, Map
from evp.slam.map_adjustment import adjust_whole_map
from evp.slam.pose_optimizer import optimise_pose, rotation_covariance
from evp.slam.projection import project_points, projected_stretch, undistorted_bounds
from evp.slam.scheduler import InlineScheduler, Scheduler
from evp.types import CameraModel, Frame, ImuSample, PoseEstimate, TrackingState
from evp.vision.images import grey_image
from evp.vision.matching import TH_HIGH, TH_LOW, match_descriptors, match_in_window, rotation_consistent
from evp.vision.orb import Features, OrbExtractor
from evp.vision.vocabulary import BowVector, Vocabulary

RELOCALISATION_CANDIDATES = 5  # keyframes verified by PnP per lost frame, best place first
# Parallax enough to start from when the initial reference is about to be replaced (ORB-SLAM's
# own minimum): its matches are dying faster than the parallax grows, as at a low frame rate or
# a fast forward motion, and waiting for slam.init_min_parallax_deg would mean never starting.
# The map must still be as well determined as a nominal start's (init_min_parallax_deg over
# init_min_triangulated points): a point's depth error goes as 1 / parallax, the map's shape and
# scale error as that over the square root of the points, so fewer degrees need more points.
# A hand-held start turning on the spot (MH01) loses matches fast too; its 1.7-degree, 82-point
# candidate failed within 10 frames, where KITTI at 5 Hz starts on 2.4 degrees and 181 points.
EXPIRING_MIN_PARALLAX_DEG = 1.0
# Features per frame while starting and while starved, in multiples of orb.n_features (at most 3:
# OrbExtractor keeps 3 times its quota of corners). A two-view start needs hundreds of matches
# that survive the parallax it waits for, and a forward drive loses most of them at every frame
# (ORB-SLAM's monocular start takes 5 times its features; 3 here delayed the rendered circle's
# hovering start from 2 s to 7 s). Tracking keeps the budget until its inliers, scaled to the
# configured count, are over STARVED_INLIER_FACTOR times slam.min_tracked_inliers (the line where
# it is lost), and takes it again below: a map thinning out (fast forward motion, a low frame
# rate, dropped frames) would keep fewer inliers at each frame until it is lost.
STARVED_FEATURE_BUDGET = 2
STARVED_INLIER_FACTOR = 3


@dataclass
class _TrackedFrame:
    """What the next frame needs from this one."""

    timestamp: float
    features: Features
    T_cw: np.ndarray
    point_ids: np.ndarray  # (N,) matched map point per feature, -1 where none


@dataclass
class _InitAttempt:
    """One frame's two-view candidate against the initial reference, kept for the next try."""

    candidate: TwoViewCandidate
    rows: np.ndarray  # matched reference features
    cols: np.ndarray  # and this frame's
    features: Features
    record: int  # index of its record in SlamSystem.records
    timestamp: float


@dataclass
class _InitReference:
    """The frame initialisation matches later frames against."""

    features: Features
    record: int  # index of its record in SlamSystem.records
    last_matches: int = field(init=False)  # matched at the last try (its keypoint count at first)
    last_attempt: _InitAttempt | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.last_matches = len(self.features)

    def expiring(self, matches: int, needed: int) -> bool:
        """Whether the matches, falling at the rate of the last step, will be too few at the next
        frame: the reference is about to be replaced, and the parallax it has now is the most it
        will reach. Slow starts (hand-held, hovering, drones climbing) keep most matches from
        frame to frame and wait for the full parallax; a fast forward motion or a low frame rate
        loses most of them at each step. Remembers ``matches`` as the next step's starting count."""
        expiring = matches * matches < needed * self.last_matches
        self.last_matches = matches
        return expiring

    def past_peak(self, attempt: _InitAttempt, needed_points: int, needed_matches: int) -> _InitAttempt | None:
        """The last try, if this reference's parallax peaked there: it has fallen since, the points
        with a new point's parallax, falling at the last step's rate, will be too few at the next
        frame, and the matches, falling at the last step's rate, leave the reference no more
        frames ahead than it has lived. A forward motion's near points leave the view while the
        far ones gain little, so its parallax rises and falls within a few frames (the rendered
        road at 10 Hz: 2.6, 2.4, 1.9 degrees over 142, 139, 76 such points, 579, 357, 240
        matches) and waiting for the nominal parallax means waiting for a new reference. A slow
        start's parallax dips as the hand sways back, its matches stay (the rendered circle's
        hover: 1.5 to 1.2 degrees, 285 to 56 such points, 489 to 476 matches). Remembers
        ``attempt`` for the next try."""
        last, self.last_attempt = self.last_attempt, attempt
        if last is None or attempt.candidate.parallax_deg >= last.candidate.parallax_deg:
            return None
        wide, last_wide = attempt.candidate.wide, last.candidate.wide
        if wide * wide >= needed_points * last_wide:
            return None
        matches, rate = len(attempt.rows), len(attempt.rows) / len(last.rows)
        frames_ahead = np.log(needed_matches / matches) / np.log(rate) if rate < 1 else np.inf
        return last if frames_ahead <= attempt.record - self.record else None


@dataclass
class SavedMapState:
    """A start from a saved map: its keyframes, when tracking first relocalised in it, and when it
    gave up waiting for that and started a new map (None until then)."""

    keyframes: int
    relocalised_at: float | None = None
    fell_back_at: float | None = None


@dataclass
class _FrameRecord:
    timestamp: float
    reference_kf: int
    T_frame_ref: np.ndarray  # T_cw(frame) @ inverse(T_cw(reference keyframe))
    state: TrackingState


class SlamSystem(Estimator):
    """``vocabulary`` is the place-recognition vocabulary (the adapter loads the one
    ``settings.vocabulary`` names); ``scheduler`` runs the work besides tracking: by default all of it in the caller's thread,
    in order (deterministic); evp.runtime.slam.build_slam lends the threads ``slam.mapping``
    asks for (this class does not read that setting)."""

    def __init__(
        self,
        camera: CameraModel,
        orb: OrbSettings | None = None,
        settings: SlamSettings | None = None,
        *,
        vocabulary: Vocabulary,
        scheduler: Scheduler | None = None,
        initial_map: Map | None = None,
        gyro: GyroRotations | None = None,
    ):
        self.camera = camera
        self.gyro = gyro
        self.settings = settings or SlamSettings()
        self.scheduler = scheduler or InlineScheduler()
        self.extractor = OrbExtractor(orb or OrbSettings(), camera, self.scheduler.parallel)
        self.K = camera.K
        self.bounds = undistorted_bounds(self.extractor)
        self.map = Map(self.scheduler.map_lock) if initial_map is None else initial_map
        self.map.lock = self.scheduler.map_lock
        self.vocabulary = vocabulary
        self.mapping = self.scheduler.start_mapping(LocalMapper(self.map, self.extractor, self.settings))
        self.state = TrackingState.NOT_INITIALIZED
        self.extraction_ms: list[float] = []
        self.tracking_ms: list[float] = []  # per frame, without mapping
        self.records: list[_FrameRecord] = []
        self.reset_counter = 0  # bumped on relocalisation and restart (a discontinuity for consumers)
        self._init_reference: _InitReference | None = None
        self._before_start: deque[tuple[int, Features]] = deque(maxlen=self.settings.start_backfill_frames)  # (record index, features)
        self._last: _TrackedFrame | None = None
        self._velocity: np.ndarray | None = None  # motion between the last two tracked frames
        self._velocity_dt = 0.0  # their time apart (s)
        self._rotation_prior: tuple[np.ndarray, np.ndarray] | None = None  # the gyro's R_cw for the frame being tracked, and its information
        self._rotation_covariance: np.ndarray | None = None  # of the last tracked frame's rotation, when tracked (rad^2)
        self._reference_kf: int | None = None
        self._frame_count = 0
        self._last_kf_frame = 0
        self._last_kf_time = -np.inf
        self._last_reloc_frame = -(10**9)
        self._last_inliers = 0
        self._feature_budget = STARVED_FEATURE_BUDGET
        self._globally_adjusted = False
        # a saved map to start from: relocalise in it (no two-view start) until
        # slam.map_relocalise_timeout_s passes without, then start a new map
        self.first_own_keyframe = self.map.id_counters[0]  # keyframes before this id came with the saved map
        self.saved_map = SavedMapState(len(self.map.keyframes)) if initial_map is not None else None
        if initial_map is not None:
            self.state = TrackingState.LOST

    # --- public ---------------------------------------------------------------------------

    def feed(self, frame: Frame) -> PoseEstimate:
        grey = grey_image(frame, self.camera)
        self.settle()
        self._frame_count += 1
        start = time.perf_counter()
        features = self.extractor.extract(grey, self._feature_budget)
        self.extraction_ms.append((time.perf_counter() - start) * 1000.0)
        # a frame is handled under the map lock, its answer too: the answer's record relates the
        # pose to its reference keyframe as tracked, before mapping can move that keyframe
        with self.map.lock:
            if self.state != TrackingState.OK:
                self._rotation_covariance = None  # a start or a relocalisation: the gyro's prior waits for a tracked frame
            if self.state == TrackingState.NOT_INITIALIZED:
                T_cw = self._initialise(frame, features)
                if T_cw is None:
                    self._before_start.append((len(self.records), features))  # this frame's record comes next
            elif self.state == TrackingState.LOST:
                T_cw = self._relocalise(frame.timestamp, features)
                if T_cw is None:
                    self._give_up_saved_map(frame.timestamp)
            else:
                T_cw = self._track(frame.timestamp, features)
            estimate = self._answer(frame, T_cw)
        self.tracking_ms.append((time.perf_counter() - start) * 1000.0)
        return estimate

    @property
    def uses_telemetry(self) -> bool:
        return self.gyro is not None

    def observe(self, record) -> None:
        """The gyro's samples, when tracking has the gyro; other records are not used."""
        if self.gyro is not None and isinstance(record, ImuSample):
            self.gyro.add(record)

    def settle(self) -> None:
        """Inline mapping: map the last frame's keyframe now (feed does it first otherwise), so a
        live caller can answer a pose, then map while it waits for the next frame."""
        self.mapping.settle()

    def finish(self) -> None:
        """Wait for local mapping to finish its queue, then release what the scheduler started
        (end of a run; the trajectories stay readable)."""
        try:
            self.mapping.finish()
        finally:
            self.scheduler.close()

    def close(self) -> None:
        """Release the scheduler's threads and process without mapping what is queued."""
        self.scheduler.close()

    @property
    def frames_fed(self) -> int:
        """Frames fed so far (each counts once, tracked or not)."""
        return self._frame_count

    @property
    def mapping_ms(self) -> list[float]:
        return self.mapping.mapping_ms

    @property
    def loop_closures(self) -> list[LoopClosure]:
        closer = self.mapping.mapper.loop_closer
        return list(closer.closures) if closer is not None else []

    def keyframe_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        with self.map.lock:
            return self.map.keyframe_poses()

    def sparse_map(self) -> Map:
        return self.map

    def timing(self) -> dict:
        """Tracking without the keyframe mapping a call may run first, ORB extraction, mapping
        per keyframe and the deepest the keyframe queue got."""
        return {
            "tracking_ms": self.tracking_ms,
            "orb_extraction_ms": self.extraction_ms,
            "mapping_ms_per_keyframe": self.mapping_ms,
            "keyframe_queue_max": self.mapping.max_queue,
        }

    def report(self) -> dict:
        report = {"loop_closures": [asdict(closure) for closure in self.loop_closures], "gyro_aided_tracking": self.gyro is not None}
        if self.saved_map is not None:
            report["saved_map"] = asdict(self.saved_map)
        return report

    @property
    def in_saved_map(self) -> bool:
        """Started from a saved map and still in it (not fallen back to a new one)."""
        return self.saved_map is not None and self.saved_map.fell_back_at is None

    def refined_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """Timestamps and ``T_world_cam`` of every tracked frame, through the final keyframe poses.

        The first call after a run (``slam.final_bundle_adjustment``) adjusts the whole map once:
        local bundle adjustment left each keyframe as its window saw it, and a closed loop was
        adjusted when it closed, not with what came after (seconds; offline runs ask for it).
        Then the frames fed before initialisation are localised in that map. Both belong to the
        end of a run: call it after :meth:`finish`."""
        if self.settings.final_bundle_adjustment and not self._globally_adjusted:
            self._globally_adjusted = True
            with self.map.lock:
                adjust_whole_map(self.map, self.extractor.scale_factors, self.K, self.settings.ba_evaluations, self.settings.final_ba_points_per_keyframe)
        with self.map.lock:
            self._localise_frames_before_start()
        stamps, poses = [], []
        with self.map.lock:
            for record in self.records:
                if not record.state.tracked:
                    continue
                T_ref = self._keyframe_pose(record.reference_kf)
                if T_ref is None:
                    continue
                stamps.append(record.timestamp)
                poses.append(se3_inverse(record.T_frame_ref @ T_ref))
        return np.array(stamps), np.array(poses).reshape(-1, 4, 4)

    def _localise_frames_before_start(self) -> None:
        """Give a pose to the frames that came while the parallax to the initial reference grew
        (a hovering start can take seconds). They are tracked outward in time from the earliest
        keyframe, each from the one localised before it with the constant-velocity model and the
        local map, falling back to relocalisation against that keyframe. Tracking's state (reference keyframe,
        last frame, velocity) is left alone."""
        waiting = [(index, features) for index, features in self._before_start if self.records[index].state == TrackingState.NOT_INITIALIZED]
        self._before_start.clear()
        if not waiting or not self.map.keyframes:
            return
        anchor = min(self.map.keyframes.values(), key=lambda kf: kf.timestamp)
        later = [item for item in waiting if self.records[item[0]].timestamp > anchor.timestamp]
        earlier = [item for item in reversed(waiting) if self.records[item[0]].timestamp < anchor.timestamp]
        for sweep in (later, earlier):
            behind = [_TrackedFrame(anchor.timestamp, anchor.features, anchor.T_cw.copy(), anchor.point_ids.copy())]
            for index, features in sweep:
                record = self.records[index]
                located = self._follow_sweep(behind, features, anchor)
                if located is None:
                    continue
                behind = [behind[-1], _TrackedFrame(record.timestamp, features, located[0], located[1])]
                # the map is final: any keyframe can carry the pose
                record.reference_kf, record.T_frame_ref, record.state = anchor.id, located[0] @ se3_inverse(anchor.T_cw), TrackingState.OK

    def _follow_sweep(self, behind: list[_TrackedFrame], features: Features, anchor: KeyFrame) -> tuple[np.ndarray, np.ndarray] | None:
        """One frame of the start's sweep: ``(T_cw, matched)`` or None."""
        last = behind[-1]
        T_pred = last.T_cw if len(behind) < 2 else last.T_cw @ se3_inverse(behind[0].T_cw) @ last.T_cw
        matched = np.full(len(features), -1)
        T_cw = self._track_from(last, T_pred, features, matched)
        if T_cw is not None:
            T_cw, inliers, _ = self._track_local_map(features, matched, T_cw)
            if inliers >= self.settings.min_tracked_inliers:
                return T_cw, matched
        found = self._localise(features, anchor)
        return None if found is None else found[:2]

    # --- initialisation ---------------------------------------------------------------------

    def _initialise(self, frame: Frame, features: Features) -> np.ndarray | None:
        s = self.settings
        reference = self._init_reference
        if reference is None or len(features) < s.init_min_matches:
            if len(features) >= s.init_min_matches:
                self._init_reference = self._reference_here(features)
            return None
        ref = reference.features
        radius = s.init_search_radius_px * self.extractor.window_stretch(ref.lens_jacobian)
        rows, cols = match_in_window(ref.descriptors, ref.un_px, features.descriptors, features.un_px, radius, TH_LOW, 0.9)
        keep = rotation_consistent(ref.angle[rows], features.angle[cols])
        rows, cols = rows[keep], cols[keep]
        if len(rows) < s.init_min_matches:
            self._init_reference = self._reference_here(features)
            return None
        expiring = reference.expiring(len(rows), s.init_min_matches)
        candidate = two_view_candidate(
            ref.normalised[rows], features.normalised[cols], self.camera.fx, s.init_min_triangulated, s.homography_ratio, parallel=self.scheduler.parallel
        )
        if candidate is None:
            reference.last_attempt = None  # a peak is judged between consecutive tries
            return None
        attempt = _InitAttempt(candidate, rows, cols, features, len(self.records), frame.timestamp)  # this frame's record comes next
        peak = reference.past_peak(attempt, s.init_min_triangulated, s.init_min_matches)
        if peak is not None and self._start_map(reference, peak, lowered=True):
            return self._track(frame.timestamp, features)
        if not self._start_map(reference, attempt, lowered=expiring):
            return None
        return self._last.T_cw.copy()

    def _start_map(self, reference: _InitReference, attempt: _InitAttempt, lowered: bool) -> bool:
        """The initial map from the reference and an attempt whose parallax is enough: the nominal
        slam.init_min_parallax_deg, or when ``lowered`` (this is the most parallax the reference
        will give) EXPIRING_MIN_PARALLAX_DEG made up by more points. Tracking then continues from
        the attempt's frame."""
        s = self.settings
        ref, rows, cols = reference.features, attempt.rows, attempt.cols
        min_parallax = min(s.init_min_parallax_deg, EXPIRING_MIN_PARALLAX_DEG) if lowered else s.init_min_parallax_deg
        result = complete_two_view(attempt.candidate, ref.normalised[rows], attempt.features.normalised[cols], self.camera.fx, min_parallax, s.init_min_triangulated)
        if result is None or result.good.sum() < s.init_min_triangulated:
            return False
        if lowered and result.parallax_deg * np.sqrt(result.good.sum()) < s.init_min_parallax_deg * np.sqrt(s.init_min_triangulated):
            return False  # the lower parallax must be made up by more points
        kf0 = self.map.add_keyframe(self.records[reference.record].timestamp, np.eye(4), ref, self._bow(ref))
        kf1 = self.map.add_keyframe(attempt.timestamp, result.T21, attempt.features, self._bow(attempt.features))
        for a, b, position in zip(rows[result.good], cols[result.good], result.points[result.good], strict=True):
            point = self.map.add_point(position, ref.descriptors[a], kf0.id)
            self.map.add_observation(point, kf0, int(a))
            self.map.add_observation(point, kf1, int(b))
        adjust_whole_map(self.map, self.extractor.scale_factors, self.K, evaluations=20)
        depth = self.map.median_depth(kf0)
        if not depth > 0 or len(self.map.points) < s.init_min_triangulated:
            self._discard_map()
            return False
        self._rescale(s.initial_median_depth_m / depth)
        self.map.refresh_points(list(self.map.points), self.extractor.scale_factors)
        self.map.update_covisibility(kf0)
        self.map.update_covisibility(kf1)
        for record, keyframe in ((reference.record, kf0), (attempt.record, kf1)):
            if record < len(self.records):  # the current frame's record is written with its answer
                self.records[record].reference_kf, self.records[record].T_frame_ref, self.records[record].state = keyframe.id, np.eye(4), TrackingState.OK
        self._init_reference = None
        self._reference_kf = kf1.id
        self._last_kf_frame = self._frame_count
        self._last_kf_time = attempt.timestamp
        self._velocity = None
        self._last = _TrackedFrame(attempt.timestamp, attempt.features, kf1.T_cw.copy(), kf1.point_ids.copy())
        self._last_inliers = int((kf1.point_ids >= 0).sum())
        self.state = TrackingState.OK
        return True

    def _reference_here(self, features: Features) -> _InitReference:
        return _InitReference(features, len(self.records))  # this frame's record comes next

    def _bow(self, features: Features) -> BowVector:
        return self.vocabulary.transform(features.descriptors)

    def _rescale(self, factor: float) -> None:
        for kf in self.map.keyframes.values():
            T = kf.T_cw.copy()
            T[:3, 3] *= factor
            kf.set_pose(T)
        for point in self.map.points.values():
            point.position *= factor

    def _discard_map(self) -> None:
        for kf_id in list(self.map.keyframes):
            self.map.remove_keyframe(kf_id)
        self.map.remove_all_points()

    def _restart(self) -> None:
        """Tracking lost a map of a few keyframes: the start was wrong (too few points, or a
        climb along the optical axis with too little parallax), and relocalising against it
        rarely succeeds. ORB-SLAM resets such a map; so does this, and initialises again. The
        frames tracked in it leave the trajectory (they had that map's scale and frame)."""
        self._discard_map()
        self.state = TrackingState.NOT_INITIALIZED
        self._init_reference = None
        self._last = None
        self._feature_budget = STARVED_FEATURE_BUDGET
        self.reset_counter += 1

    # --- tracking -------------------------------------------------------------------------

    def _track(self, timestamp: float, features: Features) -> np.ndarray | None:
        self._follow_reference_keyframe()
        self._rotation_prior = self._gyro_prior(timestamp)
        try:
            T_cw = self._track_with_prior(timestamp, features)
        finally:
            prior, self._rotation_prior = self._rotation_prior, None
        if self.gyro is not None:  # what the next frame's prior inherits; nothing to carry without a gyro
            self._rotation_covariance = None if T_cw is None else self._rotation_posterior(T_cw, prior)
        return T_cw

    def _gyro_prior(self, timestamp: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame's rotation as the gyro turns the last frame's, and its information: the
        gyro's uncertainty plus the last frame's own (the prior inherits that frame's error), so
        the gyro's 0.02 degrees a frame do not override a map that fixes rotation better, nor hold
        a frame to a last one that was itself uncertain. The information is zero while the last
        frame's uncertainty is unknown (the first frame after a start or a relocalisation): the
        gyro then only predicts."""
        measured = self.gyro.between(self._last.timestamp, timestamp) if self.gyro is not None else None
        if measured is None:
            return None
        R = measured.R_c1_c0
        if self._rotation_covariance is None:
            return R @ self._last.T_cw[:3, :3], np.zeros((3, 3))
        covariance = R @ self._rotation_covariance @ R.T + np.linalg.inv(measured.information)
        return R @ self._last.T_cw[:3, :3], np.linalg.inv(covariance)

    def _rotation_posterior(self, T_cw: np.ndarray, prior: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray | None:
        """The tracked rotation's covariance (3x3, rad^2): what its inliers fix, with the gyro's
        prior when there was one (information adds); None when it cannot be said."""
        rows = np.flatnonzero(self._last.point_ids >= 0)
        if len(rows) < 6:
            return None
        features = self._last.features
        lens = None if features.lens_jacobian is None else features.lens_jacobian[rows]
        covariance = rotation_covariance(T_cw, self.map.store.position[self._last.point_ids[rows]], self.extractor.inv_level_sigma2[features.octave[rows]], self.K, lens)
        if covariance is None or prior is None:
            return covariance
        return np.linalg.inv(np.linalg.inv(covariance) + prior[1])

    def _track_with_prior(self, timestamp: float, features: Features) -> np.ndarray | None:
        matched = np.full(len(features), -1)
        T_cw = None
        if self._velocity is not None:
            T_cw = self._track_motion_model(timestamp, features, matched)
            if T_cw is None:
                matched[:] = -1
                T_cw = self._track_prediction_in_local_map(timestamp, features, matched)
        if T_cw is None:
            matched[:] = -1
            T_cw = self._track_reference_keyframe(features, matched)
        if T_cw is not None:
            T_cw, inliers, reference = self._track_local_map(features, matched, T_cw)
            if reference is not None:
                self._reference_kf = reference
            needed = self.settings.min_relocalised_inliers if self._frame_count - self._last_reloc_frame < 30 else self.settings.min_tracked_inliers
            if inliers < needed:
                T_cw = None
        if T_cw is None:
            self.state = TrackingState.LOST
            self._velocity = None
            if len(self.map.keyframes) <= self.settings.restart_max_keyframes:
                self._restart()
            return None
        self._velocity = T_cw @ se3_inverse(self._last.T_cw)
        self._velocity_dt = timestamp - self._last.timestamp
        self._last_inliers = inliers
        self._budget_features(inliers, len(features))
        self._last = _TrackedFrame(timestamp, features, T_cw, matched.copy())
        if self._need_keyframe(inliers, timestamp, T_cw, matched):
            self._insert_keyframe(timestamp, features, T_cw, matched)
        return T_cw

    def _depth_changed(self, T_cw: np.ndarray, matched: np.ndarray, reference: KeyFrame) -> bool:
        """Whether the tracked points' median depth differs from the reference keyframe's by more
        than ``slam.keyframe_depth_change`` (relative): the camera moved along its axis."""
        ratio = self._tracked_depth(T_cw, matched) / self.map.median_depth(reference)
        return bool(np.isfinite(ratio)) and abs(np.log(ratio)) > np.log1p(self.settings.keyframe_depth_change)

    def _tracked_depth(self, T_cw: np.ndarray, matched: np.ndarray) -> float:
        """Median depth (map units) of the map points a frame matched; NaN when it matched none."""
        rows = np.flatnonzero(matched >= 0)
        if len(rows) == 0:
            return float("nan")
        positions, _ = self._map_point_arrays(matched[rows])
        return float(np.median(positions @ T_cw[2, :3] + T_cw[2, 3]))

    def _budget_features(self, inliers: int, features: int) -> None:
        """More features for the next frame while tracking is starved (they multiply what it
        can match and what its keyframe triangulates); back to the configured count once the
        inliers, scaled to that count, are over the starved line (a small image that has fewer
        corners than the budget goes back at once)."""
        line = STARVED_INLIER_FACTOR * self.settings.min_tracked_inliers
        if inliers < line:
            self._feature_budget = STARVED_FEATURE_BUDGET
        elif inliers * min(1.0, self.extractor.settings.n_features / max(features, 1)) > line:
            self._feature_budget = 1

    def _follow_reference_keyframe(self) -> None:
        """The last frame moves with its reference keyframe (ORB-SLAM's UpdateLastFrame): since
        it was tracked, bundle adjustment or a loop correction may have moved the map, and the
        motion model must predict in the map as it is now. Left behind, the last pose puts the
        map's shift into the velocity, which the next frames then repeat."""
        record = self.records[-1] if self.records else None
        if record is None or record.timestamp != self._last.timestamp or record.reference_kf < 0:
            return
        T_ref = self._keyframe_pose(record.reference_kf)
        if T_ref is not None:
            self._last.T_cw = record.T_frame_ref @ T_ref

    def _map_point_arrays(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.map.store.position[ids], self.map.store.descriptor[ids]

    def _optimise(self, features: Features, matched: np.ndarray, T_cw: np.ndarray) -> tuple[np.ndarray, int]:
        """Pose-only optimisation on the current matches; outliers are unmatched."""
        rows = np.flatnonzero(matched >= 0)
        if len(rows) < 6:
            return T_cw, 0
        positions, _ = self._map_point_arrays(matched[rows])
        inv_sigma2 = self.extractor.inv_level_sigma2[features.octave[rows]]
        lens = None if features.lens_jacobian is None else features.lens_jacobian[rows]
        T_cw, inlier = optimise_pose(T_cw, positions, features.un_px[rows], inv_sigma2, self.K, lens, rotation_prior=self._rotation_prior)
        matched[rows[~inlier]] = -1
        return T_cw, int(inlier.sum())

    def _track_motion_model(self, timestamp: float, features: Features, matched: np.ndarray) -> np.ndarray | None:
        last = self._last
        return self._track_from(last, self._predicted_pose(timestamp), features, matched)

    def _track_from(self, last: _TrackedFrame, T_pred: np.ndarray, features: Features, matched: np.ndarray) -> np.ndarray | None:
        """Guided search for the points ``last`` tracked around their projection at ``T_pred``,
        then pose optimisation."""
        rows_last = self.map.rows_with_points(last.point_ids)
        if len(rows_last) < 10:
            return None
        ids = last.point_ids[rows_last]
        positions, descriptors = self._map_point_arrays(ids)
        pc = positions @ T_pred[:3, :3].T + T_pred[:3, 3]
        front = pc[:, 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.c_[self.K[0, 0] * pc[:, 0] / pc[:, 2] + self.K[0, 2], self.K[1, 1] * pc[:, 1] / pc[:, 2] + self.K[1, 2]]
        octave = last.features.octave[rows_last]
        stretch = projected_stretch(self.extractor, np.where(front[:, None], uv, self.K[:2, 2]))  # behind the camera: not searched
        for widen in (1.0, 2.0):
            radius = widen * self.settings.motion_search_radius_px * self.extractor.scale_factors[octave] * stretch
            a, b = match_in_window(
                descriptors[front], uv[front], features.descriptors, features.un_px, radius[front], TH_HIGH, 0.9, octave[front], features.octave
            )
            keep = rotation_consistent(last.features.angle[rows_last][front][a], features.angle[b])
            a, b = a[keep], b[keep]
            if len(a) >= 20:
                break
        if len(a) < 20:
            return None
        matched[b] = ids[front][a]
        T_cw, inliers = self._optimise(features, matched, T_pred)
        return T_cw if inliers >= 10 else None

    def _predicted_pose(self, timestamp: float) -> np.ndarray:
        """The motion model's pose at ``timestamp``: the camera where the constant velocity puts
        it, turned as the gyro says when it says."""
        return self._gyro_turned(self._predicted_motion(timestamp - self._last.timestamp) @ self._last.T_cw)

    def _gyro_turned(self, T_cw: np.ndarray) -> np.ndarray:
        """``T_cw`` with the gyro's rotation for the frame being tracked (its centre kept), or as
        it is without one."""
        if self._rotation_prior is None:
            return T_cw
        R_cw = self._rotation_prior[0]
        centre = -T_cw[:3, :3].T @ T_cw[:3, 3]
        turned = np.eye(4)
        turned[:3, :3] = R_cw
        turned[:3, 3] = -R_cw @ centre
        return turned

    def _predicted_motion(self, dt: float) -> np.ndarray:
        """Constant velocity over ``dt``: a live stream drops frames, so the last motion is
        stretched to the time since the last tracked frame (at most 10 times; never backwards,
        should a caller repeat a timestamp)."""
        if self._velocity_dt <= 0 or abs(dt - self._velocity_dt) < 0.05 * self._velocity_dt:
            return self._velocity
        return scale_motion(self._velocity, float(np.clip(dt / self._velocity_dt, 0.0, 10.0)))

    def _track_reference_keyframe(self, features: Features, matched: np.ndarray) -> np.ndarray | None:
        kf = self.map.keyframes.get(self._reference_kf)
        if kf is None:
            kf = self.map.keyframes[max(self.map.keyframes)]
            self._reference_kf = kf.id
        rows = self.map.rows_with_points(kf.point_ids)
        if len(rows) < 15:
            return None
        a, b = match_descriptors(kf.features.descriptors[rows], features.descriptors, TH_LOW, 0.7)
        keep = rotation_consistent(kf.features.angle[rows][a], features.angle[b])
        a, b = a[keep], b[keep]
        if len(a) < 15:
            return None
        matched[b] = kf.point_ids[rows][a]
        T_cw, inliers = self._optimise(features, matched, self._gyro_turned(self._last.T_cw))
        return T_cw if inliers >= 10 else None

    def _local_keyframes(self, matched: np.ndarray) -> list[int]:
        """Keyframes sharing the frame's matched points, most shared first, then their best
        covisible neighbours."""
        points = self.map.points
        votes = Counter(chain.from_iterable(points[p].observations for p in matched[matched >= 0].tolist() if p in points))
        if not votes:
            return []
        first = sorted(votes, key=lambda k: -votes[k])[:40]
        local = list(first)
        seen = set(local)
        for kf_id in first:
            kf = self.map.keyframes.get(kf_id)
            if kf is None:
                continue
            for neighbour in kf.best_covisible(10):
                if neighbour not in seen and neighbour in self.map.keyframes:
                    seen.add(neighbour)
                    local.append(neighbour)
            if len(local) >= 80:
                break
        return [k for k in local if k in self.map.keyframes]

    def _unmatched_local_points(self, local: list[int], matched: np.ndarray) -> np.ndarray:
        """Ids, ascending, of the points the local keyframes see that the frame has not matched
        (a mask over the point store: cheaper than sorting the keyframes' tens of thousands of ids)."""
        if not local:
            return np.zeros(0, int)
        seen = np.concatenate([self.map.keyframes[k].point_ids for k in local])
        wanted = np.zeros(len(self.map.store.position), bool)
        wanted[seen[seen >= 0]] = True  # keyframes' point ids always name live points (the Map keeps them in step)
        wanted[matched[matched >= 0]] = False
        return np.flatnonzero(wanted)

    def _track_prediction_in_local_map(self, timestamp: float, features: Features, matched: np.ndarray) -> np.ndarray | None:
        """The motion model found too few of the last frame's points (the step was long: fast
        forward motion, a low frame rate, dropped frames, where most points change scale or leave
        the view between frames), but the prediction is still the best pose there is: the local
        map around the last frame, thousands of points seen by several keyframes, is searched at
        the predicted pose with the motion model's window. ORB-SLAM goes from the motion model to
        the reference keyframe's bag of words, which a step like that defeats as well."""
        T_pred = self._predicted_pose(timestamp)
        local = self._local_keyframes(self._last.point_ids)
        T_cw, inliers = self._search_local_map(features, matched, T_pred, local, self.settings.motion_search_radius_px)
        return T_cw if inliers >= self.settings.min_tracked_inliers else None

    def _track_local_map(self, features: Features, matched: np.ndarray, T_cw: np.ndarray) -> tuple[np.ndarray, int, int | None]:
        """``(T_cw, inliers, the keyframe sharing most points with the frame)`` (ORB-SLAM's
        reference keyframe; None without matches)."""
        local = self._local_keyframes(matched)
        T_cw, inliers = self._search_local_map(features, matched, T_cw, local, self.settings.local_map_search_radius_px)
        return T_cw, inliers, (local[0] if local else None)

    def _search_local_map(self, features: Features, matched: np.ndarray, T_cw: np.ndarray, local: list[int], radius_px: float) -> tuple[np.ndarray, int]:
        """Match the local keyframes' points the frame has not matched yet around their
        projection at ``T_cw`` (``radius_px`` at the finest level, 2.5/4 of it for points seen
        head-on), then optimise the pose on all matches."""
        ids = self._unmatched_local_points(local, matched)
        projection = project_points(self.map, ids, T_cw, self.extractor, self.K, self.bounds)
        if projection is not None:
            candidates = ids[projection.rows]
            for point_id in candidates.tolist():
                self.map.points[point_id].visible += 1
            free = np.flatnonzero(matched < 0)
            descriptors = self.map.store.descriptor[candidates]
            radius = np.where(projection.view_cos > 0.998, 2.5, 4.0) * radius_px / 4.0 * self.extractor.scale_factors[projection.level] * projection.stretch
            a, b = match_in_window(
                descriptors, projection.uv, features.descriptors[free], features.un_px[free], radius, TH_HIGH, 0.8, projection.level, features.octave[free]
            )
            matched[free[b]] = candidates[a]
        T_cw, inliers = self._optimise(features, matched, T_cw)
        for point_id in matched[matched >= 0]:
            point = self.map.points.get(int(point_id))
            if point is not None:
                point.found += 1
        return T_cw, inliers

    # --- keyframes --------------------------------------------------------------------------

    def _need_keyframe(self, inliers: int, timestamp: float, T_cw: np.ndarray, matched: np.ndarray) -> bool:
        s = self.settings
        n_kfs = len(self.map.keyframes)
        since_kf = self._frame_count - self._last_kf_frame
        if self._frame_count - self._last_reloc_frame < s.keyframe_max_frames and n_kfs > s.keyframe_max_frames:
            return False
        reference = self.map.keyframes.get(self._reference_kf)
        min_obs = 3 if n_kfs > 2 else 2
        ref_matches = 0
        if reference is not None:
            for point_id in reference.point_ids[reference.point_ids >= 0]:
                point = self.map.points.get(int(point_id))
                ref_matches += point is not None and len(point.observations) >= min_obs
        mapper_free = self.mapping.idle
        idle = mapper_free and timestamp - self._last_kf_time >= s.keyframe_min_interval_s
        weak = inliers < 0.5 * ref_matches  # the map is slipping away (fast forward motion)
        c1 = since_kf >= s.keyframe_max_frames or idle or weak
        if not c1:
            return False
        # ORB-SLAM's share rule, or the camera moved along its axis (asked last: its median is not free)
        c2 = inliers > 15 and (inliers < s.keyframe_ref_ratio * ref_matches or (reference is not None and self._depth_changed(T_cw, matched, reference)))
        if not c2:
            return False
        if not mapper_free:
            self.mapping.interrupt()  # ORB-SLAM's InterruptBA: the mapper comes free for a next frame
        # a busy mapper still takes a keyframe when tracking is weak, one at a time
        return idle or (weak and self.mapping.pending == 0)

    def _insert_keyframe(self, timestamp: float, features: Features, T_cw: np.ndarray, matched: np.ndarray) -> None:
        kf = self.map.add_keyframe(timestamp, T_cw, features, self._bow(features))
        self._reference_kf = kf.id
        self._last_kf_frame = self._frame_count
        self._last_kf_time = timestamp
        self.mapping.submit(NewKeyFrame(kf, matched.copy()))

    # --- relocalisation ---------------------------------------------------------------------

    def _relocalise(self, timestamp: float, features: Features) -> np.ndarray | None:
        if not self.map.keyframes or len(features) < 20:
            return None
        for kf_id in self.map.database.relocalisation_candidates(self._bow(features), self.map.keyframes, RELOCALISATION_CANDIDATES):
            T_cw = self._relocalise_against(timestamp, features, self.map.keyframes[kf_id])
            if T_cw is not None:
                if self.saved_map is not None and self.saved_map.relocalised_at is None:
                    self.saved_map.relocalised_at = timestamp
                self.state = TrackingState.RELOCALIZED
                self.reset_counter += 1
                self._last_reloc_frame = self._frame_count
                self._reference_kf = kf_id
                self._velocity = None
                return T_cw
        return None

    def _relocalise_against(self, timestamp: float, features: Features, kf: KeyFrame) -> np.ndarray | None:
        found = self._localise(features, kf)
        if found is None:
            return None
        T_cw, matched, count = found
        self._last = _TrackedFrame(timestamp, features, T_cw, matched)
        self._last_inliers = count
        return T_cw

    def _localise(self, features: Features, kf: KeyFrame) -> tuple[np.ndarray, np.ndarray, int] | None:
        """Pose from scratch near a keyframe: descriptor matches to its points, PnP RANSAC, pose
        optimisation, then the local map; ``(T_cw, matched point per feature, inliers)``."""
        rows = self.map.rows_with_points(kf.point_ids)
        if len(rows) < 15:
            return None
        a, b = match_descriptors(kf.features.descriptors[rows], features.descriptors, TH_LOW, 0.75)
        if len(a) < 15:
            return None
        ids = kf.point_ids[rows][a]
        positions, _ = self._map_point_arrays(ids)
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            positions, features.un_px[b], self.K, None, iterationsCount=300, reprojectionError=4.0, confidence=0.99, flags=cv2.SOLVEPNP_EPNP
        )
        if not ok or inliers is None or len(inliers) < 10:
            return None
        T_cw = np.eye(4)
        T_cw[:3, :3], T_cw[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
        matched = np.full(len(features), -1)
        matched[b[inliers.ravel()]] = ids[inliers.ravel()]
        T_cw, count = self._optimise(features, matched, T_cw)
        if count < 10:
            return None
        T_cw, count, _ = self._track_local_map(features, matched, T_cw)
        if count < self.settings.min_relocalised_inliers:
            return None
        return T_cw, matched, count

    def _give_up_saved_map(self, timestamp: float) -> None:
        """Still not relocalised in the saved map ``slam.map_relocalise_timeout_s`` after the first
        frame: the vehicle is somewhere the map does not cover. The saved map is dropped and a new
        one initialised (a reset for consumers: its frame and scale are new)."""
        saved = self.saved_map
        if saved is None or saved.relocalised_at is not None or saved.fell_back_at is not None:
            return
        first = self.records[0].timestamp if self.records else timestamp
        if timestamp - first < self.settings.map_relocalise_timeout_s:
            return
        saved.fell_back_at = timestamp
        self._restart()

    # --- answers ----------------------------------------------------------------------------

    def _answer(self, frame: Frame, T_cw: np.ndarray | None) -> PoseEstimate:
        state = self.state
        if T_cw is None:
            if state != TrackingState.NOT_INITIALIZED:
                state = self.state = TrackingState.LOST
            T_world_cam = se3_inverse(self._last.T_cw) if self._last is not None else np.eye(4)
            self.records.append(_FrameRecord(frame.timestamp, -1, np.eye(4), state))
            return PoseEstimate(frame.timestamp, T_world_cam, state, 0)
        reference = self.map.keyframes.get(self._reference_kf)
        T_ref = reference.T_cw if reference is not None else np.eye(4)
        self.records.append(_FrameRecord(frame.timestamp, self._reference_kf if reference is not None else -1, T_cw @ se3_inverse(T_ref), state))
        if state == TrackingState.RELOCALIZED:
            self.state = TrackingState.OK
        quality = int(min(100, 100 * self._last_inliers / max(1, self.extractor.settings.n_features // 4)))
        return PoseEstimate(frame.timestamp, se3_inverse(T_cw), state, quality, scene_depth=self._scene_depth(frame.timestamp, reference))

    def _scene_depth(self, timestamp: float, reference: KeyFrame | None) -> float | None:
        """The reference keyframe's median depth; a keyframe made on this very frame is mapped
        before the next one (its points are not yet its own), so then this frame's matched points'."""
        depth = self.map.median_depth(reference) if reference is not None else float("nan")
        if not np.isfinite(depth) and self._last is not None and self._last.timestamp == timestamp:
            depth = self._tracked_depth(self._last.T_cw, self._last.point_ids)
        return float(depth) if np.isfinite(depth) else None

    def _keyframe_pose(self, kf_id: int) -> np.ndarray | None:
        """``T_cw`` of a keyframe, through the parent chain of culled ones."""
        relative = np.eye(4)
        for _ in range(1000):
            kf = self.map.keyframes.get(kf_id)
            if kf is not None:
                return relative @ kf.T_cw
            if kf_id not in self.map.removed_parents:
                return None
            kf_id, T_child_parent = self.map.removed_parents[kf_id]
            relative = relative @ T_child_parent
        return None
