"""`surestep serve` against `surestep sim-robot` over loopback DDS (two processes each run, the
loopback-only Cyclone configuration of surestep_ocp/ros/loopback.py): episodes to the goal, then
(--faults) one run per injected fault.

Per episode: the goal reached (exit 0, `serve: goal reached`), executed set-points beyond a limit
(bounds; divided differences of the set-points at their stamps against the velocity and
acceleration limits: tests/test_serve.py's check), the servo stream (rate from the stamps and from
the send times, gaps longer than two periods), the latency from a tracker estimate's arrival to the
re-plan being ready and to the first set-point of the new plan, the re-plans not played. Per fault:
the hold's reason and its delay (tracker silent: from the timeout passing; NaN: from the estimate's
arrival; stuck: from the arm's error passing the tolerance; node killed: the simulated arm's own
hold), then, the fault cleared (sim-robot's `fault ... off`), the time to resume (to the first
set-point of the new motion; the node's `--resume-after` 0.3 s window and the restart included),
the goal reached after it, and the set-points beyond a limit (each stretch between holds checked
alone: the hold itself is a stop). Its last line: `serve-loop: key=value ...`.

Where the latency goes (the node's --log, each re-plan played): from the estimate's arrival to the
re-plan's start (decoded, moved to its waypoint), the re-plan, its hand-over to the servo process
(received there), the slack until its waypoint (the budget's rest), and from the waypoint's time to
its set-point written (the servo process's tick). `--load N` runs N busy processes (pure Python
loops, with the benchmark's CPU affinity and niceness; `--load-duty D`: each spins D of every 20 ms)
in each run from the node's first plan built (its auto budget measured under the load) to the
run's end: a loaded core.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/serve_loop.py [--episodes 20] [--faults]
        [--budget auto|S] [--load N] [--servo-priority N] [--output FILE.md]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from serve_dds import Recorder, loopback_env  # noqa: E402

PROBLEM = str(ROOT / "problems" / "needle_regrasp.yaml")
# a busy process: spins `duty` of every 20 ms (its CPU affinity and niceness the benchmark's)
HOG = """
import sys, time
duty, t = float(sys.argv[1]), time.monotonic()
while True:
    t += 0.02
    while time.monotonic() < t - 0.02 * (1 - duty):
        pass
    time.sleep(max(0.0, t - time.monotonic()))
