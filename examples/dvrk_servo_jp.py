"""The crtk `servo_jp` stream a dVRK Python client sends for an exported trajectory (a
dry run by default).

Reads `surestep export --format json` output and iterates its set-points every 1/rate s: the six
arm joints' positions (cubic Hermite through the exported samples and velocities: at the exported
samples' times, exactly them) and the jaw's, as `PSM1/servo_jp` and `PSM1/jaw/servo_jp` would
receive them. Without `--trajectory` it plans the default problem's straight line at `--horizon`
and exports it first.

    .venv/bin/python examples/dvrk_servo_jp.py [--trajectory EXPORT.json] [--rate 100] \
        [--output-dir out/servo_jp]
    # a real dVRK (see below):
    .venv/bin/python examples/dvrk_servo_jp.py --trajectory EXPORT.json --robot PSM1

`--robot ARM` sends the stream through the dVRK's ROS 2 Python client (`crtk` and `dvrk`, from the
dVRK's own workspace, not PyPI) when both import: enable, home, `move_jp` to the first set-point,
then `servo_jp` at the rate. That branch was not run here (no ROS, no dVRK on this machine). The
file's joint names should be the arm's (`surestep export --joint-names`,
docs/motion_limits_and_export.md, "Joint names").
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicHermiteSpline

ap = argparse.ArgumentParser()
ap.add_argument("--trajectory",
                help="a `surestep export --format json` file (default: plan and export one)")
ap.add_argument("--rate", type=float, default=100.0, help="set-points per second (default 100)")
ap.add_argument("--horizon", type=int, default=20,
                help="without --trajectory: the plan's steps (default 20)")
ap.add_argument("--output-dir", default="out/servo_jp",
                help="without --trajectory: where the plan and its export go")
ap.add_argument("--robot", metavar="ARM",
                help="send to this dVRK arm (e.g. PSM1) through crtk/dvrk, if installed")
args = ap.parse_args()

if args.trajectory is None:  # plan and export, as `surestep solve` and `surestep export` would
    import surestep_ocp as ss
    from surestep_ocp.cli import main as surestep

    out = Path(args.output_dir)
    out.mkdir(parents=True, exist_ok=True)
    problem = ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(args.horizon)
    plan = ss.solve(problem, method="baseline").save(out / "plan.json")
    args.trajectory = out / "servo_jp_trajectory.json"
    assert surestep(["export", str(plan), "--format", "json", "--output", str(args.trajectory),
                     "--no-plot"]) == 0

d = json.loads(Path(args.trajectory).read_text())
t = np.array(d["time_s"])
arm = CubicHermiteSpline(t, np.array(d["positions"]), np.array(d["velocities"]))
jaw = (CubicHermiteSpline(t, np.array(d["jaw"]["positions"]), np.array(d["jaw"]["velocities"]))
       if "jaw" in d else None)
ticks = np.arange(int(np.ceil(t[-1] * args.rate - 1e-6)) + 1) / args.rate
at = np.minimum(ticks, t[-1])  # from the end on (the last tick): the last waypoint, held
setpoints = [(tk, arm(a), None if jaw is None else np.atleast_1d(jaw(a)))
             for tk, a in zip(ticks, at)]

names = d["joint_names"]
print(f"{args.trajectory}: {len(setpoints)} servo_jp set-points at {args.rate:g} Hz "
      f"over {t[-1]:.3f} s, joints {', '.join(names)} "
      f"(naming: {(d.get('joint_naming') or {}).get('choice', 'not recorded')}), "
      f"timing {d['timing']}")
lim = d["limits"]  # in the URDF's joint order, the written names' order too
vmax = np.array([v for n, v in zip(lim["joint_names"], lim["velocity"]) if n != "jaw"])
steps = np.abs(np.diff([q for _, q, _ in setpoints], axis=0)) * args.rate
print(f"largest mean speed between set-points: {np.max(steps / vmax):.3f} of the joint velocity "
      "limit")

client = None
if args.robot:
    try:  # the dVRK's ROS 2 Python client (dvrk_python / crtk_python_client); not on PyPI
        import crtk
        import dvrk
    except ImportError as exc:
        print(f"--robot {args.robot}: the dVRK's Python client is not importable ({exc}); a dry "
              "run instead")
    else:  # not run here: no ROS, no dVRK
        ral = crtk.ral("surestep_servo_jp")
        client = dvrk.psm(ral, args.robot)
        ral.check_connections()
        ral.spin()
        client.enable(10)
        client.home(10)
        # servo_jp expects small steps: start where the stream starts
        client.move_jp(setpoints[0][1]).wait()

start = time.perf_counter()
for k, (tk, q, j) in enumerate(setpoints):
    if client is not None:
        while time.perf_counter() - start < tk:  # real time: one set-point per tick
            time.sleep(min(1e-3, max(0.0, tk - (time.perf_counter() - start))))
        client.servo_jp(q)
        if j is not None:
            client.jaw.servo_jp(j)
    elif k < 3 or k >= len(setpoints) - 2:  # the dry run: what would be sent, first and last few
        jaw_text = "" if j is None else f"; jaw/servo_jp({j[0]:+.4f})"
        print(f"t = {tk:6.3f} s  servo_jp([{', '.join(f'{x:+.4f}' for x in q)}]){jaw_text}")
    elif k == 3:
        print("...")
if client is not None:
    ral.shutdown()
print(f"{'sent' if client is not None else 'dry run:'} {len(setpoints)} set-points")
