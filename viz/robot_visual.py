"""A URDF robot's visual geometry as Meshcat objects, posed by joint values.

Geometry comes from Pinocchio (`buildGeomFromUrdf`, VISUAL): boxes, spheres,
cylinders, cones, ellipsoids, capsules and meshes (any format coal/assimp loads:
STL, DAE, OBJ, ...; the mesh scale is already applied to the loaded vertices).
Each geometry object becomes one Meshcat node `/<root>/<geometry name>` whose
transform is `base_pose @ oMg(q)` in the world frame [m].
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import coal
import meshcat.geometry as mg
import numpy as np
import pinocchio as pin

from .shapes import ring_faces
from .style import rgb_int

# three.js cylinders are along y; URDF cylinders along z.
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


class _ZCylinder(mg.Cylinder):
    """Meshcat cylinder (or cone) with its axis along z, as in URDF."""

    def intrinsic_transform(self) -> np.ndarray:
        return _Y_TO_Z


def _capsule(radius: float, half_length: float, n: int = 24) -> mg.TriangularMeshGeometry:
    """Capsule along z: a lathe of two half circles joined by a cylinder [m]."""
    ang = np.linspace(-np.pi / 2, np.pi / 2, n // 2 + 1)
    top = [(radius * np.cos(a), half_length + radius * np.sin(a)) for a in ang if a >= 0]
    bot = [(radius * np.cos(a), -half_length + radius * np.sin(a)) for a in ang if a <= 0]
    profile = np.array(bot + top)  # (r, z) from the bottom pole to the top pole
    phi = np.linspace(0, 2 * np.pi, n, endpoint=False)
    verts = np.array([[r * np.cos(p), r * np.sin(p), z] for r, z in profile for p in phi])
    return mg.TriangularMeshGeometry(verts, ring_faces(len(profile), n))


def _mesh(geom: coal.CollisionGeometry) -> mg.TriangularMeshGeometry | None:
    """Triangle mesh of a loaded coal BVH model or convex polytope (vertices in [m])."""
    if isinstance(geom, coal.BVHModelBase):
        verts, n, tri = geom.vertices(), geom.num_tris, geom.tri_indices
    elif isinstance(geom, coal.ConvexBase):
        verts, n, tri = geom.points(), geom.num_polygons, geom.polygons
    else:
        return None
    if n == 0:
        return None
    faces = np.array([[tri(k)[i] for i in range(3)] for k in range(n)], dtype=np.uint32)
    return mg.TriangularMeshGeometry(np.asarray(verts, dtype=np.float32), faces)


def meshcat_geometry(gobj: pin.GeometryObject) -> mg.Geometry | None:
    """Meshcat geometry of one Pinocchio geometry object, or None (with a warning)."""
    g = gobj.geometry
    if isinstance(g, coal.Box):
        return mg.Box([float(x) for x in 2.0 * np.asarray(g.halfSide)])
    if isinstance(g, coal.Sphere):
        return mg.Sphere(float(g.radius))
    if isinstance(g, coal.Cylinder):
        return _ZCylinder(2.0 * g.halfLength, float(g.radius))
    if isinstance(g, coal.Cone):
        return _ZCylinder(2.0 * g.halfLength, radiusTop=0.0, radiusBottom=float(g.radius))
    if isinstance(g, coal.Capsule):
        return _capsule(float(g.radius), float(g.halfLength))
    if isinstance(g, coal.Ellipsoid):
        return mg.Ellipsoid([float(x) for x in g.radii])
    mesh = _mesh(g)
    if mesh is None:
        warnings.warn(f"geometry {gobj.name!r} ({type(g).__name__}) cannot be drawn; skipped")
    return mesh


def _package_dirs(urdf: Path, extra: Sequence[Path] = ()) -> list[str]:
    """Folders where `package://name/...` is looked up: the URDF's ancestors, then `extra`."""
    dirs = [urdf.parent, *list(urdf.parents)[1:6], *extra]
    return [str(d) for d in dirs if d.is_dir()]


