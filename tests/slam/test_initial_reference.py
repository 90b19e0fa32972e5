"""When the start stops waiting for the nominal parallax: the initial reference's signal that the
parallax it had at the last try is the most it will give (a forward drive's near points leaving
the view), and a hand's sway, which only dips it, is no such signal."""

import numpy as np

from evp.geometry.two_view import NEW_POINT_PARALLAX_COS, TwoViewCandidate
from evp.slam.system import _InitAttempt, _InitReference
from evp.vision.orb import Features

NO_FEATURES = Features(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), np.zeros(0), np.zeros((0, 32), np.uint8))
POINTS, MATCHES = 50, 100  # slam.init_min_triangulated, slam.init_min_matches


def _attempt(frame: int, parallax_deg: float, wide: int, matches: int) -> _InitAttempt:
    """Frame ``frame`` after the reference: ``matches`` matches, ``wide`` of them with a new point's parallax."""
    cos = np.full(matches, 1.0)
    cos[:wide] = NEW_POINT_PARALLAX_COS - 1e-4
    candidate = TwoViewCandidate(np.eye(4), np.zeros((matches, 3)), np.ones(matches, bool), cos, "fundamental", parallax_deg)
    return _InitAttempt(candidate, np.arange(matches), np.arange(matches), NO_FEATURES, frame, float(frame))


def _tries(*attempts: tuple[float, int, int]) -> list[_InitAttempt | None]:
    reference = _InitReference(NO_FEATURES, record=0)
    return [reference.past_peak(_attempt(frame, *a), POINTS, MATCHES) for frame, a in enumerate(attempts, start=1)]


def test_a_forward_drive_s_parallax_falling_as_its_points_leave_gives_back_the_peak():
    """The rendered road at 10 Hz (seed 1's first frames)."""
    peaks = _tries((2.64, 142, 579), (2.44, 139, 357), (1.94, 76, 240))
    assert peaks[:2] == [None, None]  # a dip whose points stay is not a peak
    assert peaks[2] is not None and peaks[2].record == 2


def test_a_hand_s_sway_dips_the_parallax_but_keeps_the_matches():
    """The rendered circle's hovering start: the sway takes most points under a new point's
    parallax, but the matches stay, so the start waits for the nominal parallax."""
    assert _tries((1.0, 150, 495), (1.47, 285, 489), (1.15, 56, 476)) == [None, None, None]


def test_a_slow_start_s_growing_parallax_never_peaks():
    assert _tries((0.5, 0, 500), (1.0, 20, 480), (1.6, 60, 470), (2.2, 110, 460), (2.9, 160, 450)) == [None] * 5
