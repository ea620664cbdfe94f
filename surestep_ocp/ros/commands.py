"""`surestep serve` and `surestep sim-robot`: their parsers and checks (no DDS imported here: the
checks run, and bad input exits 2, before cyclonedds is loaded or anything is published)."""

from __future__ import annotations

import importlib.util
import math
import sys

from ..errors import SurestepError
from ..output.joint_names import PSM_ARM, joint_naming
from .faults import FaultLimits
from .names import (DEFAULT_ARM, DEFAULT_NAMESPACE, TRACKER_TOPIC, check_arm, check_topic,
                    domain_id)
from .sim_faults import parse_faults

MAX_SERVO_HZ = 2000.0


def _positive(value: float, option: str, hi: float = math.inf) -> float:
    if not (math.isfinite(value) and 0 < value <= hi):
        raise SurestepError(f"{option}: {value:g} must be a positive number"
                            + (f" up to {hi:g}" if math.isfinite(hi) else ""))
    return value


def _common(p) -> None:
    p.add_argument("problem", help="problem YAML (problems/README.md) within enforced limits, "
                                   "e.g. problems/needle_regrasp.yaml")
    p.add_argument("--arm", default=DEFAULT_ARM, help="the dVRK arm (PSM1, PSM2, PSM3; "
                                                      "default PSM1)")
    p.add_argument("--tracker-topic", help="the tracker's geometry_msgs/PoseWithCovarianceStamped "
                                           "in the camera frame (default /ARM/tracker/pose)")
    p.add_argument("--domain-id", help="DDS domain (default: ROS_DOMAIN_ID, else 0); the "
                                       "transport is CYCLONEDDS_URI's")


def register(sub) -> None:
    s = sub.add_parser("serve", help="a ROS 2 node (DDS, no ROS install needed) that re-plans at "
                                     "the tracker's rate and streams servo_jp (docs/serve.md)")
    _common(s)
    s.add_argument("--servo-hz", type=float, default=200.0, help="servo_jp rate (default 200)")
    s.add_argument("--servo-priority", type=int, default=0, metavar="N",
                   help="run the servo process (the servo_jp stream) under the real-time "
                        "scheduler, SCHED_FIFO priority N in 1..99 (Linux; needs CAP_SYS_NICE or "
                        "an rtprio limit, else said and run as usual); 0: the normal scheduler "
                        "(default)")
    s.add_argument("--namespace", default=DEFAULT_NAMESPACE,
                   help="the node's own topics: plan, trace, planned_trace, confidence, status "
                        "(default /surestep)")
    s.add_argument("--continuous", action="store_true",
                   help="keep serving once the goal is reached: hold it, and plan to each new "
                        "goal (geometry_msgs/PoseStamped, camera frame) on NAMESPACE/goal, "
                        "until stopped")
    s.add_argument("--start", choices=("measured", "problem"), default="measured",
                   help="plan from the arm's measured joints or require the arm at the "
                        "problem's start (default measured)")
    s.add_argument("--estimate-timeout", type=float, default=0.5,
                   help="[s] hold when the tracker (or measured_js) is silent this long "
                        "(default 0.5)")
    s.add_argument("--tolerance", type=float, default=0.05,
                   help="[rad] hold when a measured joint leaves the commanded curve by more "
                        "(default 0.05)")
    s.add_argument("--insertion-tolerance", type=float, default=0.005, help="[m] the same for "
                                                                            "the insertion "
                                                                            "(default 0.005)")
    s.add_argument("--max-replan-failures", type=int, default=5,
                   help="hold after this many re-plans in a row not played (default 5)")
    s.add_argument("--replan-budget", default="auto",
                   help="[s] each waypoint this long after a tracker frame's arrival (the "
                        "waypoints are phase-locked to the frames): a re-plan's time to be played "
                        "at once; auto: the re-plans' time measured on the tracker's first "
                        "frames, before the motion starts (default: auto, docs/serve.md)")
    s.add_argument("--replan-margin", type=float, default=0.002,
                   help="[s] a re-plan starts at the first waypoint at least this long after the "
                        "estimate's arrival (default 0.002)")
    s.add_argument("--no-resume", action="store_true",
                   help="a fault hold lasts until the node is stopped (default: resume once its "
                        "cause has cleared, docs/serve.md)")
    s.add_argument("--resume-after", type=float, default=0.3,
                   help="[s] resume after a fault hold once the estimates are finite and the arm "
                        "at rest at the held set-point this long (default 0.3)")
    s.add_argument("--hold", type=float, default=0.5,
                   help="[s] the goal held this long ends the run (default 0.5)")
    s.add_argument("--wait", type=float, default=30.0,
                   help="[s] wait this long for the arm's measured_js (default 30)")
    s.add_argument("--joint-names", help="dvrk (default), dvrk-ros-model, or 6 names")
    s.add_argument("--log", help="a JSON file of every re-plan's timing and the set-points' times")
    s.set_defaults(func=cmd_serve)
    r = sub.add_parser("sim-robot", help="a simulated PSM (measured_js follows servo_jp within the "
                                         "limits) and tracker, over ROS 2 topics on DDS")
    _common(r)
    r.add_argument("--rate", type=float, default=200.0, help="measured_js rate (default 200)")
    r.add_argument("--seed", type=int, default=0, help="the tracker's noise seed (default 0)")
    r.add_argument("--tracker-latency", type=float, default=0.0,
                   help="[s] each estimate published this long after its image (default 0)")
    r.add_argument("--duration", type=float, default=0.0,
                   help="[s] end after this long (default 0: until stopped)")
    r.add_argument("--fault", action="append", metavar="KIND@T[+D]",
                   help="inject a fault at T s after the first servo_jp, for D s (default: to the "
                        "end): tracker-silent, nan, stuck (repeatable)")
    r.add_argument("--meshcat", nargs="?", type=float, const=10.0, default=None, metavar="HZ",
                   help="a Meshcat view (a server on 127.0.0.1; its URL on stderr) of the arm and "
                        "the tracker's belief, updated HZ times a second (default 10)")
    r.set_defaults(func=cmd_sim_robot)


