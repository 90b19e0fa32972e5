"""Named camera profiles shipped with EVP (``evp calibrate --list-profiles``)."""

from __future__ import annotations

from difflib import get_close_matches
from importlib import resources
from pathlib import Path

from evp.calib.camera_files import read_camera
from evp.config import CameraSettings
from evp.errors import UsageError
from evp.types import CameraModel


def _profile_dir() -> Path:
    return Path(str(resources.files("evp.calib") / "profile_files"))


def profile_names() -> list[str]:
    return sorted(p.stem for p in _profile_dir().glob("*.yaml"))


def load_profile(name: str) -> CameraModel:
    """A shipped camera profile by name, e.g. ``nexus5x_640x380`` (seed 000's phone)."""
    path = _profile_dir() / f"{name}.yaml"
    if not path.is_file():
        close = get_close_matches(name, profile_names(), n=1, cutoff=0.5)
        guess = f"did you mean {close[0]}? " if close else ""
        raise UsageError(f"unknown camera profile {name!r}; {guess}known: {', '.join(profile_names())} (or give a calibration file)")
    return read_camera(path)


def configured_camera(settings: CameraSettings) -> CameraModel | None:
    """The calibration the settings name: their calibration file, else their profile; None when
    they name neither (the caller falls back to the dataset's calibration or a default phone)."""
    if settings.calibration_file is not None:
        return read_camera(settings.calibration_file)
    if settings.profile:
        return load_profile(settings.profile)
    return None


def camera_from(spec: str) -> CameraModel:
    """A calibration file when ``spec`` names one, else a shipped profile of that name."""
    return read_camera(spec) if Path(spec).is_file() else load_profile(spec)
