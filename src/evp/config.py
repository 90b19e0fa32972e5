"""Typed settings (pydantic), loaded from YAML; ORB-SLAM-style settings files are understood too.

Every command that writes results writes the effective settings beside them (``settings.yaml``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from evp.errors import ConfigError


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class OrbSettings(_Section):
    """The ORB extractor parameters the seed 000 operator GUI exposes."""

    n_features: int = Field(1000, ge=50, le=20000, description="features per image")
    pyramid_levels: int = Field(8, ge=1, le=16, description="scale pyramid levels")
    scale_factor: float = Field(1.2, gt=1.0, le=2.0, description="scale between pyramid levels")
    ini_fast_threshold: int = Field(20, ge=1, le=255, description="FAST threshold tried first")
    min_fast_threshold: int = Field(7, ge=1, le=255, description="FAST threshold where a cell has too few corners")


class CameraSettings(_Section):
    """Where the calibration comes from when the dataset has none (or to override it)."""

    calibration_file: Path | None = Field(None, description="OpenCV/ROS/ORB-SLAM/Kalibr calibration file")
    profile: str | None = Field(None, description="named profile shipped with EVP, e.g. nexus5x_640x380")
    fps: float = Field(30.0, gt=0, description="nominal frame rate")
    color_space: Literal["gray", "bgr", "rgb"] = "gray"


class EvalSettings(_Section):
    align: Literal["none", "se3", "sim3"] = "sim3"
    n_align: int | None = Field(None, ge=3, description="align on the first N matched poses only")
    max_time_diff_s: float = Field(0.01, gt=0)
    time_offset_s: float = 0.0
    rpe_delta: float = Field(1.0, gt=0)
    rpe_unit: Literal["frames", "m"] = "frames"


class VoSettings(_Section):
    """The light keyframe visual odometry (``evp.vo.klt_vo``)."""

    max_features: int = Field(600, ge=50, description="corners kept per keyframe")
    min_feature_distance_px: float = Field(8.0, gt=0)
    init_min_parallax_px: float = Field(12.0, gt=0, description="median KLT displacement needed to initialise")
    init_min_points: int = Field(60, ge=8)
    min_tracked_points: int = Field(25, ge=6, description="fewer PnP inliers than this: tracking is lost")
    keyframe_parallax_px: float = Field(25.0, gt=0, description="median displacement since the keyframe that makes a new one")
    keyframe_min_map_ratio: float = Field(0.6, gt=0, lt=1, description="keyframe when fewer of its 3-D points are still tracked")
    ransac_threshold_px: float = Field(1.0, gt=0)
    min_triangulation_angle_deg: float = Field(1.0, gt=0)
    init_min_angle_deg: float = Field(1.5, gt=0, description="median ray angle the initial map needs")
    max_step_depth_ratio: float = Field(0.5, gt=0, description="largest frame-to-frame step, in median scene depths")


class Settings(_Section):
    orb: OrbSettings = OrbSettings()
    camera: CameraSettings = CameraSettings()
    vo: VoSettings = VoSettings()
    eval: EvalSettings = EvalSettings()


# ORB-SLAM2/3 settings keys and where they go in EVP's settings.
ORBSLAM_KEYS = {
    "ORBextractor.nFeatures": ("orb", "n_features"),
    "ORBextractor.nLevels": ("orb", "pyramid_levels"),
    "ORBextractor.scaleFactor": ("orb", "scale_factor"),
    "ORBextractor.iniThFAST": ("orb", "ini_fast_threshold"),
    "ORBextractor.minThFAST": ("orb", "min_fast_threshold"),
    "Camera.fps": ("camera", "fps"),
    "Camera1.fps": ("camera", "fps"),
}


def _from_orbslam(path: Path, data: dict) -> dict:
    nested: dict = {}
    for key, (section, field) in ORBSLAM_KEYS.items():
        if key in data:
            nested.setdefault(section, {})[field] = data[key]
    if "Camera.RGB" in data:
        nested.setdefault("camera", {})["color_space"] = "rgb" if data["Camera.RGB"] else "bgr"
    if "Camera.fx" in data or "Camera1.fx" in data:
        nested.setdefault("camera", {})["calibration_file"] = path
    return nested


def load_settings(path: str | Path | None = None) -> Settings:
    """Defaults, overridden by a YAML file (EVP layout or ORB-SLAM settings)."""
    if path is None:
        return Settings()
    from evp.calib.camera_files import load_yaml_mapping

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: settings file not found")
    data = load_yaml_mapping(path, lambda p, msg, line=None: ConfigError(f"{p}" + (f", line {line}" if line else "") + f": {msg}"))
    if any(key in data for key in ORBSLAM_KEYS) or "Camera.fx" in data:
        data = _from_orbslam(path, data)
    try:
        return Settings.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"{path}: {where}: {first['msg']} (got {first.get('input')!r})") from exc


def settings_yaml(settings: Settings) -> str:
    return yaml.safe_dump(settings.model_dump(mode="json"), sort_keys=False)


def write_settings(settings: Settings, directory: Path) -> Path:
    """The effective settings beside a command's results."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "settings.yaml"
    path.write_text(settings_yaml(settings))
    return path