"""
CLI = [sys.executable, "-m", "surestep_ocp.cli"]


def run(tmp: Path, domain: int, serve_args, sim_args, kill_after=None, timeout=240.0,
        stop_on_hold=True, load=(0, 1.0)):
    """One node + simulated robot run; the recorder's servo_jp samples decoded, the node's log.
    `load`: (N, duty) busy processes from the node's first plan built (it says it waits for the
    tracker: the build, 20-40 s of CPU, is not the loop's) to the run's end."""
    from surestep_ocp.ros import messages as m

    env = loopback_env(tmp, domain)
    os.environ["CYCLONEDDS_URI"] = env["CYCLONEDDS_URI"]
    rec = Recorder(domain, {"/PSM1/servo_jp": m.JointState, "/PSM1/jaw/servo_jp": m.JointState,
                            "/PSM1/measured_js": m.JointState, "/surestep/status": m.String})
    sim = subprocess.Popen(CLI + ["sim-robot", PROBLEM] + sim_args, env=env,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    serve = subprocess.Popen(CLI + ["serve", PROBLEM, "--log", str(tmp / "log.json")] + serve_args,
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err_lines: list = []
    reader = threading.Thread(target=lambda: err_lines.extend(serve.stderr), daemon=True)
    reader.start()
    t_end, first, killed_at, hogs = time.time() + timeout, None, None, []
    try:
        while serve.poll() is None and time.time() < t_end:
            if load[0] and not hogs and any("waiting for the tracker" in ln for ln in err_lines):
                hogs = [subprocess.Popen([sys.executable, "-c", HOG, str(load[1])])
                        for _ in range(load[0])]
            rec.poll()
            if first is None and rec.samples["/PSM1/servo_jp"]:
                first = time.time()
            if kill_after is not None and first and time.time() - first > kill_after:
                serve.kill()
                killed_at = time.time()
                break
            if stop_on_hold and any(b"hold:" in raw
                                    for _, raw in rec.samples["/surestep/status"]):
                time.sleep(0.3)
                serve.send_signal(signal.SIGTERM)
                break
            time.sleep(0.005)
        # serve's stdout and stderr are its servo process's too: they end when both have
        out = serve.stdout.read()
        reader.join(60)
        serve.wait(60)
        err = "".join(err_lines)
        ended_ms = None if killed_at is None else (time.time() - killed_at) * 1e3
        time.sleep(0.3)
        rec.poll()
    finally:  # (interrupted: neither left running)
        for h in hogs:
            h.kill()
            h.wait()
        for p in (serve, sim):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        sim_out, sim_err = sim.communicate(timeout=30)
        del os.environ["CYCLONEDDS_URI"]
    log = json.loads((tmp / "log.json").read_text()) if (tmp / "log.json").exists() else None
    return {"code": serve.returncode, "out": out, "err": err, "sim_err": sim_err, "log": log,
            "servo_ended_ms": ended_ms,
            "servo": rec.decoded("/PSM1/servo_jp", "sensor_msgs/msg/JointState"),
            "jaw": rec.decoded("/PSM1/jaw/servo_jp", "sensor_msgs/msg/JointState"),
            "measured": rec.decoded("/PSM1/measured_js", "sensor_msgs/msg/JointState")}


def _stamp(msg) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def first_off_curve(r, tol=np.array([0.05, 0.05, 0.005, 0.05, 0.05, 0.05]), window=0.1):
    """[wall s] the first measured_js farther than the tolerance from every set-point stamped in
    the window before it (the node's criterion, from the recorded messages), or None."""
    ts = np.array([_stamp(m) for _, m in r["servo"]])
    qs = np.array([m.position for _, m in r["servo"]])
    for _, m in r["measured"]:
        t = _stamp(m)
        near = (ts <= t) & (ts >= t - window)
        if near.any() and np.min(np.max(np.abs(qs[near] - m.position) / tol, axis=1)) > 1:
            return t
    return None


def beyond_limits(servo, jaw, lim, lower, upper, hold_gap: float = 0.1) -> int:
    """Set-points beyond a bound, or whose divided differences exceed a velocity or acceleration
    limit (to 1e-6 relative; 1e-3 for the second ones, the stamps' nanosecond rounding); each
    stretch between fault holds (stamps more than `hold_gap` s apart) alone."""
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in servo])
    cut = np.flatnonzero(np.diff(t) > hold_gap)
    if len(cut):
        bounds = np.r_[0, cut + 1, len(t)]
        return sum(beyond_limits(servo[a:b], jaw[a:b], lim, lower, upper, np.inf)
                   for a, b in zip(bounds[:-1], bounds[1:]))
    if len(t) < 3:
        return 0
    q = np.array([np.r_[s.position, j.position] for (_, s), (_, j) in zip(servo, jaw)])
    bad = np.any((q < lower - 1e-6) | (q > upper + 1e-6), axis=1).sum()
    v = np.diff(q, axis=0) / np.diff(t)[:, None]
    bad += np.any(np.abs(v) > lim.velocity * (1 + 1e-6) + 1e-9, axis=1).sum()
    a = 2 * np.diff(v, axis=0) / (t[2:] - t[:-2])[:, None]
    bad += np.any(np.abs(a) > lim.acceleration * (1 + 1e-3) + 1e-6, axis=1).sum()
    return int(bad)


def stages(log) -> dict:
    """[ms] each played re-plan's stages (module docstring), lists."""
    dt = log["dt"]
    out = {"arrival_to_start": [], "replan": [], "handover": [], "slack": [], "tick": [],
           "image_to_arrival": []}
    for g in log["replans"]:
        if not g["ok"] or g.get("received") is None or g.get("first_command") is None:
            continue
        out["arrival_to_start"].append((g["start"] - g["arrival"]) * 1e3)
        out["replan"].append((g["ready"] - g["start"]) * 1e3)
        out["handover"].append((g["received"] - g["ready"]) * 1e3)
        out["slack"].append((g["step"] * dt - g["received"]) * 1e3)
        out["tick"].append((g["first_command"] - g["step"] * dt) * 1e3)
        if g.get("image") is not None:
            out["image_to_arrival"].append((g["arrival"] - g["image"]) * 1e3)
    return out


