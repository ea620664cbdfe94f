"""Reading solution JSON files and turning their camera-frame data into world coordinates.

A solution is one JSON object per solved method (see the solver's output):
`poses` are `[px, py, pz, rx, ry, rz]` in the OpenCV camera frame (position [m],
axis-angle [rad]), `camera_pose` is the 4x4 world pose of that frame, `sigma`
the 6x6 covariances (position block first).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from surestep_ocp.output.files import MAX_SOLUTION_BYTES, input_file_problem

Solution = dict[str, Any]

COMPARISON_FILE = "comparison.json"


def load_solutions(path: Path | str) -> list[Solution]:
    """Solutions from one JSON file, or from every `*.json` in a directory except comparison.json.

    A file may hold one solution object or a list of them. Each returned dict gets
    `_source` (the file it came from). Files in a directory are read in name order;
    objects without `poses` are skipped there.
    """
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.glob("*.json") if p.name != COMPARISON_FILE)
        if not files:
            raise FileNotFoundError(f"no solution *.json in {path}")
    else:
        files = [path]
    out: list[Solution] = []
    for f in files:
        problem = input_file_problem(f, MAX_SOLUTION_BYTES)
        if problem is not None:
            raise ValueError(problem)
        data = json.loads(f.read_text(encoding="utf-8"))
        for sol in data if isinstance(data, list) else [data]:
            if not isinstance(sol, dict) or ("poses" not in sol and path.is_dir()):
                continue
            if "poses" not in sol:
                raise ValueError(f"{f} is not a solution file (no 'poses')")
            sol = dict(sol)
            sol.setdefault("method", f.stem)
            sol["_source"] = str(f)
            out.append(sol)
    return out


def order_methods(solutions: Sequence[Solution]) -> list[Solution]:
    """Solutions sorted baseline, gradient, ocp first, then the others by name."""
    rank = {"baseline": 0, "gradient": 1, "ocp": 2}
    return sorted(solutions, key=lambda s: (rank.get(s["method"], 3), s["method"]))


def rotation_from_axis_angle(r: Sequence[float]) -> np.ndarray:
    """3x3 rotation of an axis-angle vector [rad] (Rodrigues)."""
    r = np.asarray(r, dtype=float)
    th = float(np.linalg.norm(r))
    if th < 1e-12:
        return np.eye(3)
    k = r / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def pose_matrix(pose: Sequence[float]) -> np.ndarray:
    """4x4 pose of `[px, py, pz, rx, ry, rz]` (m, axis-angle rad)."""
    T = np.eye(4)
    T[:3, :3] = rotation_from_axis_angle(pose[3:6])
    T[:3, 3] = np.asarray(pose[:3], dtype=float)
    return T


def camera_pose(sol: Solution) -> np.ndarray:
    """4x4 world pose of the camera frame of a solution."""
    return np.asarray(sol["camera_pose"], dtype=float).reshape(4, 4)


def valid_nodes(sol: Solution) -> list[int]:
    """Indices t whose pose is present (not null)."""
    return [t for t, p in enumerate(sol["poses"]) if p is not None and None not in p]


def node_camera_poses(sol: Solution) -> list[np.ndarray]:
    """4x4 world pose of the camera frame each node's pose is expressed in (the camera may move)."""
    if sol.get("camera_poses"):
        return [np.asarray(C, dtype=float).reshape(4, 4) for C in sol["camera_poses"]]
    return [camera_pose(sol)] * len(sol["poses"])


def world_points(sol: Solution) -> np.ndarray:
    """(N, 3) tool positions in the world [m], `camera_pose_t @ p_t`, for the valid nodes."""
    C = node_camera_poses(sol)
    pts = [C[t][:3, :3] @ np.asarray(sol["poses"][t][:3], dtype=float) + C[t][:3, 3]
           for t in valid_nodes(sol)]
    return np.array(pts, dtype=float).reshape(-1, 3)


def world_pose(sol: Solution, pose: Sequence[float]) -> np.ndarray:
    """4x4 world pose of a camera-frame pose `[p, r]` of this solution."""
    return camera_pose(sol) @ pose_matrix(pose)


def position_covariances(sol: Solution) -> list[np.ndarray | None]:
    """3x3 camera-frame position covariance [m^2] per node (None where missing)."""
    out: list[np.ndarray | None] = []
    for S in sol.get("sigma") or []:
        out.append(None if S is None else np.asarray(S, dtype=float).reshape(6, 6)[:3, :3])
    return out
