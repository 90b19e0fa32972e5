"""Core records that flow through EVP: sensor samples in, pose estimates and trajectories out, and
the camera model.

Every sensor sample and estimate is a frozen dataclass whose first field is ``timestamp`` in
seconds (float64) on the sensor's own clock. Units are SI and frames are named in the field names: ``T_world_cam`` is the
pose of the camera optical frame (x right, y down, z forward) in the world frame.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from evp.geometry.transforms import poses_from_xyz_quat, quat_xyzw_from_matrices


@dataclass(frozen=True)
class Frame:
    """One camera image. ``image`` is HxW (grey) or HxWx3 (BGR) uint8."""

    timestamp: float
    image: np.ndarray
    index: int = 0
    source: str = ""


@dataclass(frozen=True)
class ImuSample:
    """Gyro (rad/s) and specific force (m/s^2) in the IMU frame."""

    timestamp: float
    angular_velocity_rad_s: tuple[float, float, float]
    linear_acceleration_m_s2: tuple[float, float, float]


@dataclass(frozen=True)
class GpsFix:
    """WGS-84 fix; accuracies in metres (NaN when the receiver gives none): the vertical one
    1-sigma, the horizontal one the horizontal RMS error (east and north together: 1-sigma per
    axis times sqrt(2), about the 68 % radius a phone reports and what the simulator draws)."""

    timestamp: float
    latitude_deg: float
    longitude_deg: float
    altitude_m: float
    horizontal_accuracy_m: float = float("nan")
    vertical_accuracy_m: float = float("nan")


@dataclass(frozen=True)
class BaroSample:
    """Static pressure in pascals and, when the device gives it, its altitude estimate."""

    timestamp: float
    pressure_pa: float
    altitude_m: float = float("nan")


@dataclass(frozen=True)
class RangeSample:
    """Distance (m) measured by a range finder (sonar, laser) along its axis; NaN when out of range."""

    timestamp: float
    distance_m: float


@dataclass(frozen=True)
class BeaconRange:
    """Distance (m) from the vehicle to the fixed beacon ``beacon_id`` (radio time of flight, UWB);
    the beacons' surveyed positions are in ``Dataset.beacons``."""

    timestamp: float
    beacon_id: str
    range_m: float


@dataclass(frozen=True)
class WheelOdometry:
    """Wheel speeds (m/s, one per wheel) and, when known, body forward speed and yaw rate (positive
    turning left, counter-clockwise seen from above)."""

    timestamp: float
    wheel_speeds_m_s: tuple[float, ...]
    forward_speed_m_s: float = float("nan")
    yaw_rate_rad_s: float = float("nan")


@dataclass(frozen=True)
class EncoderCounts:
    """A robot's raw wheel encoder counters (one per wheel, left first; unsigned, wrapping at the
    counter's width) and, when it has one, its gyro's yaw rate (rad/s, counter-clockwise).
    :class:`evp.fusion.wheel_encoders.EncoderOdometry` turns successive ones into
    :class:`WheelOdometry`."""

    timestamp: float
    counts: tuple[int, ...]
    yaw_rate_rad_s: float = float("nan")


@dataclass(frozen=True)
class WifiScan:
    """Received signal strength (dBm) per access point (BSSID)."""

    timestamp: float
    rssi_dbm: dict[str, float] = field(default_factory=dict)


class TrackingState(enum.Enum):
    NOT_INITIALIZED = "NOT_INITIALIZED"
    OK = "OK"
    LOST = "LOST"
    RELOCALIZED = "RELOCALIZED"

    @property
    def tracked(self) -> bool:
        """Whether a pose in this state locates the camera (tracked, or found again after being
        lost); only such poses go into trajectories, counts of tracked frames and the vehicle's
        position output. Wire and database states are the member values:
        ``TrackingState(text).tracked``."""
        return self in (TrackingState.OK, TrackingState.RELOCALIZED)