@dataclass
class RobotVisual:
    """A robot's kinematic and visual model placed in the world.

    Attributes:
        model: Pinocchio kinematic model.
        geom: Pinocchio VISUAL geometry model.
        base_pose: 4x4 pose of the URDF root in the world frame [m].
        root: Meshcat node under which the geometry nodes live (e.g. "robot").
        names: node name of each geometry object (same order as `geom.geometryObjects`).
    """

    model: pin.Model
    geom: pin.GeometryModel
    base_pose: np.ndarray
    root: str
    names: list[str] = field(default_factory=list)

    @classmethod
    def load(
        cls, urdf: Path, base_pose: np.ndarray, root: str, package_dirs: Sequence[Path] = ()
    ) -> "RobotVisual":
        """Load a URDF and its visual geometry (meshes searched via `package_dirs`)."""
        urdf = Path(urdf)
        model = pin.buildModelFromUrdf(str(urdf))
        dirs = _package_dirs(urdf, package_dirs)
        geom = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=dirs)
        names = [g.name.replace("/", "_") for g in geom.geometryObjects]
        return cls(model, geom, np.asarray(base_pose, dtype=float), root, names)

    def q_vector(
        self, values: Sequence[float | None] | None, joint_names: Sequence[str] | None = None
    ) -> np.ndarray | None:
        """Pinocchio configuration from one value per named 1-DoF joint [rad or m].

        `joint_names=None` means the values follow the model's joint order. Joints
        missing from the names keep their neutral value; unknown names are ignored.
        Returns None when `values` is None or holds a None (an unreachable node).
        """
        if values is None or any(v is None for v in values):
            return None
        if joint_names is None:
            joint_names = [self.model.names[j] for j in range(1, self.model.njoints)]
        q = pin.neutral(self.model)
        for name, v in zip(joint_names, values):
            if not self.model.existJointName(name):
                continue
            jm = self.model.joints[self.model.getJointId(name)]
            if jm.nq == 1:
                q[jm.idx_q] = float(v)
            elif jm.nq == 2 and jm.nv == 1:  # continuous: (cos, sin)
                q[jm.idx_q : jm.idx_q + 2] = np.cos(float(v)), np.sin(float(v))
        return q

    def placements(self, q: np.ndarray) -> list[np.ndarray]:
        """World pose (4x4) of every geometry object at configuration `q`."""
        data = self.model.createData()
        gdata = pin.GeometryData(self.geom)
        pin.forwardKinematics(self.model, data, q)
        pin.updateGeometryPlacements(self.model, data, self.geom, gdata)
        return [self.base_pose @ np.asarray(M.homogeneous) for M in gdata.oMg]

    def frame_pose(self, q: np.ndarray, frame: str) -> np.ndarray:
        """World pose (4x4) of a named frame at configuration `q`."""
        data = self.model.createData()
        pin.framesForwardKinematics(self.model, data, q)
        fid = self.model.getFrameId(frame)
        return self.base_pose @ np.asarray(data.oMf[fid].homogeneous)

    def draw(self, vis, q: np.ndarray, color: Sequence[float] | None = None) -> list[str]:
        """Add every drawable geometry under `vis[root]` posed at `q`; return the full node paths.

        `color` (RGB or RGBA in [0, 1]) overrides the URDF material colours.
        """
        drawn = []
        for gobj, name, T in zip(self.geom.geometryObjects, self.names, self.placements(q)):
            shape = meshcat_geometry(gobj)
            if shape is None:
                continue
            rgba = list(color) if color is not None else list(np.asarray(gobj.meshColor))
            alpha = float(rgba[3]) if len(rgba) > 3 else 1.0
            material = mg.MeshPhongMaterial(color=rgb_int(rgba), opacity=alpha, shininess=30)
            node = vis[self.root][name]
            node.set_object(shape, material)
            node.set_transform(T)
            drawn.append(node.path.lower())
        return drawn

    def set_frame(self, frame_vis, q: np.ndarray) -> None:
        """Key-frame every geometry node at `q` (frame_vis from `Animation.at_frame`)."""
        for name, T in zip(self.names, self.placements(q)):
            frame_vis[self.root][name].set_transform(T)
