"""Named camera profiles shipped with EVP (``evp calibrate --list-profiles``)."""

from __future__ import annotations

from difflib import get_close_matches
from importlib import resources
from pathlib import Path

from evp.calib.camera_files import read_camera
from evp.config import CameraSettings
from evp.errors import CalibrationError, UsageError
from evp.types import CameraModel


def _profile_dir() -> Path:
    return Path(str(resources.files("evp.calib") / "profile_files"))


def profile_names() -> list[str]:
    return sorted(p.stem for p in _profile_dir().glob("*.yaml"))


# names a profile went by before issue 35 made evp sim use the profile names; the shipped
# vocabulary's notes record its training scenes with this one
FORMER_NAMES = {"global_752x480": "global_shutter_752x480"}


def load_profile(name: str) -> CameraModel:
    """A shipped camera profile by name, e.g. ``nexus5x_640x380`` (seed 000's phone)."""
    path = _profile_dir() / f"{FORMER_NAMES.get(name, name)}.yaml"
    if not path.is_file():
        close = get_close_matches(name, profile_names(), n=1, cutoff=0.5)
        guess = f"did you mean {close[0]}? " if close else ""
        raise UsageError(f"unknown camera profile {name!r}; {guess}known: {', '.join(profile_names())} (or give a calibration file)")
    return read_camera(path)


def configured_camera(settings: CameraSettings, size: tuple[int, int] | None = None) -> CameraModel | None:
    """The calibration the settings name: their calibration file, else their profile, for images
    of ``size`` (width, height) when known; None when they name neither (the caller falls back
    to the dataset's calibration or a default phone)."""
    if settings.calibration_file is not None:
        return camera_from(str(settings.calibration_file), size)
    if settings.profile:
        return camera_from(settings.profile, size)
    return None


def camera_from(spec: str, size: tuple[int, int] | None = None) -> CameraModel:
    """A calibration file when ``spec`` names one, else a shipped profile of that name; for images
    of ``size`` (width, height) when given: a file without a size (calib.txt) takes it, and a
    calibration of the same shape at another resolution is scaled to it (a phone's 1920x1080
    calibration for its 640x360 stream); another shape is refused."""
    width, height = size if size is not None else (None, None)
    path = Path(spec)
    if path.is_file():
        camera = read_camera(path, width, height)
    elif path.suffix or len(path.parts) > 1:  # a path, not a profile name: say the file is missing
        raise CalibrationError(path, "calibration file not found (give a calibration file or a profile name: evp camera list)")
    else:
        camera = load_profile(spec)
    if size is None or (camera.width, camera.height) == size:
        return camera
    if abs(camera.width * height - camera.height * width) > 0.01 * camera.width * height:
        raise CalibrationError(
            spec, f"calibration is for {camera.width}x{camera.height} images, these are {width}x{height} (another shape, so it cannot be scaled)"
        )
    return camera.scaled(width, height)
