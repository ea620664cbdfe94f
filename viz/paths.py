"""One method's path: polyline, tube and 3-sigma position ellipsoids (world frame, metres).

Nodes, under the given parent (normally `/meshcat/paths`):

    <method>/line             Line through the tool positions camera_pose @ p_t
    <method>/tube             the same path as a thin tube (visible at any zoom)
    <method>/ellipsoids/<t>   unit sphere scaled by 3 sqrt(eig(Sigma_t,pp)) along the
                              eigenvectors, rotated into the world

Ellipsoids are semi-transparent in the method's colour. Their opacity falls as
they grow (large, uncertain ones are faint, small ones solid) so that
overlapping paths stay readable; ones larger than `hide_above` start hidden, and
a path drawn with `ellipsoids_shown` shows only that many (the last node's and
evenly spaced ones before it), the rest start hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import meshcat.geometry as mg
import numpy as np

from . import style
from .shapes import covariance_ellipsoid, polyline, tube
from .solutions import Solution, node_camera_poses, position_covariances, valid_nodes, world_points


class _OnTopMesh(mg.Mesh):
    """Mesh drawn after the (transparent, later-sorted) ellipsoids, so they do not tint it.

    Its material must be `transparent` (three.js sorts transparent objects by
    renderOrder first); depth testing stays on, so the arm still hides it. Of two
    coinciding tubes, the one with the higher `render_order` shows.
    """

    def __init__(self, geometry, material, render_order: int = 10) -> None:
        super().__init__(geometry, material)
        self.render_order = render_order

    def lower(self) -> dict:
        data = super().lower()
        data["object"]["renderOrder"] = self.render_order
        return data


@dataclass
class PathInfo:
    """What was drawn for one method's path (world frame, metres)."""

    method: str
    color: tuple[float, float, float]
    nodes: list[int]  # node indices t drawn
    points: np.ndarray  # (N, 3) tool positions, camera_pose @ p_t
    radii: np.ndarray  # (M, 3) ellipsoid radii [m], N_SIGMA * sqrt(eig(Sigma_pp))
    axes: np.ndarray  # (M, 3, 3) ellipsoid axes (columns) in the world frame
    line_node: str
    ellipsoid_nodes: list[str]
    hidden: list[str]  # ellipsoid nodes that start hidden (larger than hide_above, or thinned out)


def ellipsoid_opacity(max_radius: float) -> float:
    """Opacity of an ellipsoid of the given largest radius [m]: ELLIPSOID_OPACITY up to
    ELLIPSOID_REF_RADIUS, then falling as 1/radius, never below ELLIPSOID_MIN_OPACITY."""
    scale = style.ELLIPSOID_REF_RADIUS / max(max_radius, 1e-12)
    return float(np.clip(style.ELLIPSOID_OPACITY * scale, style.ELLIPSOID_MIN_OPACITY,
                         style.ELLIPSOID_OPACITY))


def draw_path(parent, sol: Solution, color: tuple[float, float, float],
              hide_above: float = np.inf, priority: int = 0,
              tube_radius: float = style.TUBE_RADIUS, ellipsoids_shown: int | None = None,
              opacity_scale: float = 1.0) -> PathInfo:
    """Draw one solution's path under `parent[method]` and return what was drawn.

    `priority`: where tubes coincide, the path with the higher priority is on top (a
    thicker `tube_radius` [m] wins where tubes run along each other but differ slightly).
    `ellipsoids_shown`: at most this many ellipsoids start visible (None: all), each at
    `opacity_scale` times its usual opacity; the others are drawn hidden.
    """
    m = sol["method"]
    node = parent[m]
    base = node.path.lower()
    nodes, pts = valid_nodes(sol), world_points(sol)
    node["line"].set_object(polyline(pts, color))
    tube_geo = tube(pts, tube_radius)
    if tube_geo is not None:
        mat = mg.MeshBasicMaterial(color=style.rgb_int(color), transparent=True, opacity=1.0)
        node["tube"].set_object(_OnTopMesh(tube_geo, mat, 10 + priority))
    cams = node_camera_poses(sol)
    covs = position_covariances(sol)
    radii, axes, enodes, hidden = [], [], [], []
    stride = 1 if ellipsoids_shown is None else -(-len(nodes) // max(ellipsoids_shown, 1))
    for i, (t, p) in enumerate(zip(nodes, pts)):
        if t >= len(covs) or covs[t] is None:
            continue
        r, V = covariance_ellipsoid(covs[t], cams[t][:3, :3], style.N_SIGMA)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = V, p
        e = node["ellipsoids"][str(t)]
        mat = mg.MeshPhongMaterial(color=style.rgb_int(color),
                                   opacity=opacity_scale * ellipsoid_opacity(r.max()),
                                   depthWrite=False, side=0)
        e.set_object(mg.Ellipsoid(np.maximum(r, 1e-6).tolist()), mat)
        e.set_transform(T)
        path = f"{base}/ellipsoids/{t}"
        if r.max() > hide_above or (len(nodes) - 1 - i) % stride:
            e.set_property("visible", False)
            hidden.append(path)
        radii.append(r), axes.append(V), enodes.append(path)
    return PathInfo(m, color, nodes, pts, np.array(radii).reshape(-1, 3),
                    np.array(axes).reshape(-1, 3, 3), f"{base}/line", enodes, hidden)
