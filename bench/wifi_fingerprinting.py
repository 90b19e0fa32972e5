"""WiFi RSS fingerprinting (seed 001's weighted k-NN and a stronger method) on the UJI long-term
library data, month 1 (../shared/data/wifi_uji_library_month01): radio map trn01, test sets
tst01-tst05. The issue's aim: the stronger method's mean 2-D error on the test points that are not
in the radio map at least 20 % below plain 3-NN's.

Usage: python bench/wifi_fingerprinting.py [--folder ../shared/data/wifi_uji_library_month01]

The same computation as ``evp wifi eval FOLDER --json FILE``: a row per method with the mean 2-D
error over every test sample, over the samples at points not in the radio map (tst02-tst04), its
change against knn3, the floor accuracy and the k the method used (wknn_cv's by leave-one-place-out
cross-validation inside the radio map, never on the tests).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from results import Results

from evp.config import WifiSettings
from evp.io.wifi_uji import read_database
from evp.wifi.evaluation import evaluate_methods
from evp.wifi.methods import compared_methods

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
COLUMNS = [
    ("method", "{method}"),
    ("k", "{k}"),
    ("mean 2-D error (m)", "{mean_m:.2f}"),
    ("unseen points (m)", "{unseen_m:.2f}"),
    ("vs knn3 on unseen", "{unseen_change_percent:+.1f} %"),
    ("floor accuracy", "{floor_percent:.2f} %"),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--folder", type=Path, default=SHARED / "wifi_uji_library_month01")
    args = parser.parse_args()
    settings = WifiSettings()
    survey, tests = read_database(args.folder)
    methods, _ = compared_methods(survey, settings)
    scores = evaluate_methods(survey, tests, methods, settings.not_detected_dbm, settings.place_tolerance_m)["methods"]
    results = Results("wifi_fingerprinting", "python bench/wifi_fingerprinting.py " + " ".join(sys.argv[1:]))
    table = results.table("methods", COLUMNS, ["folder", "method"], f"{args.folder.name}: radio map trn01, tests {', '.join(tests)}")
    baseline = scores["knn3"]["unseen_points_mean_error_m"]
    print(table.header())
    for method in methods:
        s = scores[method.name]
        record = {
            "folder": args.folder.name,
            "method": method.name,
            "k": method.k,
            "mean_m": s["mean_error_m"],
            "unseen_m": s["unseen_points_mean_error_m"],
            "unseen_change_percent": 100 * (s["unseen_points_mean_error_m"] / baseline - 1),
            "floor_percent": 100 * s["floor_accuracy"],
        }
        print(table.add(record), flush=True)


if __name__ == "__main__":
    main()
