"""Shared fixtures: the default problem at the paper's pace and its set-up (loaded once), a writer
of modified problems.

The solver tests use `needle_regrasp_paper_pace.yaml`: the default problem with 20 steps and the
motion limits reported, not enforced (the default, `needle_regrasp.yaml`, enforces them over 40
steps: an IPOPT solve of seconds).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path

import pytest
import yaml

REPO_ROOT = Path(__file__).resolve().parents[1]
PROBLEMS_DIR = REPO_ROOT / "problems"
DEFAULT_PROBLEM = PROBLEMS_DIR / "needle_regrasp_paper_pace.yaml"  # see the module docstring


@pytest.fixture(scope="session")
def default_problem_tree() -> dict:
    """The default problem file as a plain YAML tree (copy it before changing it)."""
    return yaml.safe_load(DEFAULT_PROBLEM.read_text())


@pytest.fixture(scope="session")
def default_problem():
    """The default problem, loaded once per session (a frozen dataclass: safe to share)."""
    from surestep_ocp.problem.load import load_problem

    return load_problem(DEFAULT_PROBLEM)


@pytest.fixture(scope="session")
def default_setup(default_problem):
    """Robot, camera, start and goal of the default problem, built once per session.

    Shared: tests must not mutate it (use `dataclasses.replace` on the problem and
    `build_setup` for a variant).
    """
    from surestep_ocp.problem.setup import build_setup

    return build_setup(default_problem)


@pytest.fixture()
def write_problem(tmp_path: Path, default_problem_tree: dict) -> Callable[..., Path]:
    """Write a variant of the default problem to `tmp_path` and return its path.

    Usage: `write_problem(lambda tree: tree.update(horizon=0), name="zero_horizon")`.
    The callable receives a deep copy of the default YAML tree and edits it in place
    (its return value is ignored, so `tree.pop(...)` works).
    """

    def write(edit: Callable[[dict], object] | None = None, name: str = "variant") -> Path:
        tree = copy.deepcopy(default_problem_tree)
        if edit is not None:
            edit(tree)
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(tree, sort_keys=False))
        return path

    return write


@pytest.fixture(scope="session")
def interior_setup():
    """The default problem by the interior-point method, interpreted (no compile): the setup of
    the real-time iteration's and the re-plan certificate's tests. Shared: do not mutate."""
    import surestep_ocp as ss
    from surestep_ocp.problem.setup import build_setup

    problem = ss.load_problem("problems/needle_regrasp.yaml").with_solver(name="interior",
                                                                          codegen=False)
    return build_setup(problem)


@pytest.fixture()
def count_evaluated(monkeypatch) -> Callable[[], list[int]]:
    """`count_evaluated()`: the list of the configuration numbers `surestep evaluate` runs from
    then on, in order (a counting wrapper around `evaluation.evaluate_configuration`): what a
    resumed run does again."""
    from surestep_ocp.evaluation import evaluation

    def install() -> list[int]:
        calls: list[int] = []
        real = evaluation.evaluate_configuration

        def counting(*args):
            calls.append(args[2])
            return real(*args)

        monkeypatch.setattr(evaluation, "evaluate_configuration", counting)
        return calls

    return install
