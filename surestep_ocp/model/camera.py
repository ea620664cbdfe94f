"""Pinhole camera: intrinsics and the normalised image offset used by the FOV noise.

Camera frame convention (stated once): OpenCV, x right, y down, z forward [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics [px] and image size [px]."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def offset(self, p):
        """Offset of the projection of `p` (camera frame) from the image centre.

        Measured on the normalised image plane, `((u - W/2)/fx, (v - H/2)/fy)`,
        where `(u, v)` is the pinhole projection (works on CasADi and NumPy).
        """
        du = p[0] / p[2] + (self.cx - self.width / 2) / self.fx
        dv = p[1] / p[2] + (self.cy - self.height / 2) / self.fy
        return du, dv

    def project(self, p: np.ndarray) -> np.ndarray:
        """Pixel coordinates `(u, v)` of camera-frame points `p` (..., 3)."""
        p = np.asarray(p, dtype=float)
        return np.stack([self.fx * p[..., 0] / p[..., 2] + self.cx,
                         self.fy * p[..., 1] / p[..., 2] + self.cy], -1)

    def in_image(self, p: np.ndarray) -> bool:
        """Whether a camera-frame point projects inside the image and lies in front."""
        if p[2] <= 0:
            return False
        u, v = self.project(p)
        return 0 <= u <= self.width and 0 <= v <= self.height

    def to_dict(self) -> dict:
        return {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "width": self.width,
                "height": self.height}
