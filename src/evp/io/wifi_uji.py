"""The UJI long-term WiFi fingerprinting layout (Mendoza-Silva et al., Data 2018), and EVP's
radio-map file.

A database folder ``dbNN/`` holds sets ``SSSnn`` (``trn01`` the survey, ``tst01``... the tests),
each as row-aligned headerless CSV files: ``SSSnnrss.csv`` (N x APs, dBm, 100 = not detected)
and ``SSSnncrd.csv`` (N x 3: x m, y m, floor). Access points are named by their column, as the
dataset defines them (``AP001``...).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from evp.errors import DatasetError, UnknownFormatError
from evp.io.npz_archives import read_archive
from evp.io.text_tables import read_table
from evp.wifi.fingerprints import Fingerprints

NOT_DETECTED = 100.0  # the files' value for an access point not heard
SURVEY_SET = "trn01"
RADIO_MAP_FORMAT = "evp-wifi-radio-map"


def access_point_names(count: int) -> tuple[str, ...]:
    return tuple(f"AP{j + 1:03d}" for j in range(count))


def rss_from_file_values(values: np.ndarray, path: Path) -> np.ndarray:
    """dBm with NaN for not heard; a value that is neither 100 nor a plausible RSS is an error."""
    bad = (values != NOT_DETECTED) & ((values > 0) | (values < -130) | ~np.isfinite(values))
    if bad.any():
        row, column = np.argwhere(bad)[0]
        raise DatasetError(
            path, f"RSS {values[row, column]!r} in column {column + 1} is neither {NOT_DETECTED:g} (not detected) nor a dBm value", line=int(row) + 1
        )
    return np.where(values == NOT_DETECTED, np.nan, values)


def read_set(folder: Path, name: str) -> Fingerprints:
    """One set (``trn01``, ``tst03``...) of a database folder."""
    rss_path, crd_path = folder / f"{name}rss.csv", folder / f"{name}crd.csv"
    rss_values, _, _ = read_table(rss_path, delimiter=",", header=False)
    crd, _, _ = read_table(crd_path, columns=3, delimiter=",", header=False)
    if len(crd) != len(rss_values):
        raise DatasetError(crd_path, f"{len(crd)} rows but {rss_path.name} has {len(rss_values)}: the files must be row-aligned")
    rss = rss_from_file_values(rss_values, rss_path)
    return Fingerprints(rss, crd[:, :2], crd[:, 2].astype(int), access_point_names(rss.shape[1]))


def database_folder(folder: Path) -> Path:
    """``folder`` itself when it holds the survey set, else its one ``dbNN`` subfolder."""
    folder = Path(folder)
    if (folder / f"{SURVEY_SET}rss.csv").is_file():
        return folder
    if folder.is_file():
        raise UnknownFormatError(f"{folder}: a file, and the folder holding the UJI sets is needed here: give {folder.parent}")
    if not folder.is_dir():
        raise UnknownFormatError(f"{folder}: no such folder")
    databases = sorted(p for p in folder.iterdir() if p.is_dir() and re.fullmatch(r"db\d+", p.name) and (p / f"{SURVEY_SET}rss.csv").is_file())
    if len(databases) != 1:
        found = ", ".join(p.name for p in databases) or "none"
        raise UnknownFormatError(f"{folder}: expected {SURVEY_SET}rss.csv or one dbNN/ folder holding it (UJI long-term layout); found {found}")
    return databases[0]


def read_database(folder: Path) -> tuple[Fingerprints, dict[str, Fingerprints]]:
    """The survey (``trn01``) and every test set (``tst*``, in name order) of a database folder."""
    folder = database_folder(folder)
    names = sorted(p.name[: -len("rss.csv")] for p in folder.glob("tst*rss.csv"))
    if not names:
        raise DatasetError(folder, "no test sets (tstNNrss.csv)")
    return read_set(folder, SURVEY_SET), {name: read_set(folder, name) for name in names}


def read_scans(path: Path, access_points: int) -> np.ndarray:
    """Scans to locate, as rows of an ``SSSnnrss.csv`` file (the radio map's access point columns)."""
    values, _, _ = read_table(Path(path), delimiter=",", header=False)
    if values.shape[1] != access_points:
        raise DatasetError(path, f"{values.shape[1]} RSS columns, but the radio map has {access_points} access points")
    return rss_from_file_values(values, Path(path))


def save_radio_map(survey: Fingerprints, path: Path) -> None:
    """The survey samples (every method builds its own map from them) in one ``.npz``."""
    meta = {"format": RADIO_MAP_FORMAT, "version": 1, "access_points": list(survey.access_points)}
    np.savez_compressed(Path(path), meta=np.array(json.dumps(meta)), rss=survey.rss, positions=survey.positions, floors=survey.floors)


def load_radio_map(path: Path) -> Fingerprints:
    data, meta = read_archive(path, RADIO_MAP_FORMAT, "an EVP WiFi radio map")
    return Fingerprints(data["rss"], data["positions"], data["floors"], tuple(meta["access_points"]))
