"""The plane a trajectory lies in, for its top view and its in-plane ("horizontal") error.

Datasets disagree on which axis is up: EuRoC, GPS ENU and the simulator have z up, a KITTI or
TUM camera trajectory has y down, so x-y is a KITTI drive seen edge-on (a 1.2 m line for a 600 m
drive). ``auto`` picks the coordinate plane of the two axes along which the reference moves most,
and keeps the axes' names (x, y, z in the reference's frame, what a user can relate to); when
that plane keeps less than :data:`COORDINATE_PLANE_SHARE` of the motion (a path tilted to every
coordinate plane), it uses the principal plane of the positions (PCA) instead. A path that is
nearly a straight line holds no plane at all (which of its two small axes wins is noise: the first
60 m of KITTI 06 descend more than they swerve, so "most motion" picked y-z, a side view of the
car): it is drawn in its frame's ground plane, x-z when it runs along z (camera frames: z forward,
y down) and x-y otherwise (z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AXES = "xyz"
PLANES = ("auto", "xy", "xz", "yz")
# share of the positions' variance the chosen coordinate plane must hold before the principal
# plane is used instead: 90 % leaves a plane tilted by up to ~18 degrees on its coordinate axes
COORDINATE_PLANE_SHARE = 0.9
# a path whose second-largest variance is below 1 % of its largest (a sideways wander under 10 %
# of its length) is a line; KITTI 06's first 60 m: 0.04 %
LINE_VARIANCE_RATIO = 0.01


@dataclass(frozen=True)
class Plane:
    """A projection of 3-D positions to 2-D: ``basis`` (3, 2) columns, and the axes' labels."""

    name: str  # "xy", "xz", "yz" or "principal"
    basis: np.ndarray
    labels: tuple[str, str]

    def project(self, positions: np.ndarray) -> np.ndarray:
        return np.asarray(positions, float) @ self.basis


def coordinate_plane(name: str) -> Plane:
    first, second = (AXES.index(a) for a in name)
    basis = np.zeros((3, 2))
    basis[first, 0] = basis[second, 1] = 1.0
    return Plane(name, basis, (f"{name[0]} (m)", f"{name[1]} (m)"))


def motion_plane(positions: np.ndarray, choice: str = "auto") -> Plane:
    """The plane ``choice`` names, or for ``auto`` the one the positions move in (module doc)."""
    if choice != "auto":
        return coordinate_plane(choice)
    positions = np.asarray(positions, float).reshape(-1, 3)
    if len(positions) < 3:
        return coordinate_plane("xy")
    spread = positions.var(axis=0)
    total = float(spread.sum())
    if total == 0.0:
        return coordinate_plane("xy")
    order = np.argsort(spread)
    if spread[order[1]] < LINE_VARIANCE_RATIO * spread[order[2]]:
        return coordinate_plane("xz" if order[2] == 2 else "xy")
    kept = sorted(order[1:])  # drop the axis with the least motion
    if spread[kept].sum() >= COORDINATE_PLANE_SHARE * total:
        return coordinate_plane("".join(AXES[i] for i in kept))
    centred = positions - positions.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return Plane("principal", vt[:2].T.copy(), ("principal axis 1 (m)", "principal axis 2 (m)"))
