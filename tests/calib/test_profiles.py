import pytest

from evp.calib.camera_files import write_opencv_yaml
from evp.calib.profiles import configured_camera, load_profile, profile_names
from evp.config import CameraSettings
from evp.errors import EvpError


def test_nexus_profile_matches_seed_000():
    camera = load_profile("nexus5x_640x380")
    assert (camera.width, camera.height) == (640, 380)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (494.08, 494.16, 319.85, 173.56)
    assert (camera.k1, camera.k2, camera.p1, camera.p2, camera.k3) == (0.04, -0.09, -0.014, 0.0, 0.0)
    assert "nexus5x_640x380" in profile_names()
    with pytest.raises(EvpError, match="unknown camera profile"):
        load_profile("iphone_99")


def test_configured_camera_prefers_the_calibration_file_then_the_profile(tmp_path):
    nexus = load_profile("nexus5x_640x380")
    assert configured_camera(CameraSettings()) is None
    assert configured_camera(CameraSettings(profile="nexus5x_640x380")) == nexus
    other = load_profile(next(name for name in profile_names() if name != "nexus5x_640x380"))
    write_opencv_yaml(tmp_path / "c.yaml", other, {})
    from_file = configured_camera(CameraSettings(calibration_file=tmp_path / "c.yaml", profile="nexus5x_640x380"))
    assert (from_file.width, from_file.height, from_file.fx, from_file.k1) == (other.width, other.height, other.fx, other.k1)
    with pytest.raises(EvpError, match="unknown camera profile"):
        configured_camera(CameraSettings(profile="iphone_99"))
