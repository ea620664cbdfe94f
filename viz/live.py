"""The live loop in Meshcat (`surestep sim-robot --meshcat`): the scene `surestep show` draws for a
problem (camera, goal, start, the straight line, the arm), then the arm at its measured joints and
the tracker's belief (its mean, the 3-sigma position ellipsoid) moved as they change."""

from __future__ import annotations

import meshcat.geometry as mg
import numpy as np
from meshcat.animation import Animation

from . import style
from .scene import ROOT, _loader, build_scene
from .shapes import covariance_ellipsoid
from .solutions import Solution, camera_pose

BELIEF = "live/belief"  # under ROOT


class LiveView:
    """`update(q, mean, cov)` poses the arm at joints `q` (the solution's joint order) and the
    belief (camera frame: mean `[p, axis-angle]`, 6x6 covariance) in `vis`."""

    def __init__(self, sol: Solution, vis):
        self.vis, self.info = vis, build_scene([sol], vis=vis)
        vis.set_animation(Animation(), play=False)  # the live joints move the arm, not a clip
        self.robot = _loader(None, sol)(sol["robot"], "robot")
        self.joint_names = sol.get("joint_names")
        self.camera = camera_pose(sol)
        self.updates = 0
        mat = mg.MeshPhongMaterial(color=style.rgb_int(style.method_colors(["ocp"])["ocp"]),
                                   opacity=0.35, depthWrite=False)
        vis[ROOT][BELIEF].set_object(mg.Sphere(1.0), mat)  # scaled by its transform

    def belief_transform(self, mean, cov) -> np.ndarray:
        """World transform of the unit sphere that is the belief's 3-sigma position ellipsoid."""
        C = self.camera
        r, V = covariance_ellipsoid(np.asarray(cov, float)[:3, :3], C[:3, :3], style.N_SIGMA)
        T = np.eye(4)
        T[:3, :3] = V @ np.diag(np.maximum(r, 1e-6))
        T[:3, 3] = C[:3, :3] @ np.asarray(mean, float)[:3] + C[:3, 3]
        return T

    def update(self, q, mean=None, cov=None) -> None:
        if self.robot is not None:
            qv = self.robot.q_vector([float(x) for x in q], self.joint_names)
            node = self.vis[ROOT][self.robot.root]
            for name, T in zip(self.robot.names, self.robot.placements(qv)):
                node[name].set_transform(T)
        if mean is not None and cov is not None and np.all(np.isfinite(mean)):
            self.vis[ROOT][BELIEF].set_transform(self.belief_transform(mean, cov))
        self.updates += 1
