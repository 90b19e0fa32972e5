"""Bundle adjustment of a nadir photo survey, with the lens's radial distortion estimated.

The mosaic registration places each photo by a homography, which cannot model lens distortion or
relief: with a nominal camera from EXIF (no lens model) a few percent of barrel distortion bends
every homography, and the chain of them drifts in position and height. Here all photos are
adjusted together, as structure from motion does: 6-DoF camera poses and the 3-D ground points
matched between photos (tracks), with the project's bundle adjustment.

When the camera comes without a lens model, its radial coefficient k1 is estimated too: the
adjustment's robust reprojection cost, measured in the photos' own pixels, is minimised over k1
(a one-dimensional profile search, each step one bundle adjustment). The focal length stays as
given: over flat ground seen from above it trades exactly against height, so the photos cannot
tell it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from evp.geometry.two_view import CHI2_2DOF
from evp.slam.bundle_adjustment import BundleProblem, bundle_adjust
from evp.types import CameraModel

K1_SEARCH = (-0.25, 0.1)  # consumer lenses: barrel (negative) to mild pincushion
K1_TOLERANCE = 0.0005  # 0.05 % of the radial term at the image corner: half a pixel at 1200 px
MIN_TRACKS = 20  # fewer matched ground points: nothing worth adjusting, the given poses stand


@dataclass
class SurveyTracks:
    """Observations of ground points: photo index, track (point) index and pixel, one row each."""

    image_index: np.ndarray  # (N,)
    track_index: np.ndarray  # (N,)
    pixels: np.ndarray  # (N, 2) pixels as detected (distorted)

    @property
    def num_tracks(self) -> int:
        return int(self.track_index.max()) + 1 if len(self.track_index) else 0


def tracks_from_matches(keypoints: list[np.ndarray], matches: list[tuple[int, int, np.ndarray]]) -> SurveyTracks:
    """Tracks as the connected components of pairwise feature matches.

    ``keypoints[i]`` are photo i's pixels; each match entry ``(i, j, pairs)`` links keypoint
    ``pairs[:, 0]`` of photo i with ``pairs[:, 1]`` of photo j. A component that holds two
    keypoints of one photo is an ambiguous chain of matches and is dropped."""
    offsets = np.concatenate([[0], np.cumsum([len(k) for k in keypoints])])
    edges = np.vstack([np.column_stack([offsets[i] + pairs[:, 0], offsets[j] + pairs[:, 1]]) for i, j, pairs in matches] or [np.zeros((0, 2), int)])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(offsets[-1], offsets[-1]))
    _, component = connected_components(graph, directed=False)
    matched = np.unique(edges)
    image = np.searchsorted(offsets, matched, side="right") - 1
    track = component[matched]
    size = np.bincount(track)
    distinct_images = np.bincount(np.unique(np.column_stack([track, image]), axis=0)[:, 0], minlength=len(size))
    keep = size[track] == distinct_images[track]
    _, track_index = np.unique(track[keep], return_inverse=True)
    return SurveyTracks(image[keep], track_index, np.vstack(keypoints)[matched[keep]])


def _ground_intersections(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> np.ndarray:
    """Initial track points: the mean of where each observation's ray meets the ground (z = 0)."""
    rays_cam = camera.unproject(tracks.pixels)
    rays = np.einsum("nij,nj->ni", poses_wc[tracks.image_index, :3, :3], rays_cam)
    centres = poses_wc[tracks.image_index, :3, 3]
    depth = -centres[:, 2] / np.where(np.abs(rays[:, 2]) > 1e-9, rays[:, 2], -1e-9)
    hits = centres + rays * depth[:, None]
    counts = np.bincount(tracks.track_index, minlength=tracks.num_tracks)
    sums = np.stack([np.bincount(tracks.track_index, weights=hits[:, a], minlength=tracks.num_tracks) for a in range(3)], axis=1)
    return sums / counts[:, None]


def _adjust(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, float]:
    """Adjusted poses (camera-to-world) and the truncated reprojection cost, in the photos' own
    pixels, for one lens model. The bundle adjustment works on undistorted pixels; each
    observation's standard deviation there is the lens's local magnification, so that costs of
    different lens models compare."""
    xy = camera.undistort_points(tracks.pixels)
    r2 = np.sum(xy * xy, axis=1)
    radial, tangential = 1.0 + 3.0 * camera.k1 * r2, 1.0 + camera.k1 * r2  # d(distorted)/d(undistorted), k1 only
    sigma = 1.0 / np.sqrt(np.abs(radial * tangential))
    fixed = np.zeros(len(poses_wc), dtype=bool)
    fixed[0] = True  # the gauge: the first photo where the mosaic put it
    problem = BundleProblem(
        np.linalg.inv(poses_wc), _ground_intersections(camera, poses_wc, tracks), tracks.image_index, tracks.track_index,
        camera.undistort_pixels(tracks.pixels), sigma, fixed, camera.K,
    )  # fmt: skip
    poses_cw, _, chi2 = bundle_adjust(problem, evaluations=20, first_gate_chi2=np.inf)  # mosaic poses can be pixels off
    return np.linalg.inv(poses_cw), float(np.sum(np.minimum(chi2, CHI2_2DOF)))


def adjust_survey(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, CameraModel]:
    """Adjusted camera-to-world poses (P, 4, 4) and the lens they were adjusted with: the given
    camera when it has a lens model, else the camera with the k1 that fits the photos best.
    With fewer than ``MIN_TRACKS`` tracks the poses and the camera come back as given."""
    if tracks.num_tracks < MIN_TRACKS:
        return poses_wc, camera
    if camera.has_distortion:
        return _adjust(camera, poses_wc, tracks)[0], camera
    search = minimize_scalar(
        lambda k1: _adjust(replace(camera, k1=k1), poses_wc, tracks)[1], bounds=K1_SEARCH, method="bounded", options={"xatol": K1_TOLERANCE}
    )
    lens = replace(camera, k1=float(search.x), name=f"{camera.name or 'camera'}+k1")
    return _adjust(lens, poses_wc, tracks)[0], lens
