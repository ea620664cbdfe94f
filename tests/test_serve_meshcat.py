"""The live Meshcat view of `surestep sim-robot --meshcat` (viz/live.py): the arm's and the
belief's updates as recorded by a server-less visualizer (checked against Pinocchio's placements
and the covariance), and sim-robot with its own Meshcat server on 127.0.0.1 over loopback DDS."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("meshcat")

ROOT = Path(__file__).resolve().parents[1]
PROBLEM = str(ROOT / "problems" / "needle_regrasp.yaml")


def _matrix(cmd) -> np.ndarray:
    return np.array(cmd["matrix"], float).reshape(4, 4).T  # meshcat sends it column-major


@pytest.fixture(scope="module")
def view():
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup
    from surestep_ocp.methods.registry import run_method
    from surestep_ocp.viz.live import LiveView
    from surestep_ocp.viz.recorder import recording_visualizer

    setup = build_setup(load_problem(PROBLEM))
    vis, window = recording_visualizer()
    return LiveView(run_method(setup, "baseline").to_dict(), vis), window, setup


def test_the_arm_and_the_belief_follow_their_updates(view):
    from surestep_ocp.viz.scene import ROOT as SCENE
    from surestep_ocp.viz.live import BELIEF

    live, window, setup = view
    rng = np.random.default_rng(0)
    C = live.camera
    for q in (np.array(setup.q_start, float), np.array(setup.q_goal, float)):
        A = rng.normal(size=(6, 6)) * 1e-3
        cov, mean = A @ A.T, np.r_[setup.pose_of(q)[:3], 0.1, 0.2, 0.3]
        live.update(q, mean, cov)
        expected = live.robot.placements(live.robot.q_vector(q.tolist(), live.joint_names))
        for name, T in zip(live.robot.names, expected):
            sent = [c for c in window.decoded[f"{SCENE}/robot/{name}"]
                    if c["type"] == "set_transform"][-1]
            assert np.allclose(_matrix(sent), T, atol=1e-9)
        E = _matrix([c for c in window.decoded[f"{SCENE}/{BELIEF}"]
                     if c["type"] == "set_transform"][-1])
        # the unit sphere's image: 3-sigma of the position covariance, in the world
        R = C[:3, :3]
        assert np.allclose(E[:3, :3] @ E[:3, :3].T, 9 * R @ cov[:3, :3] @ R.T, atol=1e-12)
        assert np.allclose(E[:3, 3], R @ mean[:3] + C[:3, 3], atol=1e-12)
    assert live.updates == 2
    # the two configurations differ: the arm moved
    tip = [c for c in window.decoded[f"{SCENE}/robot/{live.robot.names[-1]}"]
           if c["type"] == "set_transform"]
    assert not np.allclose(_matrix(tip[-1]), _matrix(tip[-2]))


def test_sim_robot_serves_the_view_on_loopback(tmp_path):
    pytest.importorskip("cyclonedds")
    from serve_dds import SURESTEP, free_domain, loopback_env

    env = loopback_env(tmp_path, free_domain())
    r = subprocess.run(SURESTEP + ["sim-robot", PROBLEM, "--meshcat", "20", "--duration", "2"],
                       env=env, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    said = [ln for ln in r.stderr.splitlines() if "Meshcat view at" in ln]
    assert said and "http://127.0.0.1:" in said[0], r.stderr
    n = int(r.stdout.split(" Meshcat updates sent")[0].rsplit(" ", 1)[1])
    assert n >= 1


def test_bad_meshcat_rate_exits_2(capsys):
    from surestep_ocp.cli import main

    assert main(["sim-robot", PROBLEM, "--meshcat", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--meshcat" in err[0]