def episode_row(r, lim, lower, upper, hz: float) -> dict:
    log = r["log"]
    kept = [g for g in log["replans"] if g["ok"]]
    sent = np.array(log["sent_at"])
    gaps = np.diff(sent)
    t = np.array([_stamp(m) for _, m in r["servo"]])
    return {"reached": r["code"] == 0 and r["out"].startswith("serve: goal reached"),
            "beyond": beyond_limits(r["servo"], r["jaw"], lim, lower, upper),
            "rate_stamps": (len(t) - 1) / (t[-1] - t[0]),
            "rate_sent": (len(sent) - 1) / (sent[-1] - sent[0]),
            "gaps_over_2": int(np.sum(gaps > 2 / hz)), "longest_gap_ms": float(gaps.max() * 1e3),
            "gaps_in_replan": gaps_in_replan(sent, log["replans"], 2 / hz),
            "busy": sum(g["ready"] - g["arrival"] for g in log["replans"]) / (sent[-1] - sent[0]),
            "ready_ms": [(g["ready"] - g["arrival"]) * 1e3 for g in kept],
            "first_ms": [(g["first_command"] - g["arrival"]) * 1e3 for g in kept
                         if g["first_command"] is not None],
            "replan_ms": [g["replan_s"] * 1e3 for g in log["replans"]],
            "not_played": len(log["replans"]) - len(kept), "replans": len(log["replans"]),
            "budget_ms": log["budget"] * 1e3, "stages": stages(log),
            "servo_exit": log["servo"]["exit"]}


def gaps_in_replan(sent, replans, longer) -> int:
    """Gaps longer than `longer` s between set-points sent that overlap a re-plan's run (its
    estimate's arrival to its ready time): the re-planning thread holding the interpreter."""
    runs = [(g["arrival"], g["ready"]) for g in replans if g.get("epoch", 0) == 0]
    n = 0
    for a, b in zip(sent[:-1], sent[1:]):
        if b - a > longer and any(lo < b and hi > a for lo, hi in runs):
            n += 1
    return n


def fault_off(r) -> float | None:
    """[wall s] when sim-robot ended the injected fault, or None."""
    said = [ln for ln in r["sim_err"].splitlines() if " off at " in ln and "fault" in ln]
    return float(said[0].split("(wall ")[1].rstrip(")")) if said else None


