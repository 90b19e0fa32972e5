import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evp.types import CameraModel, Frame, TrackingState

EUROC = CameraModel(752, 480, 458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
cameras = st.builds(
    CameraModel,
    width=st.integers(160, 2000),
    height=st.integers(120, 1500),
    fx=st.floats(200, 2000),
    fy=st.floats(200, 2000),
    cx=st.floats(50, 1000),
    cy=st.floats(50, 800),
    k1=st.floats(-0.3, 0.3),
    k2=st.floats(-0.1, 0.1),
    p1=st.floats(-0.01, 0.01),
    p2=st.floats(-0.01, 0.01),
    k3=st.floats(-0.02, 0.02),
)


@settings(max_examples=200, deadline=None)
@given(cameras, st.floats(-0.5, 0.5), st.floats(-0.4, 0.4), st.floats(0.1, 100.0))
def test_project_unproject_round_trip(camera, x, y, depth):
    point = np.array([[x * depth, y * depth, depth]])
    pixel = camera.project(point)
    back = camera.unproject(pixel, depth)
    assert np.allclose(back, point, atol=1e-9 * max(1.0, depth))


def test_project_matches_opencv():
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-1, 1, 500), rng.uniform(-0.7, 0.7, 500), rng.uniform(1, 5, 500)])
    ours = EUROC.project(points)
    theirs, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), EUROC.K, EUROC.distortion)
    assert np.allclose(ours, theirs.reshape(-1, 2), atol=1e-9)


def test_undistort_matches_opencv_and_inverts_strong_distortion():
    rng = np.random.default_rng(1)
    pixels = rng.uniform([0, 0], [752, 480], (2000, 2))
    ours = EUROC.undistort_points(pixels)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-15)
    theirs = cv2.undistortPoints(pixels.reshape(-1, 1, 2), EUROC.K, EUROC.distortion, None, None, None, criteria).reshape(-1, 2)
    assert np.allclose(ours, theirs, atol=1e-10)
    assert np.allclose(EUROC.project(np.column_stack([ours, np.ones(len(ours))])), pixels, atol=1e-9)


def test_scaled_camera_sees_the_same_rays():
    small = EUROC.scaled(376, 240)
    assert (small.width, small.height) == (376, 240)
    assert small.fx == pytest.approx(EUROC.fx / 2) and small.fy == pytest.approx(EUROC.fy / 2)
    point = np.array([[0.3, -0.2, 2.0]])
    big_px = EUROC.project(point)[0]
    small_px = small.project(point)[0]
    # pixel-centre convention: edges coincide, so (u + 0.5) scales exactly
    assert np.allclose((big_px + 0.5) / 2, small_px + 0.5, atol=1e-9)
    assert small.k1 == EUROC.k1


def test_camera_rejects_invalid_parameters():
    with pytest.raises(ValueError, match="resolution"):
        CameraModel(0, 480, 500, 500, 320, 240)
    with pytest.raises(ValueError, match="focal"):
        CameraModel(640, 480, -1, 500, 320, 240)
    with pytest.raises(ValueError, match="finite"):
        CameraModel(640, 480, 500, 500, math.nan, 240)


def test_records_are_frozen_and_timestamp_first():
    frame = Frame(1.5, np.zeros((2, 2), np.uint8))
    with pytest.raises(AttributeError):
        frame.timestamp = 2.0
    from dataclasses import fields

    from evp import types

    for record in (types.Frame, types.ImuSample, types.GpsFix, types.BaroSample, types.WheelOdometry, types.WifiScan, types.BeaconRange, types.PoseEstimate):
        assert fields(record)[0].name == "timestamp"


def test_tracked_states_are_ok_and_relocalized():
    assert {state for state in TrackingState if state.tracked} == {TrackingState.OK, TrackingState.RELOCALIZED}
    assert TrackingState("RELOCALIZED").tracked and not TrackingState("LOST").tracked  # as on the wire
