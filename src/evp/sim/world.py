"""Scenes of textured rectangles and an exact ray-casting renderer.

Every surface (ground, walls, box faces, marker boards) is a textured rectangle. Each image pixel
casts its exact ray (through the lens model, so distortion is rendered, not approximated; a
fisheye's rays reach 90 degrees from the axis), the nearest rectangle hit wins, and its texture is
sampled there from a mip-map level that matches the pixel's footprint. With a rolling shutter every
image row has its own camera pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from evp.types import CameraModel, LensModel


@dataclass
class TexturedQuad:
    """Rectangle ``origin + a * axis_u + b * axis_v`` for a in [0, size_u], b in [0, size_v] (metres).

    Texture pixel (column, row) = (a, b) / metres_per_texel; axis_u and axis_v must be orthonormal.
    """

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size_u: float
    size_v: float
    texture: np.ndarray  # uint8 grey
    metres_per_texel: float
    name: str = ""
    _mips: list[np.ndarray] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        self.origin = np.asarray(self.origin, dtype=float)
        self.axis_u = np.asarray(self.axis_u, dtype=float)
        self.axis_v = np.asarray(self.axis_v, dtype=float)
        if abs(np.dot(self.axis_u, self.axis_v)) > 1e-9 or abs(np.linalg.norm(self.axis_u) - 1) > 1e-9 or abs(np.linalg.norm(self.axis_v) - 1) > 1e-9:
            raise ValueError(f"quad {self.name!r}: axes must be orthonormal")
        if self.texture.ndim != 2 or self.texture.dtype != np.uint8:
            raise ValueError(f"quad {self.name!r}: texture must be a grey uint8 image")
        # area-averaged halvings keep texel edges aligned (pyrDown would shift them by a quarter texel)
        self._mips = [self.texture]
        while min(self._mips[-1].shape) > 8:
            height, width = self._mips[-1].shape
            self._mips.append(cv2.resize(self._mips[-1], (width // 2, height // 2), interpolation=cv2.INTER_AREA))

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_u, self.axis_v)

    def mip(self, level: int) -> np.ndarray:
        return self._mips[min(level, len(self._mips) - 1)]


@dataclass
class Scene:
    quads: list[TexturedQuad]
    background: int = 0  # grey level where no surface is hit (sky, void)
    _arrays: tuple | None = field(default=None, repr=False)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """(origins, normals, axes_u, axes_v, sizes) of all quads, for vectorised queries."""
        if self._arrays is None:
            q = self.quads
            self._arrays = (
                np.array([x.origin for x in q]),
                np.array([x.normal for x in q]),
                np.array([x.axis_u for x in q]),
                np.array([x.axis_v for x in q]),
                np.array([[x.size_u, x.size_v] for x in q]),
            )
        return self._arrays


def box_quads(centre, size, texture: np.ndarray, metres_per_texel: float, name: str, skip_bottom: bool = True) -> list[TexturedQuad]:
    """The faces of an axis-aligned box: a building or a crate, or a room (faces are two-sided, so the
    same quads bound a room seen from inside)."""
    cx, cy, cz = centre
    sx, sy, sz = size
    lo = np.array([cx - sx / 2, cy - sy / 2, cz - sz / 2])
    ex, ey, ez = np.eye(3)
    faces = [
        (lo + [0, 0, sz], ex, ey, sx, sy, "top"),
        (lo, ex, ez, sx, sz, "south"),
        (lo + [0, sy, 0], ex, ez, sx, sz, "north"),
        (lo, ey, ez, sy, sz, "west"),
        (lo + [sx, 0, 0], ey, ez, sy, sz, "east"),
    ]
    if not skip_bottom:
        faces.append((lo, ex, ey, sx, sy, "bottom"))
    quads = []
    for origin, u, v, su, sv, face in faces:
        rows = max(2, int(round(sv / metres_per_texel)))
        cols = max(2, int(round(su / metres_per_texel)))
        face_texture = cv2.resize(texture, (cols, rows), interpolation=cv2.INTER_AREA) if texture.shape != (rows, cols) else texture
        quads.append(TexturedQuad(origin, u, v, su, sv, face_texture, su / cols, f"{name}:{face}"))
    return quads


class Renderer:
    """Renders a scene for one camera; the per-pixel rays are computed once.

    Which quads a pose sees, and where, is found by clipping each to the viewing frustum: four
    planes through the camera centre bounding every pixel's ray in the two view coordinates
    (x / z, y / z). Along a straight edge in front of the camera each coordinate is monotone, so a
    clipped polygon's extremes are at its corners and the per-row/column ranges of the pixel rays
    give its exact image window. A pinhole's view coordinates are its normalised coordinates, on
    whose z = 1 plane its rays are cast. A fisheye sees up to 90 degrees off the axis, where those
    run to infinity: its rays are unit bearings and its view coordinates the angles
    atan2(x, z), atan2(y, z), monotone in the same ratios and finite up to 90 degrees.
    """

    def __init__(self, camera: CameraModel, scene: Scene):
        self.camera = camera
        self.scene = scene
        u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
        pixels = np.column_stack([u.ravel(), v.ravel()])
        self._pinhole = camera.lens is LensModel.RADTAN
        if self._pinhole:
            xy = camera.undistort_points(pixels)
            rays = np.column_stack([xy, np.ones(len(xy))])
        else:
            rays = camera.bearings(pixels)
            xy = self._view_coordinates(rays)
        self._ray_norm = np.linalg.norm(rays, axis=1).reshape(camera.height, camera.width).astype(np.float32)
        self._rays = rays.reshape(camera.height, camera.width, 3).astype(np.float32)
        grid = xy.reshape(camera.height, camera.width, 2)
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        self._row_lo, self._row_hi = grid[..., 1].min(axis=1), grid[..., 1].max(axis=1)
        if self._pinhole:  # x / z >= lo: x - lo z >= 0 ...
            normals = np.array([[1.0, 0.0, -lo[0]], [-1.0, 0.0, hi[0]], [0.0, 1.0, -lo[1]], [0.0, -1.0, hi[1]]])
        else:  # atan2(x, z) >= lo: x cos(lo) - z sin(lo) >= 0 ...
            c, s = np.cos(np.r_[lo, hi]), np.sin(np.r_[lo, hi])
            normals = np.array([[c[0], 0.0, -s[0]], [-c[2], 0.0, s[2]], [0.0, c[1], -s[1]], [0.0, -c[3], s[3]]])
        # planes (normal, offset) for the exact clipping: in front of the camera, then the four sides
        self._clip_planes = np.vstack([[0.0, 0.0, 1.0, -1e-6], np.column_stack([normals, np.zeros(4)])])
        self._frustum_normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
        self._sphere_centres = np.array([q.origin + 0.5 * (q.size_u * q.axis_u + q.size_v * q.axis_v) for q in scene.quads]).reshape(-1, 3)
        self._sphere_radii = np.array([0.5 * np.hypot(q.size_u, q.size_v) for q in scene.quads])
        self._col_lo, self._col_hi = grid[..., 0].min(axis=0), grid[..., 0].max(axis=0)

    def render(self, T_world_cam: np.ndarray, row_poses: np.ndarray | None = None) -> np.ndarray:
        """Grey uint8 image. ``row_poses`` (H, 4, 4) gives each row its own pose (rolling shutter)."""
        if row_poses is None:
            # rays stay in the camera frame; the rotation is folded into each quad's frame below
            rays, rotation = self._rays, T_world_cam[:3, :3]
            centres = T_world_cam[:3, 3].reshape(1, 1, 3)
            poses = [T_world_cam]
        else:
            rays, rotation = np.einsum("hij,hwj->hwi", row_poses[:, :3, :3].astype(np.float32), self._rays), np.eye(3)
            centres = row_poses[:, None, :3, 3]
            poses = [row_poses[0], row_poses[-1]]
        candidates = self._in_view(poses)
        windows = {i: self._window(poses, self.scene.quads[i]) for i in candidates}
        return self._shade(rays, rotation, centres, {i: w for i, w in windows.items() if w is not None})

    def _in_view(self, poses: list[np.ndarray]) -> np.ndarray:
        """Indices of quads whose bounding sphere touches the (padded) viewing frustum of any pose:
        a vectorised first cut before the exact per-quad clipping."""
        keep = np.zeros(len(self._sphere_centres), bool)
        for T in poses:
            local = (self._sphere_centres - T[:3, 3]) @ T[:3, :3]
            inside = local[:, 2] > -self._sphere_radii
            for normal in self._frustum_normals:  # planes through the camera centre, normals point inwards
                inside &= local @ normal > -self._sphere_radii
            keep |= inside
        return np.flatnonzero(keep)

    def _window(self, poses: list[np.ndarray], quad: TexturedQuad) -> tuple[int, int, int, int] | None:
        """Image rows/columns (r0, r1, c0, c1) the quad can cover, None when it is out of view.

        The quad is clipped to the camera's viewing frustum (in view coordinates, so lens
        distortion is accounted for exactly through the per-row/column ranges of the pixel rays);
        the window is the union over the given poses (rolling shutter: first and last row).
        """
        corners = quad.origin + np.array([[0, 0], [quad.size_u, 0], [quad.size_u, quad.size_v], [0, quad.size_v]]) @ np.stack([quad.axis_u, quad.axis_v])
        window = None
        for T in poses:
            polygon = _clip_to_frustum((corners - T[:3, 3]) @ T[:3, :3], self._clip_planes)
            if polygon is None:
                continue
            xy = polygon[:, :2] / polygon[:, 2:3] if self._pinhole else self._view_coordinates(polygon)
            rows = np.flatnonzero((self._row_hi >= xy[:, 1].min()) & (self._row_lo <= xy[:, 1].max()))
            cols = np.flatnonzero((self._col_hi >= xy[:, 0].min()) & (self._col_lo <= xy[:, 0].max()))
            if len(rows) == 0 or len(cols) == 0:
                continue
            box = (rows[0], rows[-1] + 1, cols[0], cols[-1] + 1)
            window = box if window is None else (min(window[0], box[0]), max(window[1], box[1]), min(window[2], box[2]), max(window[3], box[3]))
        if window is not None and len(poses) > 1:  # rows between first and last: pad a little
            pad = max(2, self.camera.height // 20)
            window = (max(0, window[0] - pad), min(self.camera.height, window[1] + pad), max(0, window[2] - pad), min(self.camera.width, window[3] + pad))
        return window

    @staticmethod
    def _view_coordinates(points: np.ndarray) -> np.ndarray:
        """A fisheye's view coordinates of (N, 3) camera-frame points: atan2(x, z), atan2(y, z)."""
        return np.arctan2(points[:, :2], points[:, 2:3])

    def _shade(self, rays: np.ndarray, rotation: np.ndarray, centres: np.ndarray, windows: dict[int, tuple[int, int, int, int]]) -> np.ndarray:
        """Nearest hit per pixel. For a quad with frame M = [n u v], a ray c + t r hits the plane at
        t = -(c - o).n / r.n, with surface coordinates (c - o).u + t r.u and (c - o).v + t r.v.
        ``rays`` are rotated to the world by ``rotation`` (so r.M = rays @ (rotation^T M)).
        Each quad is traced only inside its image window."""
        shape = rays.shape[:2]
        depth = np.full(shape, np.inf, dtype=np.float32)
        owner = np.full(shape, -1, dtype=np.int32)
        hits: dict[int, tuple] = {}
        for index, (r0, r1, c0, c1) in windows.items():
            quad = self.scene.quads[index]
            frame = np.stack([quad.normal, quad.axis_u, quad.axis_v], axis=1)
            along = rays[r0:r1, c0:c1] @ (rotation.T @ frame).astype(np.float32)  # r.n, r.u, r.v
            offset = ((centres[r0:r1] if centres.shape[0] > 1 else centres) - quad.origin) @ frame  # (c - o).n, .u, .v
            offset = offset.astype(np.float32)
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -offset[..., 0] / along[..., 0]
            a = offset[..., 1] + t * along[..., 1]
            b = offset[..., 2] + t * along[..., 2]
            window_depth = depth[r0:r1, c0:c1]
            visible = (t > 1e-6) & (a >= 0) & (a <= quad.size_u) & (b >= 0) & (b <= quad.size_v)
            if hits:  # the first quad traced competes with nothing yet
                visible &= t < window_depth
            if visible.all():  # common case (the ground filling the view): no masked writes
                window_depth[...] = t
                owner[r0:r1, c0:c1] = index
                hits[index] = (a, b, t, along[..., 0])
            elif visible.any():
                window_depth[visible] = t[visible]
                owner[r0:r1, c0:c1][visible] = index
                hits[index] = (a, b, t, along[..., 0])
        image = np.full(shape, self.scene.background, dtype=np.uint8)
        for index, (a, b, t, denominator) in hits.items():
            r0, r1, c0, c1 = windows[index]
            mask = owner[r0:r1, c0:c1] == index
            if not mask.any():
                continue
            full = mask.all() and (r1 - r0, c1 - c0) == shape
            samples = self._sample(self.scene.quads[index], None if full else mask, a, b, t, denominator, self._ray_norm[r0:r1, c0:c1])
            if full:
                return samples
            image[r0:r1, c0:c1][mask] = samples[mask]
        return image

    def _sample(self, quad: TexturedQuad, mask: np.ndarray | None, a, b, t, denominator, ray_norm) -> np.ndarray:
        """Bilinear texture samples over a window (valid where ``mask``) from the mip level whose
        texel size matches the pixel footprint.

        A pixel covers about range x (1 / fx) / cos(incidence) metres of surface; with rays
        normalised to z = 1 that is t |ray|^2 / (fx |ray . n|), the same with a fisheye's unit
        bearings (its pixels span about 1 / fx radians wherever they are). The median over a sparse
        grid of the quad's pixels picks the level.
        """
        step = max(1, int(np.sqrt(t.size / 2000)))
        sub = (slice(None, None, step), slice(None, None, step))
        footprints = t[sub] * ray_norm[sub] ** 2 / (self.camera.fx * np.maximum(np.abs(denominator[sub]), 1e-9))
        picked = footprints if mask is None else footprints[mask[sub]]
        footprint = float(np.median(picked)) if picked.size else float(np.median(np.abs(footprints)))
        level = int(max(0, np.floor(np.log2(max(footprint / quad.metres_per_texel, 1.0)))))
        texture = quad.mip(level)
        map_x = a * np.float32(texture.shape[1] / quad.size_u) - np.float32(0.5)
        map_y = b * np.float32(texture.shape[0] / quad.size_v) - np.float32(0.5)
        if mask is not None:
            map_x[~mask] = -1.0
            map_y[~mask] = -1.0
        return cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def _clip_to_frustum(polygon: np.ndarray, planes: np.ndarray) -> np.ndarray | None:
    """Sutherland-Hodgman clipping of a 3-D polygon (camera frame) to the half-spaces
    normal . p + offset >= 0 of the (normal, offset) rows of ``planes``."""
    points = list(polygon)
    for plane in planes:
        if not points:
            return None
        clipped = []
        for k, current in enumerate(points):
            previous = points[k - 1]
            d_cur = plane[:3] @ current + plane[3]
            d_prev = plane[:3] @ previous + plane[3]
            if d_cur >= 0:
                if d_prev < 0:
                    clipped.append(previous + (current - previous) * d_prev / (d_prev - d_cur))
                clipped.append(current)
            elif d_prev >= 0:
                clipped.append(previous + (current - previous) * d_prev / (d_prev - d_cur))
        points = clipped
    return np.array(points) if len(points) >= 3 else None


def ray_distance(scene: Scene, origin: np.ndarray, direction: np.ndarray) -> float:
    """Distance along a unit ``direction`` from ``origin`` to the nearest quad (inf if none)."""
    origins, normals, axes_u, axes_v, sizes = scene.arrays()
    along = normals @ direction
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = -np.einsum("ij,ij->i", origin - origins, normals) / along
        hit = origin + t[:, None] * direction - origins
        a = np.einsum("ij,ij->i", hit, axes_u)
        b = np.einsum("ij,ij->i", hit, axes_v)
    valid = (np.abs(along) > 1e-12) & (t > 0) & (a >= 0) & (a <= sizes[:, 0]) & (b >= 0) & (b <= sizes[:, 1])
    return float(t[valid].min()) if valid.any() else float("inf")
