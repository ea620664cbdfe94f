"""Geometry helpers: camera frustum, polylines, arcs, tubes and covariance ellipsoids.

All lengths are in metres. Poses are 4x4 homogeneous matrices.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import meshcat.geometry as mg
import numpy as np

from .style import rgb_int


def image_corners(intrinsics: Mapping[str, float], depth: float) -> np.ndarray:
    """(4, 3) camera-frame points [m] of the image corners back-projected to `depth` [m].

    Order: (0, 0), (W, 0), (W, H), (0, H) in pixels (OpenCV: x right, y down, z forward).
    """
    fx, fy, cx, cy = (float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy"))
    w, h = float(intrinsics["width"]), float(intrinsics["height"])
    uv = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    x = (uv[:, 0] - cx) / fx * depth
    y = (uv[:, 1] - cy) / fy * depth
    return np.column_stack([x, y, np.full(4, depth)])


def transform_points(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 4x4 pose to (N, 3) points."""
    pts = np.asarray(pts, dtype=float).reshape(-1, 3)
    return pts @ T[:3, :3].T + T[:3, 3]


def frustum_segments(intrinsics: Mapping[str, float], depth: float) -> np.ndarray:
    """(16, 3) camera-frame segment end points: centre->corners and the far rectangle."""
    c = image_corners(intrinsics, depth)
    segs = []
    for i in range(4):
        segs += [np.zeros(3), c[i], c[i], c[(i + 1) % 4]]
    return np.array(segs)


def rectangle_segments(corners: np.ndarray) -> np.ndarray:
    """(8, 3) segment end points of the closed quadrilateral through 4 corners."""
    return np.array([p for i in range(4) for p in (corners[i], corners[(i + 1) % 4])])


def line_segments(points: np.ndarray, color: Sequence[float],
                  opacity: float = 1.0) -> mg.LineSegments:
    """Meshcat LineSegments object (pairs of points) in one colour (transparent if opacity < 1)."""
    geo = mg.PointsGeometry(np.asarray(points, dtype=np.float32).T)
    mat = mg.LineBasicMaterial(color=rgb_int(color), opacity=float(opacity),
                               **({"depthWrite": False} if opacity < 1 else {}))
    return mg.LineSegments(geo, mat)


def polyline(points: np.ndarray, color: Sequence[float]) -> mg.Line:
    """Meshcat Line object through the points, in one colour."""
    geo = mg.PointsGeometry(np.asarray(points, dtype=np.float32).T)
    return mg.Line(geo, mg.LineBasicMaterial(color=rgb_int(color)))


def arc_points(radius: float, start: float, sweep: float, n: int = 61) -> np.ndarray:
    """(n, 3) points [m] of a circular arc of `radius` [m] in the x-y plane, centred at the
    origin, from angle `start` [rad] (from +x towards +y) over `sweep` [rad]."""
    a = start + np.linspace(0.0, sweep, n)
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n)])


def quad(corners: np.ndarray) -> mg.TriangularMeshGeometry:
    """Two-triangle surface of a planar quadrilateral given by 4 corners."""
    return mg.TriangularMeshGeometry(np.asarray(corners), np.array([[0, 1, 2], [0, 2, 3]]))


def tube(points: np.ndarray, radius: float, sides: int = 8) -> mg.TriangularMeshGeometry | None:
    """Triangle mesh of a tube of `radius` [m] along the polyline `points` (N, 3).

    Returns None when the polyline has fewer than two distinct points.
    """
    pts = np.asarray(points, dtype=float)
    keep = [0] + [i for i in range(1, len(pts)) if np.linalg.norm(pts[i] - pts[i - 1]) > 1e-9]
    pts = pts[keep]
    if len(pts) < 2:
        return None
    tang = np.gradient(pts, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True) + 1e-15
    ref = np.array([0.0, 0.0, 1.0]) if abs(tang[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    rings = []
    normal = np.cross(tang[0], ref)
    for p, t in zip(pts, tang):
        normal = normal - t * (normal @ t)  # parallel transport of the ring's frame
        normal /= np.linalg.norm(normal) + 1e-15
        binormal = np.cross(t, normal)
        phi = np.linspace(0, 2 * np.pi, sides, endpoint=False)
        rings.append(p + radius * (np.outer(np.cos(phi), normal) + np.outer(np.sin(phi), binormal)))
    return mg.TriangularMeshGeometry(np.concatenate(rings), ring_faces(len(pts), sides))


def ring_faces(n_rings: int, n: int) -> np.ndarray:
    """Triangles joining consecutive rings of `n` vertices each (vertices stored
    ring after ring)."""
    faces = []
    for i in range(n_rings - 1):
        for j in range(n):
            a, b = i * n + j, i * n + (j + 1) % n
            faces += [[a, b, b + n], [a, b + n, a + n]]
    return np.array(faces)


def covariance_ellipsoid(
    cov: np.ndarray, rotation: np.ndarray | None = None, n_sigma: float = 3.0
) -> tuple[np.ndarray, np.ndarray]:
    """Radii [m] and orientation of the n-sigma ellipsoid of a 3x3 position covariance [m^2].

    `rotation` (3x3) maps the covariance's frame into the drawing frame (camera ->
    world); the covariance in the drawing frame is `R cov R^T`. Returns
    `(radii, axes)`: radii = n_sigma * sqrt(eigenvalues) (negative eigenvalues from
    round-off clipped to 0), axes = 3x3 rotation whose columns are the eigenvectors
    in the drawing frame (det +1).
    """
    cov = np.asarray(cov, dtype=float)
    cov = 0.5 * (cov + cov.T)
    lam, vec = np.linalg.eigh(cov)
    if rotation is not None:
        vec = np.asarray(rotation, dtype=float) @ vec
    if np.linalg.det(vec) < 0:
        vec[:, 2] = -vec[:, 2]
    return n_sigma * np.sqrt(np.clip(lam, 0.0, None)), vec