def fault_row(kind: str, r, lim=None, lower=None, upper=None) -> dict:
    log = r["log"] or {}
    hold, at = log.get("hold"), log.get("hold_at")
    if kind == "tracker-silent" and at is not None:
        delay = at - (log["last_estimate"] + 0.3)
    elif kind == "nan" and at is not None and log.get("fault_seen") is not None:
        delay = at - log["fault_seen"]
    elif kind == "stuck" and at is not None and first_off_curve(r) is not None:
        delay = log["t0_wall"] + at - first_off_curve(r)  # from the arm's error passing tolerance
    else:
        delay = None
    if kind == "killed":
        said = [ln for ln in r["sim_err"].splitlines() if "servo_jp silent" in ln]
        return {"kind": kind, "hold": said[0].split("sim-robot: ")[1] if said else None,
                "delay_ms": None, "code": r["code"], "resume_ms": None, "cleared_ms": None,
                "restart_ms": None, "reached": False, "beyond": None,
                "servo_ended_ms": r["servo_ended_ms"]}
    row = {"kind": kind, "hold": hold, "delay_ms": None if delay is None else delay * 1e3,
           "code": r["code"], "resume_ms": None, "cleared_ms": None, "restart_ms": None,
           "reached": r["code"] == 0 and r["out"].startswith("serve: goal reached"),
           "beyond": None if lim is None else beyond_limits(r["servo"], r["jaw"], lim, lower,
                                                            upper)}
    h = (log.get("holds") or [None])[0]
    off = fault_off(r)
    if h and h.get("first_command") is not None and off is not None:
        row["resume_ms"] = (log["t0_wall"] + h["first_command"] - off) * 1e3
        row["cleared_ms"] = (log["t0_wall"] + h["cleared"] - off) * 1e3
        row["restart_ms"] = h["restart_s"] * 1e3
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--faults", action="store_true")
    ap.add_argument("--budget", default="auto")
    ap.add_argument("--load", type=int, default=0, help="busy processes for the whole run")
    ap.add_argument("--load-duty", type=float, default=1.0,
                    help="each busy process's share of every 20 ms it spins (default 1: always)")
    ap.add_argument("--servo-priority", type=int, default=0,
                    help="serve --servo-priority (SCHED_FIFO for the servo process; 0: off)")
    ap.add_argument("--servo-hz", type=float, default=200.0)
    ap.add_argument("--output")
    args = ap.parse_args()
    from surestep_ocp.model.limits import joint_bounds, problem_limits
    from surestep_ocp.problem.load import load_problem
    from surestep_ocp.problem.setup import build_setup

    setup = build_setup(load_problem(PROBLEM))
    lim = problem_limits(setup)
    lower, upper = joint_bounds(setup.robot, lim.rcm_min_distance)
    base = 100 + os.getpid() % 50
    serve_args = ["--replan-budget", str(args.budget), "--servo-hz", str(args.servo_hz),
                  "--servo-priority", str(args.servo_priority)]
    rows, faults = [], []
    args.loadavg_start = os.getloadavg()
    args.affinity = sorted(os.sched_getaffinity(0))
    _runs(args, base, serve_args, rows, faults, lim, lower, upper)
    args.loadavg_end = os.getloadavg()
    report(rows, faults, args)


def _runs(args, base, serve_args, rows, faults, lim, lower, upper) -> None:
    for i in range(args.episodes):
        with tempfile.TemporaryDirectory() as tmp:
            r = run(Path(tmp), base + i % 50, serve_args, ["--seed", str(i)],
                    load=(args.load, args.load_duty))
        rows.append(episode_row(r, lim, lower, upper, args.servo_hz))
        e = rows[-1]
        print(f"episode {i}: reached {e['reached']}, beyond {e['beyond']}, rate "
              f"{e['rate_stamps']:.1f}/{e['rate_sent']:.1f} Hz, gaps>2T {e['gaps_over_2']}, "
              f"first {np.median(e['first_ms']):.1f} ms (budget {e['budget_ms']:.1f}), "
              f"not played {e['not_played']}", flush=True)
    if args.faults:
        # each fault clears after D s: hold, then resume, then the goal
        silent = ["--fault", "tracker-silent@0.6+0.5"]
        specs = [("tracker-silent", ["--estimate-timeout", "0.3"], silent, None),
                 ("nan", [], ["--fault", "nan@0.6+0.3"], None),
                 ("stuck", [], ["--fault", "stuck@0.6+1"], None), ("killed", [], [], 0.6)]
        for j, (kind, sa, sim_a, kill) in enumerate(specs):
            with tempfile.TemporaryDirectory() as tmp:
                r = run(Path(tmp), base + (args.episodes + j) % 50, serve_args + sa, sim_a, kill,
                        stop_on_hold=kill is not None, load=(args.load, args.load_duty))
            faults.append(fault_row(kind, r, lim, lower, upper))
            print(f"fault {kind}: {faults[-1]}", flush=True)


