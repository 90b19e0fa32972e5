"""The methods EVP compares: plain 3-NN (the usual baseline), seed 001's weighted k-NN on a
radio map of averaged fingerprints, and weighted k-NN on every survey sample with floor detection
and k chosen by leave-one-place-out cross-validation inside the radio map."""

from __future__ import annotations

from collections.abc import Callable

from evp.config import WifiSettings
from evp.errors import UsageError
from evp.wifi.fingerprints import Fingerprints
from evp.wifi.knn import KnnMethod
from evp.wifi.tuning import tuned_k

PLAIN = KnnMethod("knn3", k=3)
PAPER = KnnMethod("wknn_paper", k=3, weighted=True, average_places=True)
TUNED = KnnMethod("wknn_cv", k=3, weighted=True, floor_detection=True)


def compared_methods(survey: Fingerprints, settings: WifiSettings, advance: Callable[[], None] = lambda: None) -> tuple[list[KnnMethod], dict[int, float]]:
    """The three methods, the last with its k tuned on ``survey`` (``advance`` after each k tried);
    and the tuning's error per k."""
    tuned, errors = tuned_k(survey, TUNED, settings.k_candidates, settings.not_detected_dbm, settings.place_tolerance_m, advance)
    return [PLAIN, PAPER, tuned], errors


def method_named(name: str, survey: Fingerprints, settings: WifiSettings, advance: Callable[[], None] = lambda: None) -> KnnMethod:
    """One of the compared methods by name (``wknn_cv`` tuned on ``survey``)."""
    if name == TUNED.name:
        return tuned_k(survey, TUNED, settings.k_candidates, settings.not_detected_dbm, settings.place_tolerance_m, advance)[0]
    for method in (PLAIN, PAPER):
        if method.name == name:
            return method
    raise UsageError(f"unknown WiFi method {name!r}; choose one of {PLAIN.name}, {PAPER.name}, {TUNED.name}")
