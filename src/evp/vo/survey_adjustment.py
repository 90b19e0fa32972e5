"""Bundle adjustment of a nadir photo survey, with the lens self-calibrated.

The mosaic registration places each photo by a homography, which cannot model lens distortion or
relief: with a nominal camera from EXIF (no lens model) a few percent of barrel distortion bends
every homography, and the chain of them drifts in position and height. Here all photos are
adjusted together, as structure from motion does: 6-DoF camera poses and the 3-D ground points
matched between photos (tracks), with the project's bundle adjustment.

When the camera comes without a lens model, the focal length and the radial coefficients k1, k2
are estimated too, as COLMAP and OpenSfM self-calibrate: they are variables of the one bundle
adjustment, beside the poses and points (``evp.optim.self_calibration``), held near the EXIF
camera by wide priors. Over perfectly flat ground the focal length trades against height; the
relief of real ground tells them apart, if weakly: on the Toledo survey the adjustment slides
along a long valley from EXIF's 693 px to f = 546 px, k1 = -0.065, k2 = 0.036 (0.79 of EXIF's;
the cost falls by only 6 % on the way; 1.63 m against GPS), in one
adjustment of ~40 iterations, where the Gauss-Newton search over the lens it replaced ran 31 whole
adjustments (f = 621 px, 1.80 m) and the Nelder-Mead search before it 91 (539 px, 1.70 m)
(bench/survey_self_calibration.py). The GPS heights over the ground suggest EXIF's focal length
to 2 %: the lens found is the one that fits the photos best along that valley, not the maker's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.self_calibration import SelfCalibrationProblem, self_calibrating_adjust
from evp.types import CameraModel, LensModel

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


def _adjust(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> np.ndarray:
    """Adjusted poses (camera-to-world) for a calibrated lens. The bundle adjustment works on
    undistorted pixels; each observation's standard deviation there is the lens's local
    magnification, as the detector's noise is isotropic in the photos' own pixels."""
    xy = camera.undistort_points(tracks.pixels)
    r2 = np.sum(xy * xy, axis=1)
    tangential = 1.0 + camera.k1 * r2 + camera.k2 * r2 * r2  # d(distorted)/d(undistorted) across and along the radius
    radial = 1.0 + 3.0 * camera.k1 * r2 + 5.0 * camera.k2 * r2 * r2
    sigma = 1.0 / np.sqrt(np.abs(radial * tangential))
    fixed = np.zeros(len(poses_wc), dtype=bool)
    fixed[0] = True  # the gauge: the first photo where the mosaic put it
    problem = BundleProblem(
        np.linalg.inv(poses_wc), _ground_intersections(camera, poses_wc, tracks), tracks.image_index, tracks.track_index,
        camera.undistort_pixels(tracks.pixels), sigma, fixed, camera.K,
    )  # fmt: skip
    poses_cw, _, _ = bundle_adjust(problem, evaluations=20, first_gate_chi2=np.inf)  # mosaic poses can be pixels off
    return np.linalg.inv(poses_cw)


def _self_calibrate(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, CameraModel]:
    """Adjusted poses (camera-to-world) and the camera with the focal length, k1 and k2 adjusted
    with them, in one bundle adjustment (``self_calibration``)."""
    fixed = np.zeros(len(poses_wc), dtype=bool)
    fixed[0] = True  # the gauge: the first photo where the mosaic put it
    problem = SelfCalibrationProblem(
        np.linalg.inv(poses_wc), _ground_intersections(camera, poses_wc, tracks), tracks.image_index, tracks.track_index, tracks.pixels, fixed, camera
    )  # fmt: skip
    poses_cw, lens, _ = self_calibrating_adjust(problem)
    return np.linalg.inv(poses_cw), replace(lens, name=f"{camera.name or 'camera'}+self-calibrated")


def adjust_survey(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, CameraModel]:
    """Adjusted camera-to-world poses (P, 4, 4) and the lens they were adjusted with: the given
    camera when it has a lens model, else the camera with the focal length, k1 and k2 that fit
    the photos best. With fewer than ``MIN_TRACKS`` tracks, or a fisheye lens (the observation
    weights and the self-calibration are radial-tangential's), the poses and the camera come back
    as given."""
    if tracks.num_tracks < MIN_TRACKS or camera.lens is not LensModel.RADTAN:
        return poses_wc, camera
    if camera.has_distortion:
        return _adjust(camera, poses_wc, tracks), camera
    return _self_calibrate(camera, poses_wc, tracks)