def report(rows, faults, args) -> None:
    allv = lambda k: np.concatenate([np.asarray(r[k], float) for r in rows] or [[]])  # noqa: E731
    first, ready, rp = allv("first_ms"), allv("ready_ms"), allv("replan_ms")
    first = first if len(first) else np.array([np.nan])
    ready = ready if len(ready) else np.array([np.nan])
    rs = np.array([r["rate_stamps"] for r in rows] or [np.nan])
    rsent = np.array([r["rate_sent"] for r in rows] or [np.nan])
    summary = {
        "episodes": len(rows), "reached": sum(r["reached"] for r in rows),
        "beyond_limits": sum(r["beyond"] for r in rows),
        "rate_min_hz": round(float(min(rs.min(), rsent.min())), 1),
        "rate_err_pct_max": round(float(np.abs(np.r_[rs, rsent] / args.servo_hz - 1).max() * 100),
                                  2),
        "gaps_over_2_periods": sum(r["gaps_over_2"] for r in rows),
        "gaps_during_a_replan": sum(r["gaps_in_replan"] for r in rows),
        "replan_time_share_pct": (round(100 * float(np.mean([r["busy"] for r in rows])), 1)
                                  if rows else None),
        "longest_gap_ms": round(max([r["longest_gap_ms"] for r in rows] or [np.nan]), 1),
        "first_cmd_median_ms": round(float(np.median(first)), 1),
        "first_cmd_worst_ms": round(float(first.max()), 1),
        "ready_median_ms": round(float(np.median(ready)), 1),
        "ready_worst_ms": round(float(ready.max()), 1),
        "replan_median_ms": round(float(np.median(rp)), 1) if len(rp) else None,
        "first_cmd_p90_ms": round(float(np.percentile(first, 90)), 1),
        # played from a waypoint a step later than its frame's (the lead rule, or a late frame)
        "first_cmd_over_25ms": int(np.sum(first > 25.0)),
        "replans": sum(r["replans"] for r in rows),
        "not_played": sum(r["not_played"] for r in rows), "budget": args.budget,
        "budget_ms_median": round(float(np.median([r["budget_ms"] for r in rows])), 1)
        if rows else None,
        "budget_ms_range": (f"{min(r['budget_ms'] for r in rows):.1f}-"
                            f"{max(r['budget_ms'] for r in rows):.1f}") if rows else None,
        "servo_exit_nonzero": sum(r["servo_exit"] != 0 for r in rows), "load": args.load,
        "servo_priority": args.servo_priority, "load_duty": args.load_duty,
        "cpus": ",".join(map(str, args.affinity)),
        "loadavg_1min_start_end": f"{args.loadavg_start[0]:.2f}/{args.loadavg_end[0]:.2f}"}
    for k in ("image_to_arrival", "arrival_to_start", "replan", "handover", "slack", "tick"):
        a = np.concatenate([np.asarray(r["stages"][k], float) for r in rows] or [[]])
        summary[f"{k}_ms_median"] = round(float(np.median(a)), 2) if len(a) else None
        summary[f"{k}_ms_p90"] = round(float(np.percentile(a, 90)), 2) if len(a) else None
    lines = [f"# serve loop over loopback DDS\n\n`OPENBLAS_NUM_THREADS=1 .venv/bin/python "
             f"benchmarks/serve_loop.py --episodes {args.episodes}"
             f"{' --faults' if args.faults else ''} --budget {args.budget}"
             f"{f' --load {args.load}' if args.load else ''}"
             f"{f' --load-duty {args.load_duty:g}' if args.load and args.load_duty < 1 else ''}"
             f"{f' --servo-priority {args.servo_priority}' if args.servo_priority else ''}`\n",
             "| key | value |", "|---|---|"] + [f"| {k} | {v} |" for k, v in summary.items()]
    if faults:
        def ms(x):
            return "-" if x is None else round(x, 1)

        lines += ["", "| fault | hold (reason) | hold delay [ms] | cleared [ms] | restart [ms] | "
                  "resumed [ms] | goal reached | beyond a limit | exit |",
                  "|---|---|---|---|---|---|---|---|---|"]
        lines += [f"| {f['kind']} | {f['hold']} | {ms(f['delay_ms'])} | {ms(f['cleared_ms'])} | "
                  f"{ms(f['restart_ms'])} | {ms(f['resume_ms'])} | {f['reached']} | "
                  f"{'-' if f['beyond'] is None else f['beyond']} | {f['code']} |"
                  for f in faults]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.output:
        Path(args.output).write_text(text)
    fault_part = " ".join(
        f"{f['kind']}_ms={'-' if f['delay_ms'] is None else round(f['delay_ms'], 1)}"
        f"/resume_ms={'-' if f['resume_ms'] is None else round(f['resume_ms'], 1)}"
        for f in faults)
    print("serve-loop: " + " ".join(f"{k}={v}" for k, v in summary.items())
          + (" " + fault_part if fault_part else ""))


if __name__ == "__main__":
    main()
