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

from collections import deque
from dataclasses import dataclass

import numpy as np

from evp.fusion.nav_state import so3_exp_many
from evp.fusion.preintegration import imu_spans, samples_between
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
    (rad/s): nothing estimates the bias here, so a rotation over dt carries bias_sigma * dt."""

    def __init__(self, R_imu_cam: np.ndarray, noise_density: float, bias_sigma: float):
        self.R_imu_cam = np.asarray(R_imu_cam, float)
        self.noise_density = float(noise_density)
        self.bias_sigma = float(bias_sigma)
        self._samples: deque[tuple[float, np.ndarray]] = deque()

    def add(self, sample: ImuSample) -> None:
        """One sample, in time order (one out of order is ignored: the rotation needs a chain)."""
        if self._samples and sample.timestamp <= self._samples[-1][0]:
            return
        rate = np.asarray(sample.angular_velocity_rad_s, float)
        if not np.all(np.isfinite(rate)):
            return
        self._samples.append((float(sample.timestamp), rate))
        while self._samples[-1][0] - self._samples[0][0] > KEEP_S:
            self._samples.popleft()

    def between(self, t0: float, t1: float) -> RotationPrior | None:
        """The camera's rotation from ``t0`` to ``t1``, or None when the samples do not span them."""
        if t1 <= t0 or len(self._samples) < 2:
            return None
        times = np.array([t for t, _ in self._samples])
        if not imu_spans(times, t0, t1):
            return None
        rates = np.array([w for _, w in self._samples])
        t, w, _ = samples_between(times, rates, rates, t0, t1)
        R_i0_i1 = np.eye(3)
        for step in so3_exp_many(0.5 * (w[:-1] + w[1:]) * np.diff(t)[:, None]):
            R_i0_i1 = R_i0_i1 @ step
        R_c0_c1 = self.R_imu_cam.T @ R_i0_i1 @ self.R_imu_cam
        dt = t1 - t0
        angle = float(rotation_angle(R_c0_c1))
        variance = self.noise_density**2 * dt + (self.bias_sigma * dt) ** 2 + (MOUNT_SIGMA_RAD * angle) ** 2
        return RotationPrior(R_c0_c1.T, np.eye(3) / variance)

