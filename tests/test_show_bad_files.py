"""`surestep show` keeps the file reader's promises: no NaN or Infinity reaches the
scene, every number it reads is finite and within the problem reader's ranges, and the work is
bounded (the solution file, the URDFs read: regular files of bounded size, never a device or a
pipe); each refusal is one line, exit 2."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from surestep_ocp.cli import main
from surestep_ocp.errors import SurestepError
from surestep_ocp.output.files import NonFinite
from user_errors import assert_user_error  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
PSM = str(REPO / "robots" / "psm.urdf")
ECM = str(REPO / "robots" / "ecm.urdf")


@pytest.fixture(scope="module")
def baseline(tmp_path_factory) -> dict:
    """The default problem's straight-line plan (no optimisation), its URDFs named by absolute
    paths."""
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup
    from surestep_ocp.methods.registry import run_method

    d = tmp_path_factory.mktemp("baseline")
    setup = build_setup(load_problem(REPO / "problems" / "needle_regrasp_paper_pace.yaml"))
    sol = json.loads(Path(run_method(setup, "baseline").save(d / "baseline.json")).read_text())
    sol["robot"]["urdf"] = PSM
    sol["ecm"]["urdf"] = ECM
    sol.pop("problem", None)
    return sol


def edited(sol: dict, edit) -> dict:
    d = json.loads(json.dumps(sol))
    edit(d)
    return d


def run_show(tmp_path, capsys, sol: dict | None = None, text: str | None = None):
    src = tmp_path / "plan.json"
    src.write_text(text if text is not None else json.dumps(sol))
    out = tmp_path / "scene.html"
    capsys.readouterr()
    code = main(["show", str(src), "--html", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err, out




def test_the_baseline_is_shown(baseline, tmp_path, capsys):
    code, err, out = run_show(tmp_path, capsys, baseline)
    assert code == 0, err
    assert out.is_file()


EDITS = {
    "ecm_q_nan": (lambda d: d["ecm"].update(q=[math.nan, 0.0, 0.05, 0.0]), "ecm.q"),
    "ecm_q_dict_inf": (lambda d: d["ecm"].update(q={"yaw": math.inf}), "ecm.q"),
    "other_arm_nan": (lambda d: d.update(other_arms=[{"urdf": PSM, "frame": "tool",
                                                      "q": [math.nan] * 7}]),
                      "other_arms[0].q"),
    "other_arm_base_zero": (lambda d: d.update(other_arms=[{"urdf": PSM,
                                                            "base_pose": [[0.0] * 4] * 4}]),
                            "other_arms[0].base_pose"),
    "camera_pose_zero": (lambda d: d.update(camera_pose=[[0.0] * 4] * 4), "camera_pose"),
    "camera_pose_far": (lambda d: d["camera_pose"][0].__setitem__(3, 1e300), "camera_pose"),
    "camera_pose_sheared": (lambda d: d["camera_pose"][0].__setitem__(1, 0.5), "camera_pose"),
    "pose_far": (lambda d: d["poses"][2].__setitem__(0, 1e300), "poses[2]"),
    "goal_far": (lambda d: d["goal"].__setitem__(2, 1e3), "goal"),
    "fx_tiny": (lambda d: d["camera"].update(fx=1e-300), "camera"),
    "fx_huge": (lambda d: d["camera"].update(fx=1e300), "camera"),
    "width_huge": (lambda d: d["camera"].update(width=1e300), "camera"),
    "sigma_huge": (lambda d: d["sigma"][1][0].__setitem__(0, 1e300), "sigma[1]"),
    "camera_poses_zero": (lambda d: d.update(camera_poses=[[[0.0] * 4] * 4] * len(d["poses"])),
                          "camera_poses[0]"),
    "q_huge": (lambda d: d["q"][1].__setitem__(0, 1e300), "q[1]"),
    "robot_base_far": (lambda d: d["robot"]["base_pose"][2].__setitem__(3, 1e300),
                       "robot.base_pose"),
    "needle_radius_nan": (lambda d: d["robot"].update(needle={"radius": math.nan}), "robot.needle"),
    "depth_star_inf": (lambda d: d["noise"].update(depth_star=math.inf), "noise.depth_star"),
    "too_many_waypoints": (lambda d: d.update(poses=[d["poses"][0]] * 10_001), "poses"),
}


@pytest.mark.parametrize("case", list(EDITS))
def test_out_of_range_numbers_are_one_line_errors(baseline, tmp_path, capsys, case):
    """Reproducer: NaN reached the scene for an ecm.q of NaN, other_arms with NaN joints, an
    all-zero camera_pose, a 1e300 translation or fx = 1e-300 (exit 0)."""
    edit, key = EDITS[case]
    code, err, out = run_show(tmp_path, capsys, edited(baseline, edit))
    assert_user_error(code, err, out, "plan.json", key)


def test_a_solution_dict_given_directly_is_checked(baseline, tmp_path):
    from viz.show import show

    with pytest.raises(SurestepError, match="camera_pose"):
        show([edited(baseline, lambda d: d.update(camera_pose=[[0.0] * 4] * 4))],
             html=tmp_path / "s.html")
    assert not (tmp_path / "s.html").exists()


def _show_in_subprocess(tmp_path, sol: dict | None, target: Path | None = None,
                        timeout: float = 120):
    """`surestep show` in a child process (a regression must not hang or exhaust this one)."""
    if target is None:
        target = tmp_path / "plan.json"
        target.write_text(json.dumps(sol))
    out = tmp_path / "scene.html"
    proc = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "show", str(target),
                           "--html", str(out)],
                          capture_output=True, text=True, timeout=timeout, cwd=tmp_path)
    return proc.returncode, proc.stderr.strip().splitlines(), out


def test_a_device_as_urdf_is_an_error(baseline, tmp_path):
    """Reproducer: `robot.urdf: /dev/zero` was read at length (its time and memory: CHANGELOG),
    then exited 0."""
    code, err, out = _show_in_subprocess(
        tmp_path, edited(baseline, lambda d: d["robot"].update(urdf="/dev/zero")), timeout=60)
    assert_user_error(code, err, out, "plan.json", "robot.urdf", "not a regular file")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
@pytest.mark.parametrize("arm", ["robot", "ecm", "other_arms"])
def test_a_pipe_as_urdf_is_an_error(baseline, tmp_path, arm):
    """Reproducer: a FIFO as the URDF blocked forever."""
    fifo = tmp_path / "arm.urdf"
    os.mkfifo(fifo)

    def edit(d):
        if arm == "other_arms":
            d["other_arms"] = [{"urdf": str(fifo), "frame": "tool"}]
        else:
            d[arm]["urdf"] = str(fifo)

    code, err, out = _show_in_subprocess(tmp_path, edited(baseline, edit), timeout=60)
    assert_user_error(code, err, out, "plan.json",
                      f"{arm}[0].urdf" if arm == "other_arms" else f"{arm}.urdf")


def test_a_too_large_urdf_is_an_error(baseline, tmp_path, capsys):
    big = tmp_path / "big.urdf"
    with big.open("wb") as f:
        f.truncate(20_000_000)
    code, err, out = run_show(tmp_path, capsys,
                              edited(baseline, lambda d: d["ecm"].update(urdf=str(big))))
    assert_user_error(code, err, out, "plan.json", "ecm.urdf", "bytes")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_pipe_as_the_solution_file_is_an_error(tmp_path):
    fifo = tmp_path / "plan.json"
    os.mkfifo(fifo)
    code, err, out = _show_in_subprocess(tmp_path, None, target=fifo, timeout=60)
    assert_user_error(code, err, out, "plan.json", "not a regular file")


def test_a_huge_solution_file_is_an_error(tmp_path, capsys):
    code, err, out = run_show(tmp_path, capsys, text=" " * 60_000_000 + "{}")
    assert_user_error(code, err, out, "plan.json", "bytes")


@pytest.mark.parametrize("text", ["[" * 100_000,
                                  '{"poses": [[' + "9" * 5000 + ", 0, 0, 0, 0, 0]]}"])
def test_deep_nesting_and_long_integers_are_errors(tmp_path, capsys, text):
    code, err, out = run_show(tmp_path, capsys, text=text)
    assert_user_error(code, err, out, "plan.json")


@pytest.mark.parametrize("flag", ["html", "screenshot"])
def test_an_empty_output_name_is_an_error_not_the_live_server(baseline, tmp_path, flag):
    """Reproducer: `show --html ""` started the live server and blocked (here: viz.show_main's
    path)."""
    from viz.show import show_main

    src = tmp_path / "plan.json"
    src.write_text(json.dumps(baseline))
    args = argparse.Namespace(target=src, open_browser=False, html=None, screenshot=None,
                              endoscope_view=False, animate=None)
    setattr(args, flag, "")
    with pytest.raises(SurestepError, match=f"--{flag}"):
        show_main(args)


def test_the_page_writer_refuses_non_finite_numbers(tmp_path):
    """check_finite at the writer: a transform or a geometry holding NaN writes no page."""
    import meshcat.geometry as mg

    from viz.recorder import recording_visualizer
    from viz.scene import check_scene_finite

    vis, window = recording_visualizer()
    vis["a"].set_transform(np.eye(4))
    check_scene_finite(window)
    T = np.eye(4)
    T[0, 3] = math.nan
    vis["a"].set_transform(T)
    with pytest.raises(NonFinite, match="meshcat/a"):
        check_scene_finite(window)
    vis2, window2 = recording_visualizer()
    vis2["p"].set_object(mg.PointsGeometry(np.array([[0.0, math.inf], [0.0, 0.0], [0.0, 0.0]])))
    with pytest.raises(NonFinite):
        check_scene_finite(window2)


def test_show_cli_refuses_an_empty_html_name(tmp_path):
    """`surestep show DIR --html ""` is a one-line error (it used to start the live server and
    block)."""
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "show", str(tmp_path),
                          "--html", ""],
                         capture_output=True, text=True, timeout=60)
    assert (run.returncode == 2 and "--html: an empty file name" in run.stderr
            and "Traceback" not in run.stderr)


def test_the_live_server_ends_with_a_killed_show(baseline, tmp_path):
    """Reproducer: SIGKILL of `surestep show` (live server) left its meshcat server running."""
    import select
    import signal
    import time

    psutil = pytest.importorskip("psutil")
    (tmp_path / "plan.json").write_text(json.dumps(baseline))
    show = subprocess.Popen([sys.executable, "-u", "-m", "surestep_ocp.cli", "show", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    children = []
    try:
        seen, deadline = b"", time.monotonic() + 180
        while b"Serving" not in seen and time.monotonic() < deadline and show.poll() is None:
            if select.select([show.stdout], [], [], 1.0)[0]:
                seen += os.read(show.stdout.fileno(), 4096)
        assert b"Serving" in seen, seen
        children = psutil.Process(show.pid).children(recursive=True)
        assert children, "show started no server process"
        show.send_signal(signal.SIGKILL)
        show.wait(timeout=60)

        def alive(p) -> bool:
            try:
                return p.status() != psutil.STATUS_ZOMBIE
            except psutil.NoSuchProcess:
                return False

        deadline = time.monotonic() + 60  # generous: the server goes within a second
        while any(map(alive, children)) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(map(alive, children)), [p.cmdline() for p in children if alive(p)]
    finally:
        if show.poll() is None:
            children = psutil.Process(show.pid).children(recursive=True)
        for p in [show, *children]:  # this test's own processes only
            with contextlib.suppress(ProcessLookupError, psutil.NoSuchProcess):
                p.kill()
        show.wait(timeout=60)
        show.stdout.close()