@dataclass(frozen=True)
class PoseEstimate:
    """An estimator's answer for one frame.

    ``T_world_cam`` is 4x4 (camera-to-world). ``quality`` is 0..100 (MAVLink convention).
    ``covariance`` is 6x6 over (x, y, z, roll, pitch, yaw) in the world frame, when known.

    An estimator answers in its own frame and scale (``metric`` False). A navigation stage that
    makes the pose metric and gravity-aligned sets ``metric`` and keeps the estimator's pose in
    ``T_visual_cam``; ``scale_known`` says its scale's uncertainty is below the settings' bound,
    ``georeferenced`` that the world is ENU at a GPS origin, ``gps_trusted`` that GPS is being fused
    (the trust monitor finds it consistent); ``velocity`` is the stage's, in its world frame.
    ``scene_depth`` tells how far the tracked scene is, which a pose's error grows with.
    """

    timestamp: float
    T_world_cam: np.ndarray
    tracking_state: TrackingState
    quality: int = 0
    covariance: np.ndarray | None = None
    metric: bool = False
    scale_known: bool = False
    georeferenced: bool = False
    gps_trusted: bool = False
    T_visual_cam: np.ndarray | None = None
    velocity: np.ndarray | None = None  # m/s in the world frame, from a navigation stage
    velocity_covariance: np.ndarray | None = None  # 3x3, (m/s)^2, world frame
    scene_depth: float | None = None  # median depth of what the estimator tracked (its reference keyframe's points; a keyframe's own frame, its matched points), in its own units

    @property
    def visual_pose(self) -> np.ndarray:
        """The estimator's own pose (its frame and scale), whatever a stage made of it."""
        return self.T_world_cam if self.T_visual_cam is None else self.T_visual_cam


@dataclass(frozen=True)
class Trajectory:
    """N poses of a sensor in a world frame; ``timestamps`` is None for KITTI files without times
    (its file formats are in ``evp.io.trajectory``)."""

    positions: np.ndarray  # (N, 3) metres
    quats_xyzw: np.ndarray  # (N, 4) Hamilton, scalar last, unit norm
    timestamps: np.ndarray | None = None  # (N,) seconds
    name: str = ""

    def __post_init__(self) -> None:
        n = len(self.positions)
        if self.positions.shape != (n, 3) or self.quats_xyzw.shape != (n, 4):
            raise ValueError("positions must be (N, 3) and quaternions (N, 4)")
        if self.timestamps is not None and self.timestamps.shape != (n,):
            raise ValueError("timestamps must be (N,)")

    @staticmethod
    def from_poses(poses: np.ndarray, timestamps: np.ndarray | None = None, name: str = "") -> Trajectory:
        """From a stack of 4x4 poses."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 4, 4)
        stamps = None if timestamps is None else np.asarray(timestamps, dtype=float)
        return Trajectory(poses[:, :3, 3].copy(), quat_xyzw_from_matrices(poses[:, :3, :3]), stamps, name)

    def __len__(self) -> int:
        return len(self.positions)

    @property
    def poses(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world transforms."""
        return poses_from_xyz_quat(self.positions, self.quats_xyzw)

    @property
    def path_length(self) -> float:
        """Sum of the distances between consecutive positions (metres)."""
        if len(self) < 2:
            return 0.0
        return float(np.sum(np.linalg.norm(np.diff(self.positions, axis=0), axis=1)))

    @property
    def duration(self) -> float:
        if self.timestamps is None or len(self) < 2:
            return 0.0
        return float(self.timestamps[-1] - self.timestamps[0])

    def select(self, indices: np.ndarray) -> Trajectory:
        """The poses at the given indices (or boolean mask)."""
        stamps = None if self.timestamps is None else self.timestamps[indices]
        return Trajectory(self.positions[indices], self.quats_xyzw[indices], stamps, self.name)

    def with_timestamps(self, timestamps: np.ndarray) -> Trajectory:
        stamps = np.asarray(timestamps, dtype=float)
        if len(stamps) != len(self):
            raise ValueError(f"{len(stamps)} timestamps for {len(self)} poses")
        return Trajectory(self.positions, self.quats_xyzw, stamps, self.name)


