import pytest

from evp.config import Settings, load_settings, settings_yaml, write_settings
from evp.errors import ConfigError


def test_defaults_round_trip_through_yaml(tmp_path):
    path = write_settings(Settings(), tmp_path)
    assert load_settings(path) == Settings()
    assert "n_features: 1000" in settings_yaml(Settings())


def test_partial_file_overrides_defaults(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("orb:\n  n_features: 2000\neval:\n  align: se3\n")
    settings = load_settings(path)
    assert settings.orb.n_features == 2000 and settings.orb.pyramid_levels == 8
    assert settings.eval.align == "se3"


@pytest.mark.parametrize(
    "text, message",
    [
        ("orb:\n  n_features: 10\n", "orb.n_features"),
        ("orb:\n  scale_factor: 0.9\n", "orb.scale_factor"),
        ("orb:\n  nfeatures: 1000\n", "orb.nfeatures"),
        ("eval:\n  align: affine\n", "eval.align"),
        ("orb: [1, 2\n", "invalid YAML"),
        ("station:\n  background_bounds_deg: [47, 8, 47.1, 8.1]\n", "go together"),
        ("station:\n  background_image: o.png\n  background_bounds_deg: [47.1, 8, 47, 8.1]\n", "south < north"),
        ("station:\n  background_image: o.tif\n  background_bounds_deg: [47, 8, 47.1, 8.1]\n", "gdal_translate"),
    ],
)
def test_invalid_settings_name_the_field(tmp_path, text, message):
    path = tmp_path / "s.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_settings(path)


def test_orbslam_settings_file_is_understood(tmp_path):
    path = tmp_path / "EuRoC.yaml"
    path.write_text(
        "%YAML:1.0\nCamera.fx: 458.654\nCamera.fy: 457.296\nCamera.cx: 367.215\nCamera.cy: 248.375\nCamera.width: 752\n"
        "Camera.height: 480\nCamera.fps: 20.0\nCamera.RGB: 1\nORBextractor.nFeatures: 1500\nORBextractor.scaleFactor: 1.2\n"
        "ORBextractor.nLevels: 8\nORBextractor.iniThFAST: 20\nORBextractor.minThFAST: 7\n"
    )
    settings = load_settings(path)
    assert settings.orb.n_features == 1500 and settings.camera.fps == 20.0
    assert settings.camera.calibration_file == path and settings.camera.color_space == "rgb"


def test_missing_settings_file():
    with pytest.raises(ConfigError, match="not found"):
        load_settings("/nonexistent.yaml")
