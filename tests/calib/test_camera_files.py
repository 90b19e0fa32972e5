import pytest

from evp.calib.camera_files import read_camera, write_opencv_yaml
from evp.calib.profiles import load_profile
from evp.errors import CalibrationError

EXPECTED = dict(width=640, height=480, fx=500.0, fy=501.0, cx=320.5, cy=240.5, k1=0.1, k2=-0.2, p1=0.001, p2=0.002)


def _check(camera, k3=0.0):
    for key, value in EXPECTED.items():
        assert getattr(camera, key) == pytest.approx(value), key
    assert camera.k3 == pytest.approx(k3)


def test_opencv_filestorage_written_by_opencv_tools(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text(
        "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 500., 0., 320.5, 0., 501., 240.5, 0., 0., 1. ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n"
        "   dt: d\n   data: [ 0.1, -0.2, 0.001, 0.002, 0.03 ]\n"
    )
    _check(read_camera(path), k3=0.03)


def test_ros_camera_info(tmp_path):
    path = tmp_path / "ost.yaml"
    path.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: narrow_stereo\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
        "  data: [500, 0, 320.5, 0, 501, 240.5, 0, 0, 1]\ndistortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n"
        "  data: [0.1, -0.2, 0.001, 0.002, 0]\nrectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
    )
    camera = read_camera(path)
    _check(camera)
    assert camera.name == "narrow_stereo"


@pytest.mark.parametrize("prefix", ["Camera", "Camera1"])
def test_orbslam_settings(tmp_path, prefix):
    path = tmp_path / "orb.yaml"
    path.write_text(
        f'%YAML:1.0\nCamera.type: "PinHole"\n{prefix}.fx: 500.0\n{prefix}.fy: 501.0\n{prefix}.cx: 320.5\n{prefix}.cy: 240.5\n'
        f"{prefix}.k1: 0.1\n{prefix}.k2: -0.2\n{prefix}.p1: 0.001\n{prefix}.p2: 0.002\nCamera.width: 640\nCamera.height: 480\n"
        "Camera.fps: 30\nORBextractor.nFeatures: 1500\n"
    )
    _check(read_camera(path))


def test_kalibr_camchain_and_euroc_sensor_yaml(tmp_path):
    chain = tmp_path / "camchain.yaml"
    chain.write_text(
        "cam0:\n  camera_model: pinhole\n  intrinsics: [500.0, 501.0, 320.5, 240.5]\n  distortion_model: radtan\n"
        "  distortion_coeffs: [0.1, -0.2, 0.001, 0.002]\n  resolution: [640, 480]\n  rostopic: /cam0/image_raw\n"
        "cam1:\n  camera_model: pinhole\n  intrinsics: [400.0, 400.0, 320.0, 240.0]\n  distortion_model: radtan\n"
        "  distortion_coeffs: [0, 0, 0, 0]\n  resolution: [640, 480]\n"
    )
    _check(read_camera(chain))
    assert read_camera(chain, camera="cam1").fx == 400.0
    chain.write_text(chain.read_text().replace("distortion_model: radtan", "distortion_model: equidistant", 1))
    with pytest.raises(CalibrationError, match="equidistant"):
        read_camera(chain)


def test_written_yaml_reads_back_exactly(tmp_path):
    camera = load_profile("nexus5x_640x380")
    write_opencv_yaml(tmp_path / "c.yaml", camera, {"rms_reprojection_error_px": 0.12})
    back = read_camera(tmp_path / "c.yaml")
    assert back.K.tolist() == camera.K.tolist()
    assert back.distortion.tolist() == camera.distortion.tolist()


@pytest.mark.parametrize(
    "text, message",
    [
        ("image_width: 640\nimage_height: 480\n", "not a calibration file"),
        ("camera_matrix: {rows: 3, cols: 3, data: [1, 0, 0, 0, 1, 0, 0, 0, 1]}\n", "image_width and image_height"),
        ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [1, 2]}\n", "malformed"),
        ("cam0: [unclosed\n", "invalid YAML"),
        ("- just\n- a list\n", "mapping"),
        ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [-5, 0, 320, 0, 500, 240, 0, 0, 1]}\n", "focal"),
    ],
)
def test_malformed_calibration_files(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=message) as info:
        read_camera(path)
    assert str(path) in str(info.value)


def test_missing_file():
    with pytest.raises(CalibrationError, match="not found"):
        read_camera("/nonexistent/camera.yaml")
