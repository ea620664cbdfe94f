"""The Python API under hypothesis-generated arguments: `Planner.replan` and `Problem.with_*` given
finite, non-finite, huge, wrong-shaped, complex or non-rigid arguments either plan (from valid input
only) or raise a `SurestepError` naming what is wrong; no other exception escapes, and a plan from
garbage never succeeds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import surestep_ocp as ss

T = 4
NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3),
                    st.complex_numbers(max_magnitude=1e3), st.integers(-10**30, 10**30))


@pytest.fixture(scope="module")
def problem():
    return ss.load_problem("problems/needle_regrasp_paper_pace.yaml").with_horizon(T)


@pytest.fixture(scope="module")
def planner(problem):
    return ss.Planner(problem)


def arrays(shape):
    return st.one_of(st.lists(NUMBERS, min_size=0, max_size=8),
                     st.builds(lambda v: np.full(shape, v,
                                                 dtype=complex if isinstance(v, complex)
                                                 else float),
                               NUMBERS),
                     st.builds(lambda s: np.eye(shape[0]) * s if len(shape) == 2
                               else np.full(shape, s), st.floats(-1e12, 1e12)))


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mean=arrays((6,)), cov=arrays((6, 6)), camera=st.one_of(st.none(), arrays((4, 4))),
       step=st.one_of(st.none(), st.integers(-3, 10), st.floats(allow_nan=True),
                      st.lists(st.integers(0, 3))))
def test_replan_plans_or_names_the_error(planner, mean, cov, camera, step):
    try:
        plan = planner.replan(mean, cov, camera_pose=camera, step=step)
    except ss.SurestepError:
        return
    # accepted: then the input was a valid estimate (finite real 6-vector, SPD 6x6, rigid camera or
    # none)
    m, c = np.asarray(mean), np.asarray(cov)
    assert (m.shape == (6,) and c.shape == (6, 6) and not np.iscomplexobj(m)
            and np.all(np.isfinite(m)))
    assert np.allclose(c, c.T) and np.linalg.eigvalsh(c.astype(float))[0] > 0
    assert plan.status  # a plan, successful or not, with its status


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pose=st.one_of(arrays((6,)), st.lists(st.lists(NUMBERS, max_size=3), max_size=3),
                      st.dictionaries(st.sampled_from(["position", "axis_angle", "x"]),
                                      arrays((3,)))),
       matrix=arrays((4, 4)))
def test_with_changes_give_a_problem_or_name_the_error(problem, pose, matrix):
    for call in (lambda: problem.with_goal(pose=pose), lambda: problem.with_start(pose=pose),
                 lambda: problem.with_camera_pose(matrix)):
        try:
            changed = call()
        except ss.SurestepError:
            continue
        assert isinstance(changed, ss.Problem)
