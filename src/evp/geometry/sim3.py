"""Similarity transforms of 3-D space, ``x' = s R x + t``, in stacks (loop closing's algebra).

A monocular map drifts in scale as well as in pose, so a loop is corrected with a similarity and
keyframe poses are optimised as similarities (ORB-SLAM's Sim3). Arrays hold N transforms:
``s`` (N,), ``R`` (N, 3, 3), ``t`` (N, 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class Sim3:
    s: np.ndarray
    R: np.ndarray
    t: np.ndarray

    @staticmethod
    def from_se3(T: np.ndarray) -> Sim3:
        """Rigid transforms (N, 4, 4) or one (4, 4) as similarities of scale 1."""
        T = np.asarray(T).reshape(-1, 4, 4)
        return Sim3(np.ones(len(T)), T[:, :3, :3].copy(), T[:, :3, 3].copy())

    @staticmethod
    def one(s: float, R: np.ndarray, t: np.ndarray) -> Sim3:
        return Sim3(np.array([float(s)]), np.asarray(R, float)[None], np.asarray(t, float)[None])

    @staticmethod
    def stack(items: list[Sim3]) -> Sim3:
        """One stack of the given stacks, in order."""
        return Sim3(np.concatenate([a.s for a in items]), np.concatenate([a.R for a in items]), np.concatenate([a.t for a in items]))

    def __len__(self) -> int:
        return len(self.s)

    def __getitem__(self, index) -> Sim3:
        index = np.atleast_1d(np.arange(len(self))[index])
        return Sim3(self.s[index], self.R[index], self.t[index])

    def __matmul__(self, other: Sim3) -> Sim3:
        """Composition: ``(a @ b)(x) = a(b(x))``."""
        return Sim3(self.s * other.s, self.R @ other.R, self.s[:, None] * np.einsum("nij,nj->ni", self.R, other.t) + self.t)

    def inverse(self) -> Sim3:
        Rt = np.transpose(self.R, (0, 2, 1))
        return Sim3(1.0 / self.s, Rt, -np.einsum("nij,nj->ni", Rt, self.t) / self.s[:, None])

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Transform points (N, 3) by one similarity each (or all by a single one)."""
        return self.s[:, None] * np.einsum("nij,nj->ni", self.R, points) + self.t if len(self) > 1 else self.s[0] * points @ self.R[0].T + self.t[0]

    def to_se3(self) -> np.ndarray:
        """The rigid pose ``[R | t/s]`` (N, 4, 4): the same projections, the scale moved to the
        world (the keyframe pose ORB-SLAM keeps after a Sim3 correction)."""
        T = np.repeat(np.eye(4)[None], len(self), axis=0)
        T[:, :3, :3] = self.R
        T[:, :3, 3] = self.t / self.s[:, None]
        return T

    def log(self) -> np.ndarray:
        """(N, 7) rotation vector, translation, log scale: a small error vector for identity-near
        transforms (pose-graph residuals)."""
        return np.concatenate([Rotation.from_matrix(self.R).as_rotvec(), self.t, np.log(self.s)[:, None]], axis=1)

    @staticmethod
    def exp(xi: np.ndarray) -> Sim3:
        """Inverse of :meth:`log` (rotation vector, translation, log scale), per row."""
        xi = np.atleast_2d(xi)
        return Sim3(np.exp(xi[:, 6]), Rotation.from_rotvec(xi[:, :3]).as_matrix(), xi[:, 3:6].copy())
