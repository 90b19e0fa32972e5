"""The camera's rotation between two frames from the gyro: a prior for tracking.

A monocular tracker fixes a frame's pose from the map points it sees. When they lie at similar
depths in a narrow view (a wall, a room seen by a hand-held phone), a small turn and a sideways
step move them alike: the pose optimisation trades one for the other, the keyframes' baselines
come out too short, their new points fail the parallax test and tracking is lost as the view
turns into the unseen side (the rendered hand-held pan lost 5-17 % of its frames so). The gyro
measures the turn directly, to a few hundredths of a degree between frames, so visual-inertial
trackers predict and constrain rotation with it (ORB-SLAM3's IMU prediction, VINS's and
OpenVINS's propagation); here the integrated rotation is a prior on the tracked rotation, weighed
by what the gyro's noise, an unknown bias and the mount's calibration leave of it.

Core: samples in, rotations out; the pipeline feeds the samples (``SlamSystem.observe``).
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right
from dataclasses import dataclass

import numpy as np

from evp.fusion.preintegration import imu_spans, readings_between, rotation_chain
from evp.geometry.transforms import rotation_angle
from evp.types import ImuSample

# How far back samples are kept: more than any gap tracking bridges with a prediction (a lost
# frame's successor is relocalised, not predicted), so the buffer stays a few hundred samples.
KEEP_S = 2.0
# A mount calibrated from the phone's case or a drawing is within a degree or two; a rotation
# theta integrated in the IMU frame and moved into a camera frame misaligned by e is off by about
# e * theta (the axis tilts by e). One degree, as a 1-sigma.
MOUNT_SIGMA_RAD = np.radians(1.0)


@dataclass(frozen=True)
class RotationPrior:
    """``R_c1_c0``: the camera's rotation from frame 0 to frame 1 (``R_cw1 = R_c1_c0 @ R_cw0``),
    and its information (3x3, per rad^2, on a left increment of ``R_cw1``)."""

    R_c1_c0: np.ndarray
    information: np.ndarray


class GyroRotations:
    """Gyro samples (in the IMU frame) turned into camera rotations between frame times.

    ``R_imu_cam``: the camera's orientation in the IMU frame (the mount); ``noise_density`` the
    gyro's white noise (rad/s/sqrt(Hz)) and ``bias_sigma`` the 1-sigma of its uncompensated bias
    (rad/s): nothing estimates the bias here, so a rotation over dt carries bias_sigma * dt.
    An interval with a gap over ``max_gap_s`` between its samples gets no prior."""

    def __init__(self, R_imu_cam: np.ndarray, noise_density: float, bias_sigma: float, max_gap_s: float = 0.1):
        self.R_imu_cam = np.asarray(R_imu_cam, float)
        self.noise_density = float(noise_density)
        self.bias_sigma = float(bias_sigma)
        self.max_gap_s = float(max_gap_s)  # samples further apart inside an interval: no prior (a turn across the gap is a guess)
        self._times: list[float] = []
        self._rates: list[tuple[float, float, float]] = []

    def add(self, sample: ImuSample) -> None:
        """One sample, in time order (one out of order is ignored: the rotation needs a chain)."""
        if self._times and sample.timestamp <= self._times[-1]:
            return
        rate = tuple(float(value) for value in sample.angular_velocity_rad_s)
        if not all(np.isfinite(rate)):
            return
        self._times.append(float(sample.timestamp))
        self._rates.append(rate)
        if self._times[-1] - self._times[0] > 2 * KEEP_S:  # trimmed now and then, not at every sample
            old = bisect_left(self._times, self._times[-1] - KEEP_S)
            del self._times[:old], self._rates[:old]

    def between(self, t0: float, t1: float) -> RotationPrior | None:
        """The camera's rotation from ``t0`` to ``t1``, or None when the samples do not span them.
        Only the samples around the interval are read (a frame's few, not the buffer's hundreds)."""
        first = max(bisect_right(self._times, t0) - 2, 0)  # two before t0: a period to measure at either end
        last = min(bisect_left(self._times, t1) + 2, len(self._times))
        times = np.array(self._times[first:last])
        if t1 <= t0 or len(times) < 2 or not imu_spans(times, t0, t1) or np.diff(times).max() > self.max_gap_s:
            return None
        t, w = readings_between(times, np.array(self._rates[first:last]), t0, t1)
        R_i0_i1 = rotation_chain(t, w, np.zeros(3))[0][-1]
        R_c0_c1 = self.R_imu_cam.T @ R_i0_i1 @ self.R_imu_cam
        dt = t1 - t0
        angle = float(rotation_angle(R_c0_c1))
        variance = self.noise_density**2 * dt + (self.bias_sigma * dt) ** 2 + (MOUNT_SIGMA_RAD * angle) ** 2
        return RotationPrior(R_c0_c1.T, np.eye(3) / variance)
