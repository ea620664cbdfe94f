"""Plans run at the tool's speed limits (surestep_ocp.evaluation.pacing), checked with Pinocchio's
exp3 / log3."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml

from surestep_ocp.errors import ProblemError
from surestep_ocp.evaluation import evaluation
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation
from surestep_ocp.evaluation.pacing import paced
from test_evaluation import EVAL

DT, V, W = 0.05, 0.1, np.pi / 2  # the default step and tool limits: 5 mm and 0.0785 rad per step


def _turn(a, b) -> float:
    """Geodesic angle between two axis-angle vectors (Pinocchio, not the scipy the module uses)."""
    return float(np.linalg.norm(pin.log3(pin.exp3(np.asarray(a)).T @ pin.exp3(np.asarray(b)))))


def _plan(rng, T=6):
    """A plan with some steps far over the limits (up to 60 mm, 2.5 rad) and some well within."""
    P = np.zeros((T + 1, 6))
    P[0] = [0.0, 0.0, 0.15, 0.3, -0.2, 1.0]
    for t in range(T):
        big = t % 2 == 0
        dp = rng.normal(size=3)
        dp *= (0.06 if big else 0.003) / np.linalg.norm(dp)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = pin.exp3(axis * (2.5 if big else 0.03)) @ pin.exp3(P[t, 3:])
        P[t + 1] = np.hstack([P[t, :3] + dp, pin.log3(R)])
    return P


def test_paced_plan_is_the_plan_run_no_faster_than_the_limits():
    """Every rollout step within both limits; the plan's waypoints kept, in order; each plan step
    split into the fewest equal steps (one fewer would break a limit) along the segment and the
    geodesic."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        P = _plan(rng)
        Q = paced(P, DT, V, W)
        at = [0]
        for t in range(len(P) - 1):
            move, turn = np.linalg.norm(P[t + 1, :3] - P[t, :3]), _turn(P[t, 3:], P[t + 1, 3:])
            k = max(1, int(np.ceil(max(move / (V * DT), turn / (W * DT)))))
            # k steps are within the limits
            assert max(move / k, (turn / k) * V / W) <= V * DT * (1 + 1e-9)
            if k > 1:
                # k - 1 are not
                assert max(move / (k - 1) / (V * DT), turn / (k - 1) / (W * DT)) > 1
            seg = Q[at[-1]:at[-1] + k + 1]
            np.testing.assert_allclose(np.diff(seg[:, :3], axis=0),
                                       np.tile((P[t + 1, :3] - P[t, :3]) / k, (k, 1)),
                                       atol=1e-12)  # equal steps on the segment
            # equal turns about the step's own axis: the geodesic
            for a, b in zip(seg[:-1], seg[1:]):
                assert _turn(a[3:], b[3:]) == pytest.approx(turn / k, abs=1e-9)
            at.append(at[-1] + k)
        assert at[-1] == len(Q) - 1
        np.testing.assert_array_equal(Q[at], P)  # the plan's own waypoints, bit for bit


def test_a_plan_within_the_limits_is_left_as_it_is():
    P = np.zeros((4, 6))
    P[:, 0] = [0.0, 0.005, 0.010, 0.0149]  # 5 mm per step, exactly the limit
    P[:, 5] = [0.1, 0.1 + W * DT, 0.1 + W * DT, 0.1]
    assert paced(P, DT, V, W) is P
    with pytest.raises(ValueError, match="positive"):
        paced(P, DT, 0.0, W)


def test_execution_pace_is_read_strictly_and_runs_the_rollouts_on_the_paced_plan(tmp_path):
    """`execution.pace` is `planned` by default; a bad value names the key; at `limits` a
    configuration's rollouts follow the paced plan (rollout_steps recorded, >= the horizon), at
    `planned` the plan itself."""
    assert load_evaluation(EVAL).pace == "planned"
    tree = yaml.safe_load(EVAL.read_text())
    tree["base"] = str((EVAL.parent / tree["base"]).resolve())
    path = tmp_path / "e.yaml"
    for bad, key in (({"pace": "fast"}, "execution.pace"), ({"speed": 1}, "speed")):
        path.write_text(yaml.safe_dump({**tree, "execution": bad}))
        with pytest.raises(ProblemError) as exc:
            load_evaluation(path)
        assert "e.yaml" in str(exc.value) and key in str(exc.value) and (
            "planned" in str(exc.value) or key == "speed")
    path.write_text(yaml.safe_dump({**tree, "execution": {"pace": "limits"}}))
    assert load_evaluation(path).pace == "limits"
    evaluation._SAMPLERS.clear()
    steps = {}
    for pace in ("planned", "limits"):
        p = tmp_path / f"{pace}.yaml"
        p.write_text(yaml.safe_dump({**tree, "execution": {"pace": pace}}))
        rec = evaluation.evaluate_configuration(str(p), 0, 1, ("baseline", "ocp"), 4, ("true",))
        steps[pace] = {m: rec["solves"][m]["rollout_steps"] for m in ("baseline", "ocp")}
    assert steps["planned"] == {"baseline": 20, "ocp": 20}
    spec = load_evaluation(path)
    setup = ConfigurationSampler(spec).setup_of(ConfigurationSampler(spec).sample(0, 1))
    from surestep_ocp.methods.registry import run_method

    for m in ("baseline", "ocp"):
        P = np.asarray(run_method(setup, m).poses)
        assert steps["limits"][m] == len(paced(P, DT, V, W)) - 1 >= 20
