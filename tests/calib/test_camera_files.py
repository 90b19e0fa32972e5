import pytest

from evp.calib.camera_files import read_camera, write_opencv_yaml
from evp.calib.profiles import load_profile
from evp.errors import CalibrationError
from evp.io.ros_messages import ROS2, camera_info_to_msg, msg_to_camera
from evp.types import CameraModel, LensModel

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


def _orbslam_yaml(prefix: str, kind: str, intrinsics: tuple[float, ...], coefficients: dict[str, float], size: tuple[int, int]) -> str:
    """An ORB-SLAM3 settings file: the camera's keys under ``prefix`` (ORB-SLAM3's Camera1 or the
    older Camera), the size under Camera."""
    lines = ["%YAML:1.0", f'Camera.type: "{kind}"']
    lines += [f"{prefix}.{key}: {value}" for key, value in zip(("fx", "fy", "cx", "cy"), intrinsics, strict=True)]
    lines += [f"{prefix}.{key}: {value}" for key, value in coefficients.items()]
    lines += [f"Camera.width: {size[0]}", f"Camera.height: {size[1]}"]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("prefix", ["Camera", "Camera1"])
def test_orbslam_settings(tmp_path, prefix):
    path = tmp_path / "orb.yaml"
    path.write_text(
        _orbslam_yaml(prefix, "PinHole", (500.0, 501.0, 320.5, 240.5), {"k1": 0.1, "k2": -0.2, "p1": 0.001, "p2": 0.002}, (640, 480))
        + "Camera.fps: 30\nORBextractor.nFeatures: 1500\n"
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
    fisheye = read_camera(chain)
    assert fisheye.lens is LensModel.EQUIDISTANT and fisheye.distortion.tolist() == [0.1, -0.2, 0.001, 0.002]


RATIONAL = CameraModel(640, 480, 500.0, 501.0, 320.5, 240.5, 0.1, -0.2, 0.001, 0.002, 0.03, "r", k4=0.4, k5=-0.05, k6=0.006)
FISHEYE = CameraModel(640, 480, 200.0, 201.0, 320.5, 240.5, 0.0035, 0.0007, k3=-0.002, k4=0.0002, name="f", lens=LensModel.EQUIDISTANT)


@pytest.mark.parametrize("camera", [load_profile("nexus5x_640x380"), RATIONAL, FISHEYE], ids=["radtan", "rational", "equidistant"])
def test_written_yaml_reads_back_exactly(tmp_path, camera):
    write_opencv_yaml(tmp_path / "c.yaml", camera, {"rms_reprojection_error_px": 0.12})
    back = read_camera(tmp_path / "c.yaml")
    assert back.K.tolist() == camera.K.tolist()
    assert back.lens is camera.lens
    assert back.distortion.tolist() == camera.distortion.tolist()


@pytest.mark.parametrize("camera", [RATIONAL, FISHEYE], ids=["rational", "equidistant"])
def test_ros_camera_info_message_keeps_the_lens(camera):
    back = msg_to_camera(camera_info_to_msg(ROS2, 1.0, camera), "bag.mcap")
    assert back.lens is camera.lens and back.distortion.tolist() == camera.distortion.tolist()


def _ros_yaml(model: str, coefficients: list[float]) -> str:
    return (
        "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [500, 0, 320.5, 0, 501, 240.5, 0, 0, 1]}\n"
        f"{model}distortion_coefficients: {{rows: 1, cols: {len(coefficients)}, data: {coefficients}}}\n"
    )


def test_ros_rational_polynomial_keeps_all_eight_coefficients(tmp_path):
    path = tmp_path / "ost.yaml"
    coefficients = [0.1, -0.2, 0.001, 0.002, 0.03, 0.4, -0.05, 0.006]
    path.write_text(_ros_yaml("distortion_model: rational_polynomial\n", coefficients))
    camera = read_camera(path)
    assert camera.lens is LensModel.RADTAN and camera.distortion.tolist() == coefficients
    path.write_text(_ros_yaml("", coefficients))  # OpenCV FileStorage: eight coefficients are the rational model
    assert read_camera(path).distortion.tolist() == coefficients


@pytest.mark.parametrize("model", ["distortion_model: equidistant\n", "fisheye_model: 1\n"])
def test_opencv_and_ros_equidistant(tmp_path, model):
    path = tmp_path / "fisheye.yaml"
    path.write_text(_ros_yaml(model, [0.01, -0.002, 0.0003, -0.00004]))
    camera = read_camera(path)
    assert camera.lens is LensModel.EQUIDISTANT and (camera.k3, camera.k4) == (0.0003, -0.00004)


@pytest.mark.parametrize("prefix", ["Camera", "Camera1"])
def test_orbslam3_kannala_brandt_is_a_fisheye(tmp_path, prefix):
    path = tmp_path / "orb.yaml"
    coefficients = {"k1": 0.0034823894022493434, "k2": 0.0007150348452162257, "k3": -0.0020532361418706202, "k4": 0.00020293673591811182}
    path.write_text(_orbslam_yaml(prefix, "KannalaBrandt8", (190.97, 190.97, 254.93, 256.89), coefficients, (512, 512)))
    camera = read_camera(path)
    assert camera.lens is LensModel.EQUIDISTANT
    assert camera.distortion.tolist() == [0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202, 0.00020293673591811182]
    assert (camera.p1, camera.p2) == (0.0, 0.0)


def test_orbslam3_rectified_has_no_distortion(tmp_path):
    path = tmp_path / "orb.yaml"
    path.write_text(
        'Camera.type: "Rectified"\nCamera1.fx: 500.0\nCamera1.fy: 500.0\nCamera1.cx: 320.0\nCamera1.cy: 240.0\nCamera.width: 640\nCamera.height: 480\n'
    )
    camera = read_camera(path)
    assert camera.lens is LensModel.RADTAN and not camera.has_distortion


ORBSLAM_BASE = "Camera.fx: 500.0\nCamera.fy: 500.0\nCamera.cx: 320.0\nCamera.cy: 240.0\nCamera.width: 640\nCamera.height: 480\n"
KALIBR_BASE = "cam0:\n  intrinsics: [500.0, 501.0, 320.5, 240.5]\n  resolution: [640, 480]\n"


@pytest.mark.parametrize(
    "text, message",
    [
        (_ros_yaml("", [0.1] * 12), "12 distortion coefficients: OpenCV's thin-prism model"),
        (_ros_yaml("", [0.1] * 14), "14 distortion coefficients: OpenCV's tilted-sensor model"),
        (_ros_yaml("distortion_model: rational_polynomial\n", [0.1] * 5), "rational_polynomial has 8 coefficients"),
        (_ros_yaml("distortion_model: equidistant\n", [0.1] * 5), "equidistant \\(fisheye\\) lens has 4 coefficients"),
        (_ros_yaml("distortion_model: fov\n", [0.1]), "unsupported distortion model 'fov'"),
        (_ros_yaml("", [0.1] * 6), "radial-tangential lens has 4, 5 or 8 coefficients"),
        ('Camera.type: "Fisheye"\n' + ORBSLAM_BASE, "ORB-SLAM camera type 'Fisheye' is not supported"),
        (
            KALIBR_BASE + "  camera_model: omni\n  distortion_model: radtan\n  distortion_coeffs: [0, 0, 0, 0]\n",
            "camera model 'omni' \\(unified omnidirectional",
        ),
        (KALIBR_BASE + "  camera_model: ds\n  distortion_model: none\n  distortion_coeffs: []\n", "camera model 'ds' \\(double sphere"),
        (KALIBR_BASE + "  camera_model: eucm\n  distortion_model: none\n  distortion_coeffs: []\n", "camera model 'eucm' \\(extended unified"),
        (KALIBR_BASE + "  camera_model: pinhole\n  distortion_model: fov\n  distortion_coeffs: [0.9]\n", "distortion model 'fov' \\(field-of-view"),
        (
            KALIBR_BASE + "  camera_model: pinhole\n  distortion_model: radtan8\n  distortion_coeffs: [0.9]\n",
            "unsupported camera/distortion model pinhole/radtan8",
        ),
    ],
    ids=["thin-prism", "tilt", "rational-count", "equidistant-count", "ros-fov", "six", "orbslam-type", "omni", "ds", "eucm", "kalibr-fov", "kalibr-other"],
)
def test_lens_models_evp_cannot_use_are_refused_by_name(tmp_path, text, message):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    with pytest.raises(CalibrationError, match=message):
        read_camera(path)


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
