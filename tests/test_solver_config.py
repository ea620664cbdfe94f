"""The solver choices and their rules (surestep_ocp.problem.solver_config.resolve): every rule
raises a ProblemError naming the key a user changes, and the same bad choice in a problem file is
one line from the command line.

The expected key of each rule is written here from the rule's wording (problems/README.md,
docs/method.md): the key the user set wrong, not the one the package happens to check first. The
command line runs in this process (`cli.main`, as tests/test_bad_input.py does): exit 2, a single
`surestep: ...` line naming the file and the key.
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from surestep_ocp import cli
from surestep_ocp.errors import ProblemError
from surestep_ocp.model.belief import BeliefModel
from surestep_ocp.problem.solver_config import Form, Hessian, SolverName, resolve
from surestep_ocp.solvers.backends import Context
from surestep_ocp.solvers.strategy import first_backend

CORRELATED = np.diag([1e-2, 1e-2, 1e-1, 5e-3, 5e-3, 5e-3])
CORRELATED[0, 2] = CORRELATED[2, 0] = 2e-2  # a depth noise correlating x and z: no scalar recursion
SIX = 6  # joints moving the PSM's tool frame (the goal pose then fixes the last node's joints)


def model(problem, **noise) -> BeliefModel:
    """The belief model of `problem` with its noise section changed."""
    return BeliefModel(replace(problem.noise, **noise), problem.camera.intrinsics)


def spec(problem, **solver):
    return replace(problem.solver, **solver)


# (id, solver changes, noise changes, moving joints, the key named)
RULES = [
    ("unknown solver", dict(name="snopt"), {}, SIX, "solver.name"),
    ("unknown form", dict(covariance="sparse"), {}, SIX, "solver.covariance"),
    ("predicted needs condensed (full)", dict(covariance="full"), dict(objective="predicted"), SIX,
     "objective.covariance"),
    ("predicted needs condensed (diagonal)", dict(covariance="diagonal"),
     dict(objective="predicted"), SIX, "objective.covariance"),
    ("diagonal needs a diagonal model", dict(covariance="diagonal"), dict(joint_sigma=(0.01,) * 7),
     SIX, "solver.covariance"),
    ("diagonal needs a diagonal model (full Sigma0)", dict(covariance="diagonal"),
     dict(Sigma0=np.full((6, 6), 1e-3) + 1e-2 * np.eye(6)), SIX, "solver.covariance"),
    ("surrogate needs a structured model", dict(hessian="surrogate", name="ipopt"),
     dict(observation_noise="expected"), SIX, "solver.hessian"),
    ("gauss-newton needs a structured model", dict(hessian="gauss-newton", name="ipopt"),
     dict(observation_noise="expected"), SIX, "solver.hessian"),
    ("gauss-newton needs the condensed form",
     dict(hessian="gauss-newton", name="ipopt", covariance="full"), {}, SIX, "solver.hessian"),
    ("codegen true with the exact Hessian", dict(hessian="exact", codegen=True, name="ipopt"), {},
     SIX, "solver.codegen"),
    ("joint-space noise with the lifted form", dict(covariance="full", name="ipopt"),
     dict(joint_sigma=(0.01,) * 7), SIX, "noise.joint_motion_sigma"),
    ("newton with a redundant arm", dict(name="newton"), {}, 7, "solver.name"),
    ("newton with five moving joints", dict(name="newton"), {}, 5, "solver.name"),
    ("newton with the exact Hessian", dict(name="newton", hessian="exact"), {}, SIX, "solver.name"),
    ("newton with a forced surrogate", dict(name="newton", hessian="surrogate"), {}, SIX,
     "solver.name"),
    ("newton with the expected noise", dict(name="newton"), dict(observation_noise="expected"), SIX,
     "solver.name"),
]


@pytest.mark.parametrize("solver, noise, joints, key", [r[1:] for r in RULES],
                         ids=[r[0] for r in RULES])
def test_every_rule_raises_a_problem_error_naming_the_key(default_problem, solver, noise, joints,
                                                          key):
    with pytest.raises(ProblemError) as exc:
        resolve(spec(default_problem, **solver), model(default_problem, **noise), joints,
                file="p.yaml")
    assert exc.value.key == key, str(exc.value)
    assert key in str(exc.value) and "p.yaml" in str(exc.value)


def test_a_redundant_arm_is_checked_only_once_the_robot_is_known(default_problem):
    """Reading a file (no robot yet: `moving_joints` None) accepts `newton`; the robot's rule comes
    at set-up."""
    r = resolve(spec(default_problem, name="newton"), model(default_problem), None)
    assert r.name is SolverName.NEWTON and r.newton_fits


@pytest.mark.parametrize("solver, noise, joints, expected", [
    # the paper's constants: condensed, the surrogate Hessian, Newton first
    ({}, {}, SIX, ("condensed", "surrogate", False, True, True)),
    (dict(name="ipopt"), {}, SIX, ("condensed", "surrogate", False, True, False)),
    (dict(hessian="exact"), {}, SIX, ("condensed", "exact", False, False, False)),
    (dict(hessian="gauss-newton"), {}, SIX, ("condensed", "gauss-newton", True, False, False)),
    # a redundant arm under auto: IPOPT
    ({}, {}, 7, ("condensed", "surrogate", False, False, False)),
    # the lifted form's structured Hessian for the posterior objective
    (dict(covariance="full"), {}, SIX, ("full", "surrogate", False, False, False)),
    # the expected noise: no structure, the exact Hessian; the condensed form while the recursion is
    # scalar (the paper's isotropic constants), else the full form
    ({}, dict(observation_noise="expected"), SIX, ("condensed", "exact", False, False, False)),
    ({}, dict(observation_noise="expected", V_d0=CORRELATED), SIX,
     ("full", "exact", False, False, False)),
    # mean noise: structured
    ({}, dict(V_d0=CORRELATED), SIX, ("condensed", "surrogate", False, True, True)),
    (dict(covariance="diagonal"), {}, SIX, ("diagonal", "exact", False, False, False)),
    ({}, dict(objective="predicted"), SIX, ("condensed", "surrogate", False, True, True)),
    # joint-space noise keeps the condensed form (its surrogate takes the noise from the joints)
    ({}, dict(joint_sigma=(0.01,) * 7), SIX, ("condensed", "surrogate", False, True, True)),
])
def test_accepted_choices_resolve_as_documented(default_problem, solver, noise, joints, expected):
    """What runs for accepted choices (docs/hessian_and_newton.md): form, Hessian, forced, Newton
    fits, Newton first; written here from the documented rules."""
    r = resolve(spec(default_problem, **solver), model(default_problem, **noise), joints)
    first = first_backend(Context(SimpleNamespace(ocp=SimpleNamespace(
        limits=SimpleNamespace(enforce=False))), r, "ocp", {}))
    newton_first = first is not None and first.name == "newton"
    assert (r.form, r.hessian, r.forced, r.newton_fits, newton_first) == expected
    assert r.form in {f.value for f in Form} and r.hessian in {h.value for h in Hessian}


# The same rules from a problem file, through the command line: (id, YAML edit, the key named)
FILE_RULES = [
    ("unknown solver", lambda t: t["solver"].update(name="snopt"), "solver.name"),
    ("unknown form", lambda t: t["solver"].update(covariance="sparse"), "solver.covariance"),
    ("predicted needs condensed", lambda t: (t["objective"].update(covariance="predicted"),
                                             t["solver"].update(covariance="full")),
     "objective.covariance"),
    ("diagonal needs a diagonal model", lambda t: (t["noise"].update(joint_motion_sigma=0.01),
                                                   t["solver"].update(covariance="diagonal")),
     "solver.covariance"),
    ("surrogate needs a structured model",
     lambda t: (t["noise"].update(observation_noise="expected"),
                t["solver"].update(hessian="surrogate")), "solver.hessian"),
    ("gauss-newton needs a structured model",
     lambda t: (t["noise"].update(observation_noise="expected"),
                t["solver"].update(hessian="gauss-newton")),
     "solver.hessian"),
    ("codegen true with the exact Hessian",
     lambda t: t["solver"].update(hessian="exact", codegen=True), "solver.codegen"),
    ("joint-space noise with the lifted form",
     lambda t: (t["noise"].update(joint_motion_sigma=0.01),
                t["solver"].update(covariance="full")),
     "noise.joint_motion_sigma"),
    ("newton with the exact Hessian", lambda t: t["solver"].update(name="newton", hessian="exact"),
     "solver.name"),
]


@pytest.mark.parametrize("edit, key", [r[1:] for r in FILE_RULES], ids=[r[0] for r in FILE_RULES])
@pytest.mark.parametrize("command", ["validate", "solve"])
def test_the_cli_says_which_file_and_key_in_one_line(write_problem, capsys, monkeypatch, command,
                                                     edit, key):
    """`surestep validate FILE` and `surestep solve FILE`: exit 2, one line naming the file and the
    key, no traceback, and no solve started."""
    import surestep_ocp.methods.registry as methods

    def forbidden(*args, **kwargs):
        raise AssertionError("a solve started before the bad solver choice was refused")

    monkeypatch.setattr(methods, "run_method", forbidden)
    path = write_problem(edit, name="bad_solver")
    argv = [command, str(path)] + (["--method", "ocp", "--output", str(path.with_suffix(".json"))]
                                   if command == "solve" else [])
    code = cli.main(argv)
    _, err = capsys.readouterr()
    assert code == 2, err
    lines = err.strip().splitlines()
    # `validate` lists its files, one "error FILE: KEY: ..." line each; the other commands say
    # "surestep: ..."
    assert (len(lines) == 1 and lines[0].startswith("error " if command == "validate"
                                                    else "surestep: ")), err
    assert "Traceback" not in err
    assert "bad_solver.yaml" in lines[0] and key in lines[0], lines[0]
