"""Bundle adjustment of a nadir photo survey, with the lens self-calibrated.

The mosaic registration places each photo by a homography, which cannot model lens distortion or
relief: with a nominal camera from EXIF (no lens model) a few percent of barrel distortion bends
every homography, and the chain of them drifts in position and height. Here all photos are
adjusted together, as structure from motion does: 6-DoF camera poses and the 3-D ground points
matched between photos (tracks), with the project's bundle adjustment.

When the camera comes without a lens model, the focal length and the radial coefficients k1, k2
are estimated too, as COLMAP and OpenSfM self-calibrate: the adjustment's robust reprojection
cost, measured in the photos' own pixels, is minimised over the three as a least-squares problem
(each observation's truncated error a residual; each residual evaluation one bundle adjustment,
so the lens is the outer variable of a variable projection): Gauss-Newton with finite-difference
derivatives takes 33-41 adjustments where the Nelder-Mead search it replaced took 91, to the same
lens on the synthetic surveys of the tests; on Toledo 31 adjustments (f = 621.4 px, k1 = -0.085,
k2 = 0.059; 1.80 m against GPS) against 91 (f = 539.3 px, 1.70 m: the same ridge;
bench/survey_self_calibration.py).
One joint adjustment with the lens among the variables was tried with SciPy's sparse
trust-region solver and did not converge in 300 evaluations along the focal-height ridge (the
project's Schur-complement bundle adjustment has no lens variables). Over perfectly flat ground the focal length trades against height; the relief
of real ground tells them apart, if weakly: on the Toledo survey the cost falls from 50,400 (the
EXIF focal length, no distortion) to 14,400 at f = 0.78 of EXIF's, k1 = -0.061, k2 = 0.036, and
is 14,500 at 0.92, k1 = -0.089, k2 = 0.067 (a long ridge; the GPS heights over the ground
suggest EXIF's focal length to 2 %). Positions against GPS: 2.54 m, 1.70 m and 1.88 m.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from evp.optim.bundle_adjustment import BundleProblem, bundle_adjust
from evp.optim.reprojection import CHI2_2DOF
from evp.types import CameraModel, LensModel

LENS_SCALES = (0.1, 0.05, 0.03)  # the lens search's typical steps: log focal length, k1, k2
LENS_DIFF_STEP = 1e-3  # finite-difference step (relative): each adjustment stops at 1e-6 of its cost, so smaller steps see its noise
LENS_EVALUATIONS = 12  # Gauss-Newton iterations of the lens search (each: one adjustment and three for the derivatives)
LENS_FTOL = 1e-3  # stop when an iteration lowers the cost by less than 0.1 %
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


def _adjust(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, np.ndarray]:
    """Adjusted poses (camera-to-world) and each observation's truncated reprojection cost, in the
    photos' own pixels, for one lens model. The bundle adjustment works on undistorted pixels; each
    observation's standard deviation there is the lens's local magnification, so that costs of
    different lens models compare."""
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
    poses_cw, _, chi2 = bundle_adjust(problem, evaluations=20, first_gate_chi2=np.inf)  # mosaic poses can be pixels off
    return np.linalg.inv(poses_cw), np.minimum(chi2, CHI2_2DOF)


def _lens_and_poses(camera: CameraModel, poses_wc: np.ndarray, x: np.ndarray) -> tuple[CameraModel, np.ndarray]:
    """The camera with focal lengths scaled by exp(x[0]) and radial coefficients x[1], x[2], and
    the poses with heights over the ground (z = 0) scaled as the focal length is, so that each
    photo still covers the same ground."""
    scale = float(np.exp(x[0]))
    scaled = poses_wc.copy()
    scaled[:, 2, 3] *= scale
    return replace(camera, fx=camera.fx * scale, fy=camera.fy * scale, k1=float(x[1]), k2=float(x[2])), scaled


def adjust_survey(camera: CameraModel, poses_wc: np.ndarray, tracks: SurveyTracks) -> tuple[np.ndarray, CameraModel]:
    """Adjusted camera-to-world poses (P, 4, 4) and the lens they were adjusted with: the given
    camera when it has a lens model, else the camera with the focal length, k1 and k2 that fit
    the photos best. With fewer than ``MIN_TRACKS`` tracks, or a fisheye lens (the observation
    weights and the self-calibration are radial-tangential's), the poses and the camera come back
    as given."""
    if tracks.num_tracks < MIN_TRACKS or camera.lens is not LensModel.RADTAN:
        return poses_wc, camera
    if camera.has_distortion:
        return _adjust(camera, poses_wc, tracks)[0], camera

    def residuals(x: np.ndarray) -> np.ndarray:
        return np.sqrt(_adjust(*_lens_and_poses(camera, poses_wc, x), tracks)[1])

    search = least_squares(residuals, np.zeros(3), diff_step=LENS_DIFF_STEP, x_scale=LENS_SCALES, max_nfev=LENS_EVALUATIONS, ftol=LENS_FTOL, method="trf")
    lens, poses = _lens_and_poses(camera, poses_wc, search.x)
    lens = replace(lens, name=f"{camera.name or 'camera'}+self-calibrated")
    return _adjust(lens, poses, tracks)[0], lens
