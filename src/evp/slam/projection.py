"""Which map points a camera should see, where, and at which pyramid level (ORB-SLAM's
isInFrustum, vectorised)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evp.optim.reprojection import pinhole_pixels
from evp.slam.map import Map
from evp.vision.orb import MAX_RAY_ANGLE_DEG, OrbExtractor

MIN_VIEW_COS = 0.5  # 60 degrees from the point's mean viewing direction


@dataclass
class Projection:
    rows: np.ndarray  # indices into the ids given, of points in the frustum
    uv: np.ndarray  # (n, 2) undistorted pixel coordinates
    level: np.ndarray  # (n,) predicted pyramid level
    view_cos: np.ndarray  # (n,) cosine between the viewing ray and the point's mean direction
    stretch: np.ndarray | float  # (n,) search-window factor where each lands (``window_stretch``)


def undistorted_bounds(extractor: OrbExtractor) -> tuple[float, float, float, float]:
    """Box (u_min, v_min, u_max, v_max) of the image in undistorted pixel coordinates, cut to the
    cone of rays features are kept in (``MAX_RAY_ANGLE_DEG``): a fisheye's border lies there
    towards infinity, or has no undistorted coordinates at all beyond 90 degrees."""
    camera = extractor.camera
    un = camera.undistort_pixels(camera.border_pixels(21))
    beyond = np.isnan(un)  # fisheye border rays 90 degrees or more off the axis: the cone bounds them
    reach = np.tan(np.radians(MAX_RAY_ANGLE_DEG)) * np.array([camera.fx, camera.fy])
    low = np.maximum(np.where(beyond, -np.inf, un).min(axis=0), [camera.cx, camera.cy] - reach)
    high = np.minimum(np.where(beyond, np.inf, un).max(axis=0), [camera.cx, camera.cy] + reach)
    return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def project_points(
    slam_map: Map, ids: np.ndarray | list[int], T_cw: np.ndarray, extractor: OrbExtractor, K: np.ndarray, bounds: tuple[float, float, float, float]
) -> Projection | None:
    """``bounds``: :func:`undistorted_bounds`, computed once per camera by the caller."""
    if len(ids) == 0:
        return None
    store = slam_map.store
    positions, normals, min_d, max_d = store.position[ids], store.normal[ids], store.min_distance[ids], store.max_distance[ids]
    uv = pinhole_pixels(positions @ T_cw[:3, :3].T + T_cw[:3, 3], K)
    u, v = uv[:, 0], uv[:, 1]
    u_min, v_min, u_max, v_max = bounds
    ok = (u >= u_min) & (u <= u_max) & (v >= v_min) & (v <= v_max)  # False for NaN: behind the camera
    centre = -T_cw[:3, :3].T @ T_cw[:3, 3]
    ray = positions - centre
    distance = np.linalg.norm(ray, axis=1)
    ok &= (distance >= 0.8 * min_d) & (distance <= 1.2 * max_d)
    view_cos = np.sum(ray * normals, axis=1) / np.maximum(distance, 1e-12)
    ok &= view_cos >= MIN_VIEW_COS
    rows = np.flatnonzero(ok)
    if len(rows) == 0:
        return None
    with np.errstate(divide="ignore"):
        level = np.ceil(np.log(max_d[rows] / distance[rows]) / np.log(extractor.settings.scale_factor))
    level = np.clip(np.nan_to_num(level, nan=0.0), 0, len(extractor.scale_factors) - 1).astype(int)
    return Projection(rows, uv[rows], level, view_cos[rows], projected_stretch(extractor, uv[rows]))


def projected_stretch(extractor: OrbExtractor, uv: np.ndarray) -> np.ndarray | float:
    """The extractor's window stretch at (n, 2) undistorted pixels (1.0 where its lens widens none)."""
    if not extractor.widens_windows:
        return 1.0
    camera = extractor.camera
    return extractor.window_stretch(extractor.lens_jacobian((uv - [camera.cx, camera.cy]) / [camera.fx, camera.fy]))
