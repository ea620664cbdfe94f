"""When the tracker's detector sees the tool: the rest of the time the tracker only predicts.

The evaluation's rollouts draw detections from it, and a plan's confidence (methods/confidence.py)
counts only the observations it would deliver (a problem's `detection:` section): a belief that is
to be calibrated must know what the detector delivers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Detection:
    """When the detector sees the tool (the true pose): the rest of the time the EKF only predicts.

    margin: fraction of the image width / height at each border where nothing is detected
    (the tool's features must be in the image, not only its tracked point); min_depth [m]:
    closer to the lens (or behind it) nothing is detected; max_depth [m]: nor beyond it (out
    of focus, too small); falloff: fraction of the image size over which the detection
    probability rises linearly from 0 at that border to 1 inside (0: detected with certainty
    everywhere inside). A detector reports a pose it sees: a measurement that itself falls
    outside that region (the sampled noise put it there) is no detection either (gating).
    """

    margin: float = 0.02
    min_depth: float = 0.02
    max_depth: float = 0.30
    falloff: float = 0.0

    def probability(self, camera, p: np.ndarray) -> np.ndarray:
        """(N,) detection probability of true positions p (N, 3) in the camera frame."""
        z = p[:, 2]
        ok = (z > self.min_depth) & (z < self.max_depth)
        zs = np.where(ok, z, 1.0)
        u = (camera.fx * p[:, 0] / zs + camera.cx) / camera.width
        v = (camera.fy * p[:, 1] / zs + camera.cy) / camera.height
        # distance to the detectable region's border, in image fractions (negative outside)
        inside = np.minimum.reduce([u - self.margin, 1 - self.margin - u, v - self.margin,
                                    1 - self.margin - v])
        if self.falloff > 0:
            prob = np.clip(inside / self.falloff, 0.0, 1.0)
        else:
            prob = (inside >= 0).astype(float)
        return np.where(ok, prob, 0.0)
