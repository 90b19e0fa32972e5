"""Map files: the whole map as one ``.npz`` (to relocalise against and extend it later) and its
points as an ASCII PLY point cloud (opens in MeshLab, CloudCompare, Open3D)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from evp.errors import DataFormatError
from evp.io.npz_archives import read_archive
from evp.slam.map import Map

MAP_FORMAT_VERSION = 2  # 2: keyframes carry bag-of-words vectors (1: thumbnails)


def write_map_ply(slam_map: Map, path: Path) -> None:
    """The map points as an ASCII PLY point cloud."""
    _, positions = slam_map.point_array()
    header = (
        f"ply\nformat ascii 1.0\ncomment EVP map points\nelement vertex {len(positions)}\nproperty double x\nproperty double y\nproperty double z\nend_header\n"
    )
    with Path(path).open("w") as handle:
        handle.write(header)
        np.savetxt(handle, positions, fmt="%.9g")


def save_map(slam_map: Map, path: Path) -> None:
    """The map's arrays and its id counters, compressed into one ``.npz``."""
    next_kf, next_point = slam_map.id_counters
    meta = {"format": "evp-map", "version": MAP_FORMAT_VERSION, "next_kf": next_kf, "next_point": next_point}
    np.savez_compressed(Path(path), meta=np.array(json.dumps(meta)), **slam_map.to_arrays())


def load_map(path: Path, scale_factors: np.ndarray) -> Map:
    """A map saved by :func:`save_map`; a file that is not one, or of another format version, is a clear error."""
    # per keyframe, indexing the archive again took 26 GB for a 520-keyframe map: read_archive reads each array once
    data, meta = read_archive(path, "evp-map", "an EVP map file")
    if meta.get("version") != MAP_FORMAT_VERSION:
        raise DataFormatError(path, f"map format version {meta.get('version')}; this EVP reads version {MAP_FORMAT_VERSION} (build the map again)")
    return Map.from_arrays(data, (meta["next_kf"], meta["next_point"]), scale_factors)
