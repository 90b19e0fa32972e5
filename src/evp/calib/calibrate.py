"""Camera calibration from chessboard or ChArUco views (OpenCV), with per-view rejection.

Views whose RMS reprojection error is far above the rest (a blurred frame, a mis-detected corner)
are dropped and the calibration is repeated, so one bad image cannot spoil the result.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from evp.errors import CalibrationError, UsageError
from evp.types import CameraModel
from evp.vision.images import to_grey

SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)


@dataclass(frozen=True)
class BoardSpec:
    """A calibration board. ``cols``/``rows`` count squares; inner corners are one fewer each way."""

    kind: str  # "chessboard" or "charuco"
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0  # ChArUco marker side
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise UsageError(f"unknown board kind {self.kind!r} (chessboard or charuco)")
        if self.cols < 3 or self.rows < 3 or self.square_m <= 0:
            raise UsageError("a board needs at least 3x3 squares and a positive square size")
        if self.kind == "charuco" and not 0 < self.marker_m < self.square_m:
            raise UsageError("ChArUco markers must be smaller than the squares")

    @property
    def inner_corners(self) -> tuple[int, int]:
        return self.cols - 1, self.rows - 1

    def object_points(self) -> np.ndarray:
        """Inner corners in the board frame (metres, z = 0), row by row as OpenCV returns them."""
        cols, rows = self.inner_corners
        grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * self.square_m
        return np.column_stack([grid, np.zeros(len(grid))]).astype(np.float32)

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, dictionary)


@dataclass
class CalibrationResult:
    camera: CameraModel
    rms_px: float
    per_view_rms_px: dict[str, float]
    rejected: dict[str, str] = field(default_factory=dict)  # view name -> reason

    def report(self) -> str:
        lines = [f"RMS reprojection error {self.rms_px:.4f} px over {len(self.per_view_rms_px)} views"]
        lines += [f"  {name}: {error:.4f} px" for name, error in sorted(self.per_view_rms_px.items())]
        lines += [f"  rejected {name}: {reason}" for name, reason in sorted(self.rejected.items())]
        c = self.camera
        lines.append(f"fx {c.fx:.3f} fy {c.fy:.3f} cx {c.cx:.3f} cy {c.cy:.3f} " + " ".join(f"{name} {value:.5f}" for name, value in c.coefficients.items()))
        return "\n".join(lines)


def detect_board(image: np.ndarray, board: BoardSpec) -> tuple[np.ndarray, np.ndarray] | None:
    """(image points (N, 2), object points (N, 3)) of the board's corners, or None if not found."""
    grey = to_grey(image)
    if board.kind == "chessboard":
        found, corners = cv2.findChessboardCornersSB(grey, board.inner_corners, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not found:
            found, corners = cv2.findChessboardCorners(grey, board.inner_corners, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not found:
                return None
            corners = cv2.cornerSubPix(grey, corners, (5, 5), (-1, -1), SUBPIX_CRITERIA)
        return corners.reshape(-1, 2).astype(np.float32), board.object_points()
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(grey)
    if ids is None or len(ids) < 6:
        return None
    objects = board.charuco_board().getChessboardCorners()[ids.ravel()]
    return corners.reshape(-1, 2).astype(np.float32), objects.astype(np.float32)


def _calibrate(views: dict[str, tuple[np.ndarray, np.ndarray]], size: tuple[int, int], flags: int):
    names = list(views)
    objects = [views[n][1] for n in names]
    images = [views[n][0] for n in names]
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(objects, images, size, None, None, flags=flags)
    per_view = {}
    for name, obj, img, rvec, tvec in zip(names, objects, images, rvecs, tvecs):
        projected, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
        per_view[name] = float(np.sqrt(np.mean(np.sum((projected.reshape(-1, 2) - img) ** 2, axis=1))))
    return float(rms), K, dist.ravel(), per_view


def calibrate_views(
    images: Iterable[tuple[str, np.ndarray]],
    board: BoardSpec,
    reject_factor: float = 3.0,
    reject_floor_px: float = 0.5,
    fix_k3: bool = True,
    min_views: int = 4,
    source: str = "the images",
) -> CalibrationResult:
    """Calibrate from named images; views whose error exceeds ``max(floor, factor x median)`` are
    dropped. ``source`` names where the images came from in errors."""
    views: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    rejected: dict[str, str] = {}
    size = None
    first = None
    for name, image in images:
        this_size = (image.shape[1], image.shape[0])
        if size is None:
            size, first = this_size, image
        elif this_size != size:
            rejected[name] = f"size {this_size[0]}x{this_size[1]} differs from {size[0]}x{size[1]}"
            continue
        detection = detect_board(image, board)
        if detection is None:
            rejected[name] = "board not found"
        else:
            views[name] = detection
    if len(views) < min_views:
        raise CalibrationError(source, too_few_views(len(views), len(views) + len(rejected), min_views, board, first))
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    while True:
        rms, K, dist, per_view = _calibrate(views, size, flags)
        limit = max(reject_floor_px, reject_factor * float(np.median(list(per_view.values()))))
        worst = max(per_view, key=per_view.get)
        if per_view[worst] <= limit or len(views) <= min_views:
            break
        rejected[worst] = f"reprojection error {per_view[worst]:.3f} px > {limit:.3f} px"
        del views[worst]
    camera = CameraModel(size[0], size[1], K[0, 0], K[1, 1], K[0, 2], K[1, 2], *(list(dist) + [0.0] * 5)[:5], name="calibrated")
    return CalibrationResult(camera, rms, per_view, rejected)


def too_few_views(found: int, images: int, min_views: int, board: BoardSpec, first: np.ndarray | None) -> str:
    """Why a calibration cannot run, with the board sizes to check: ``--cols/--rows`` count
    squares, and the board given as its inner corners (one fewer each way, what OpenCV's own
    samples ask for) is the common mistake, so when no view shows the board the first image is
    tried with one more square each way and a hit is named."""
    message = f"the board was found in {found} of {images} images; at least {min_views} are needed"
    if found or first is None:
        return message + "; take more views with the whole board in sight"
    cols, rows = board.inner_corners
    hint = (
        f"; --cols {board.cols} --rows {board.rows} count squares (a {board.cols}x{board.rows} board has {cols}x{rows} inner corners): "
        "check them against the board, and that the whole board is in sight"
    )
    larger = BoardSpec(board.kind, board.cols + 1, board.rows + 1, board.square_m, board.marker_m if board.kind == "charuco" else 0.0, board.dictionary)
    if detect_board(first, larger) is not None:
        hint = f"; the first image shows a board with --cols {larger.cols} --rows {larger.rows} (these count squares, not inner corners)"
    return message + hint


def images_from_path(path: Path, every: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    """Named images from a folder of images or every ``every``-th frame of a video."""
    from evp.io.dataset import load_image
    from evp.io.readers.image_folder import IMAGE_SUFFIXES

    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise CalibrationError(path, "no images in folder")
        for file in files[::every]:
            yield file.name, load_image(file)
        return
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise CalibrationError(path, "neither an image folder nor a readable video")
    index = 0
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            if index % every == 0:
                yield f"frame_{index:06d}", frame
            index += 1
    finally:
        capture.release()