def _names(args) -> tuple[str, str, int]:
    arm = check_arm(args.arm)
    tracker = check_topic(args.tracker_topic or TRACKER_TOPIC.format(arm=arm), "--tracker-topic")
    return arm, tracker, domain_id(args.domain_id)


NO_DDS = "surestep serve / sim-robot need Cyclone DDS: pip install 'surestep_ocp[ros]'"


def _need_dds() -> None:
    if importlib.util.find_spec("cyclonedds") is None:
        raise SurestepError(NO_DDS)


def _served_problem(path: str):
    """The problem and its setup, if the node can re-plan it (ros/served_problem.py: the problem
    and the solvers loaded only once the options are checked)."""
    from .served_problem import served_problem

    return served_problem(path)


def _budget(text: str) -> float | None:
    """--replan-budget: seconds, or None for auto."""
    if str(text).strip().lower() == "auto":
        return None
    try:
        value = float(text)
    except ValueError:
        raise SurestepError(f"--replan-budget: {text!r} must be auto or a number of seconds "
                            "(e.g. 0.015)") from None
    return _positive(value, "--replan-budget", 1.0)


def cmd_serve(args) -> int:
    arm, tracker, domain = _names(args)
    namespace = check_topic(args.namespace, "--namespace")
    _positive(args.servo_hz, "--servo-hz", MAX_SERVO_HZ)
    for v, o in ((args.estimate_timeout, "--estimate-timeout"), (args.tolerance, "--tolerance"),
                 (args.insertion_tolerance, "--insertion-tolerance"),
                 (args.replan_margin, "--replan-margin"), (args.hold, "--hold"),
                 (args.resume_after, "--resume-after"),
                 (args.wait, "--wait")):
        _positive(v, o)
    if not 0 <= args.servo_priority <= 99:
        raise SurestepError(f"--servo-priority: {args.servo_priority} must be 0 (the normal "
                            "scheduler) or a SCHED_FIFO priority in 1..99")
    if args.max_replan_failures < 1:
        raise SurestepError(f"--max-replan-failures: {args.max_replan_failures} must be at "
                            "least 1")
    budget = _budget(args.replan_budget)
    naming = joint_naming(args.joint_names, list(PSM_ARM), ["jaw"])
    prob, _ = _served_problem(args.problem)
    _need_dds()
    from .serve import Serve, ServeOptions  # cyclonedds: loaded once everything is checked

    faults = FaultLimits(args.estimate_timeout, args.tolerance, args.insertion_tolerance, 0.1,
                         args.max_replan_failures)
    opts = ServeOptions(args.problem, arm, tracker, namespace, args.servo_hz, domain,
                        args.continuous, args.start, args.wait, args.hold, args.replan_margin,
                        budget, args.joint_names, faults, args.log,
                        not args.no_resume, args.resume_after, args.servo_priority)
    code = Serve(opts, prob, naming).run()
    sys.stdout.flush()
    return code


def cmd_sim_robot(args) -> int:
    arm, tracker, domain = _names(args)
    _positive(args.rate, "--rate", MAX_SERVO_HZ)
    if args.meshcat is not None:
        _positive(args.meshcat, "--meshcat", 60.0)
        if importlib.util.find_spec("meshcat") is None:
            raise SurestepError("--meshcat: the view needs meshcat (pip install meshcat)")
    if not (math.isfinite(args.tracker_latency) and 0 <= args.tracker_latency < 1):
        raise SurestepError(f"--tracker-latency: {args.tracker_latency:g} must be in [0, 1) s")
    if not (math.isfinite(args.duration) and args.duration >= 0):
        raise SurestepError(f"--duration: {args.duration:g} must be a finite number of seconds "
                            ">= 0 (0: until stopped)")
    if not 0 <= args.seed < 2**63:
        raise SurestepError(f"--seed: {args.seed} must be a whole number in [0, 2^63)")
    faults = parse_faults(args.fault or [])
    prob, setup = _served_problem(args.problem)
    _need_dds()
    from .sim_robot import SimRobot

    ecm = getattr(prob.camera, "ecm_joints", None)
    return SimRobot(setup, ecm, arm, tracker, domain, args.rate, args.seed, args.tracker_latency,
                    args.duration, faults, args.meshcat or 0.0).run()
