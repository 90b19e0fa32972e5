"""Map files: the whole map as one ``.npz`` (to relocalise against and extend it later), with its
georeference when the run that saved it had one, and its points as an ASCII PLY point cloud (opens
in MeshLab, CloudCompare, Open3D)."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from evp.errors import DataFormatError
from evp.fusion.map_georeference import MapGeoreference
from evp.io.npz_archives import read_archive
from evp.slam.map import Map

# 3: the meta may hold the map's georeference; 2: keyframes carry bag-of-words vectors (1: thumbnails)
MAP_FORMAT_VERSION = 3
READABLE_VERSIONS = (2, 3)  # a version-2 map is the same map without a georeference
WHAT = "an EVP map file"


def write_map_ply(slam_map: Map, path: Path) -> None:
    """The map points as an ASCII PLY point cloud."""
    _, positions = slam_map.point_array()
    header = (
        f"ply\nformat ascii 1.0\ncomment EVP map points\nelement vertex {len(positions)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    )
    with Path(path).open("w") as handle:
        handle.write(header)
        np.savetxt(handle, positions, fmt="%.9g")


def save_map(slam_map: Map, path: Path, georeference: MapGeoreference | None = None) -> None:
    """The map's arrays, its id counters and its georeference (when known), compressed into one ``.npz``."""
    next_kf, next_point = slam_map.id_counters
    meta = {"format": "evp-map", "version": MAP_FORMAT_VERSION, "next_kf": next_kf, "next_point": next_point}
    meta["georeference"] = georeference.to_json() if georeference is not None else None
    np.savez_compressed(Path(path), meta=np.array(json.dumps(meta)), **slam_map.to_arrays())


def load_map(path: Path, scale_factors: np.ndarray) -> Map:
    """A map saved by :func:`save_map`; a file that is not one, or of another format version, is a clear error."""
    # per keyframe, indexing the archive again took 26 GB for a 520-keyframe map: read_archive reads each array once
    data, meta = read_archive(path, "evp-map", WHAT)
    _check_version(path, meta)
    return Map.from_arrays(data, (meta["next_kf"], meta["next_point"]), scale_factors)


def read_map_georeference(path: Path) -> MapGeoreference | None:
    """The georeference a map file holds (only its metadata is read); None when the run that saved
    it was not georeferenced, or the file is of version 2. A file that is not a map, or whose
    georeference is malformed, is a clear error."""
    try:
        with np.load(Path(path), allow_pickle=False) as archive:
            meta = json.loads(str(archive["meta"]))
    except (OSError, EOFError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise DataFormatError(path, f"not {WHAT} ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != "evp-map":
        raise DataFormatError(path, f"not {WHAT}")
    _check_version(path, meta)
    record = meta.get("georeference")
    if record is None:
        return None
    try:
        return MapGeoreference.from_json(record)
    except (KeyError, TypeError, ValueError) as exc:
        raise DataFormatError(path, f"the map's georeference is malformed ({exc})") from exc


def _check_version(path: Path, meta: dict) -> None:
    if meta.get("version") not in READABLE_VERSIONS:
        readable = " or ".join(str(v) for v in READABLE_VERSIONS)
        raise DataFormatError(path, f"map format version {meta.get('version')}; this EVP reads version {readable} (build the map again)")