class LensModel(enum.StrEnum):
    """How a camera maps rays to pixels.

    ``RADTAN``: pinhole with OpenCV's radial-tangential distortion (k1 k2 p1 p2 k3), and k4 k5 k6 in
    the denominator of the radial factor for its 8-coefficient rational model (ROS
    ``rational_polynomial``). ``EQUIDISTANT``: the Kannala-Brandt fisheye of OpenCV's cv2.fisheye,
    Kalibr's ``equidistant`` and ORB-SLAM3's ``KannalaBrandt8``: a ray at angle theta from the
    optical axis lands at radius theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) on
    the normalised image plane, which reaches 90 degrees and beyond where a pinhole cannot.

    A string enum, so a camera written to JSON (the wire's config, the station's snapshot) carries
    the name, as calibration files do.
    """

    RADTAN = "radtan"
    EQUIDISTANT = "equidistant"


@dataclass(frozen=True)
class CameraModel:
    """A camera's intrinsics and lens model (:class:`LensModel`): k1 k2 p1 p2 k3 k4 k5 k6 for
    ``RADTAN``, k1 k2 k3 k4 for ``EQUIDISTANT`` (whose p1 p2 k5 k6 stay 0).

    Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0). "Normalised"
    coordinates are those of an ideal pinhole on the z = 1 plane, what the SLAM geometry uses; a
    fisheye ray at 90 degrees or more from the axis has none (NaN), its :meth:`bearings` do.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    name: str = ""
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0
    lens: LensModel = LensModel.RADTAN

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"camera resolution must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        values = (self.fx, self.fy, self.cx, self.cy, self.k1, self.k2, self.p1, self.p2, self.k3, self.k4, self.k5, self.k6)
        if not all(np.isfinite(values)):
            raise ValueError("camera parameters must be finite numbers")
        object.__setattr__(self, "lens", LensModel(self.lens))  # also from its name ("equidistant")
        if self.lens is LensModel.EQUIDISTANT and any((self.p1, self.p2, self.k5, self.k6)):
            raise ValueError("an equidistant (fisheye) lens has coefficients k1..k4 only")

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def coefficients(self) -> dict[str, float]:
        """The lens model's coefficients by name, in OpenCV's order: k1 k2 p1 p2 k3 (and k4 k5 k6
        when the rational model is in use) for ``RADTAN``, k1 k2 k3 k4 for ``EQUIDISTANT``."""
        if self.lens is LensModel.EQUIDISTANT:
            names = ("k1", "k2", "k3", "k4")
        elif self._rational:
            names = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
        else:
            names = ("k1", "k2", "p1", "p2", "k3")
        return {name: getattr(self, name) for name in names}

    @property
    def distortion(self) -> np.ndarray:
        """The coefficient vector OpenCV takes with :attr:`K` for this lens: 5 (or 8, rational)
        for its pinhole functions when ``RADTAN``, 4 for its cv2.fisheye functions when
        ``EQUIDISTANT``."""
        return np.array(list(self.coefficients.values()))

    @property
    def _rational(self) -> bool:
        return bool(self.k4 or self.k5 or self.k6)

    @property
    def has_distortion(self) -> bool:
        """Whether pixels differ from an ideal pinhole's (always for a fisheye)."""
        return self.lens is LensModel.EQUIDISTANT or bool(np.any(self.distortion != 0.0))

    def _radial(self, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radtan's radial factor and its derivative with respect to r^2."""
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        d_radial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)
        if self._rational:
            denominator = 1.0 + r2 * (self.k4 + r2 * (self.k5 + r2 * self.k6))
            d_denominator = self.k4 + r2 * (2.0 * self.k5 + 3.0 * self.k6 * r2)
            d_radial = (d_radial * denominator - radial * d_denominator) / denominator**2
            radial = radial / denominator
        return radial, d_radial

    def _theta_d(self, theta: np.ndarray) -> np.ndarray:
        """Equidistant: distorted radius on the normalised plane of a ray theta from the axis."""
        t2 = theta * theta
        return theta * (1.0 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))

    def distort_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Apply the lens model to (N, 2) normalised image coordinates (z = 1 plane)."""
        if self.lens is LensModel.EQUIDISTANT:
            return self._distort_bearings(np.column_stack([xy, np.ones(len(xy))]))
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = self._radial(r2)[0]
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return np.stack([xd, yd], axis=1)

    def _distort_bearings(self, rays: np.ndarray) -> np.ndarray:
        """Equidistant: distorted normalised coordinates of (N, 3) rays in any direction."""
        r = np.hypot(rays[:, 0], rays[:, 1])
        theta = np.arctan2(r, rays[:, 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(r > 0, self._theta_d(theta) / r, 1.0 / rays[:, 2])
        return rays[:, :2] * scale[:, None]

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of (N, 3) points in the camera frame (must have z > 0 for a
        ``RADTAN`` lens; a fisheye takes any direction but the optical axis backwards)."""
        points_cam = np.atleast_2d(np.asarray(points_cam, dtype=float))
        if self.lens is LensModel.EQUIDISTANT:
            xy = self._distort_bearings(points_cam)
        else:
            xy = self.distort_normalized(points_cam[:, :2] / points_cam[:, 2:3])
        return np.stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy], axis=1)

    def _distorted_normalised(self, pixels: np.ndarray) -> np.ndarray:
        pixels = np.atleast_2d(np.asarray(pixels, dtype=float))
        return np.stack([(pixels[:, 0] - self.cx) / self.fx, (pixels[:, 1] - self.cy) / self.fy], axis=1)

    def undistort_points(self, pixels: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Normalised undistorted coordinates (N, 2) of (N, 2) distorted pixel coordinates (NaN for
        fisheye rays 90 degrees or more off the axis).

        Inverts the lens model by Newton's method with the analytic Jacobian (vectorised), which
        converges to machine precision in a few steps even for strong barrel distortion.
        """
        target = self._distorted_normalised(pixels)
        if self.lens is LensModel.EQUIDISTANT:
            rays = self._equidistant_bearings(target)
            with np.errstate(divide="ignore", invalid="ignore"):
                xy = rays[:, :2] / rays[:, 2:3]
            xy[rays[:, 2] <= 0.0] = np.nan
            return xy
        if not self.has_distortion:
            return target
        xy = target.copy()
        for _ in range(iterations):
            residual = self.distort_normalized(xy) - target
            j11, j12, j21, j22 = self._radtan_jacobian(xy)
            det = j11 * j22 - j12 * j21
            step_x = (j22 * residual[:, 0] - j12 * residual[:, 1]) / det
            step_y = (j11 * residual[:, 1] - j21 * residual[:, 0]) / det
            xy[:, 0] -= step_x
            xy[:, 1] -= step_y
            if np.max(np.abs(residual)) < 1e-15:
                break
        return xy

    def _radtan_jacobian(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Radtan: the entries j11 j12 j21 j22 of d(distorted) / d(undistorted) normalised coordinates."""
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial, d_radial = self._radial(r2)
        j11 = radial + 2.0 * x * x * d_radial + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        j12 = 2.0 * x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        j21 = 2.0 * x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        j22 = radial + 2.0 * y * y * d_radial + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return j11, j12, j21, j22

    def pixel_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2, 2) derivative of the detected (distorted) pixel with respect to the undistorted
        pinhole pixel (same K), at (N, 2) normalised undistorted coordinates: how the lens shrinks
        an error measured in undistorted pixels into the image a detector works on. Identity for a
        lens without distortion; for a fisheye, cos^2(theta) radially and theta / tan(theta)
        tangentially (0.25 and 0.6 at 60 degrees off the axis)."""
        if self.lens is LensModel.EQUIDISTANT:
            r = np.hypot(xy[:, 0], xy[:, 1])
            theta = np.arctan(r)
            t2 = theta * theta
            slope = 1.0 + t2 * (3.0 * self.k1 + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)))
            tiny = r < 1e-9  # on the axis: the limit, identity
            safe = np.where(tiny, 1.0, r)
            ratio = np.where(tiny, 1.0, self._theta_d(theta) / safe)  # distorted / undistorted radius
            d_ratio = np.where(tiny, 0.0, (slope / (1.0 + r * r) - ratio) / safe)  # d ratio / d r
            unit = xy / safe[:, None]
            j = ratio[:, None, None] * np.eye(2) + (d_ratio * r)[:, None, None] * unit[:, :, None] * unit[:, None, :]
        else:
            j11, j12, j21, j22 = self._radtan_jacobian(xy)
            j = np.stack([np.stack([j11, j12], axis=-1), np.stack([j21, j22], axis=-1)], axis=-2)
        scale = np.array([self.fx, self.fy])
        return j * scale[None, :, None] / scale[None, None, :]

    def _equidistant_bearings(self, distorted: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Unit rays (N, 3) of distorted normalised coordinates: theta from theta_d by Newton's
        method on the odd polynomial (started at theta_d, monotone over any real lens's field)."""
        theta_d = np.hypot(distorted[:, 0], distorted[:, 1])
        theta = theta_d.copy()
        for _ in range(iterations):
            t2 = theta * theta
            slope = 1.0 + t2 * (3.0 * self.k1 + t2 * (5.0 * self.k2 + t2 * (7.0 * self.k3 + t2 * 9.0 * self.k4)))
            residual = self._theta_d(theta) - theta_d
            theta = np.clip(theta - residual / slope, 0.0, np.pi)
            if np.max(np.abs(residual), initial=0.0) < 1e-15:
                break
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(theta_d > 0, np.sin(theta) / theta_d, 1.0)
        return np.column_stack([distorted * scale[:, None], np.cos(theta)])

    def border_pixels(self, per_side: int) -> np.ndarray:
        """(4 per_side, 2) pixel centres spaced along the image's four edges: where a lens's rays
        are furthest off the axis (the extremes of its undistorted coordinates and ray angles)."""
        w, h = self.width - 1, self.height - 1
        edge = np.linspace(0.0, 1.0, per_side)
        return np.r_[np.c_[edge * w, 0 * edge], np.c_[edge * w, 0 * edge + h], np.c_[0 * edge, edge * h], np.c_[0 * edge + w, edge * h]]

    def bearings(self, pixels: np.ndarray) -> np.ndarray:
        """Unit rays (N, 3) in the camera frame through (N, 2) distorted pixels; unlike normalised
        coordinates they stay finite for fisheye rays at 90 degrees from the axis and beyond."""
        if self.lens is LensModel.EQUIDISTANT:
            return self._equidistant_bearings(self._distorted_normalised(pixels))
        xy = self.undistort_points(pixels)
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def undistort_pixels(self, pixels: np.ndarray) -> np.ndarray:
        """Where (N, 2) distorted pixels would lie in an ideal pinhole image with the same K."""
        xy = self.undistort_points(pixels)
        return np.stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy], axis=1)

    def unproject(self, pixels: np.ndarray, depth: np.ndarray | float = 1.0) -> np.ndarray:
        """3-D points (N, 3) in the camera frame at the given depth (z) behind (N, 2) pixels."""
        xy = self.undistort_points(pixels)
        depth = np.broadcast_to(np.asarray(depth, dtype=float), (len(xy),))
        return np.stack([xy[:, 0] * depth, xy[:, 1] * depth, depth], axis=1)

    def scaled(self, width: int, height: int) -> CameraModel:
        """The same lens at another resolution (same field of view; distortion is unit-free).

        Uses the pixel-centre convention: a pixel edge at 0 stays at 0, so c' = (c + 0.5) s - 0.5.
        """
        sx = width / self.width
        sy = height / self.height
        return replace(
            self,
            width=width,
            height=height,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
        )

    def undistort_image(self, image: np.ndarray) -> np.ndarray:
        """The image resampled to an ideal pinhole camera with the same K (a fisheye's field
        beyond what that pinhole sees is cut off)."""
        if self.lens is LensModel.EQUIDISTANT:
            return cv2.fisheye.undistortImage(image, self.K, self.distortion, Knew=self.K)
        return cv2.undistort(image, self.K, self.distortion)
