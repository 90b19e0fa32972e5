"""When the initial reference gives up waiting for the nominal parallax (system._InitReference)."""

import numpy as np

from evp.geometry.two_view import TwoViewResult
from evp.slam.system import _InitReference
from evp.vision.orb import Features


def _reference(n: int = 400) -> _InitReference:
    z2 = np.zeros((n, 2))
    return _InitReference(Features(z2, z2, z2, np.zeros(n, int), np.zeros(n), np.zeros((n, 32), np.uint8)), 0)


def _try(rows: np.ndarray, widest: np.ndarray, parallax_deg: float) -> tuple[TwoViewResult, np.ndarray]:
    """A two-view result over matches to the reference features ``rows``, whose widest-parallax
    points are the reference features ``widest``."""
    good = np.ones(len(rows), bool)
    return TwoViewResult(np.eye(4), np.zeros((len(rows), 3)), good, "fundamental", parallax_deg, np.searchsorted(rows, widest)), rows


def test_the_parallax_falling_as_its_points_leave_the_view_is_past_the_best():
    """A forward drive: the near points that gave the parallax are not matched any more."""
    reference = _reference()
    assert not reference.past_its_best(*_try(np.arange(300), np.arange(51), 2.6))
    assert reference.past_its_best(*_try(np.arange(40, 240), np.arange(100, 151), 2.4))


def test_a_parallax_dip_with_its_points_still_matched_is_not():
    """A hovering start: the parallax is noise-limited and dips while its points stay in view."""
    reference = _reference()
    assert not reference.past_its_best(*_try(np.arange(300), np.arange(51), 2.1))
    assert not reference.past_its_best(*_try(np.arange(290), np.arange(100, 151), 2.0))


def test_points_leaving_while_the_parallax_grows_is_not():
    reference = _reference()
    assert not reference.past_its_best(*_try(np.arange(300), np.arange(51), 1.5))
    assert not reference.past_its_best(*_try(np.arange(40, 240), np.arange(100, 151), 1.8))
    assert not reference.past_its_best(None, np.arange(10))  # a failed try forgets the last
    assert not reference.past_its_best(*_try(np.arange(100, 240), np.arange(150, 201), 1.0))
