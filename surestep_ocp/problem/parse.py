"""A problem's YAML tree -> the fields of its `Problem` (`problem_fields`; `spec.parse_problem`
builds the Problem of them): each top-level section read by its reader (`parse_scene.py`,
`parse_settings.py`), validating strictly, and every error of the file collected.

Every error is a one-line `ProblemError` naming the file, the key path and what is allowed
(`schema.Reader`); the caps on the values a problem may hold are `caps.py`'s (problems/README.md,
"Limits"), importable from here too.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from ..errors import ProblemError, ProblemErrors
from ..model.belief import BeliefModel
from .caps import (  # noqa: F401 (the caps' home before)
    MAX_ANGLE,
    MAX_FOCAL,
    MAX_FRAMES_PER_STEP,
    MAX_HORIZON,
    MAX_IMAGE,
    MAX_POSITION,
)
from .parse_errors import more_errors
from .parse_scene import _camera, _endpoint, _grasp, _robot
from .parse_settings import _gradient, _limits, _noise, _objective, _solver, _timing, read_detection
from .schema import Reader
from .sections import TimingSpec
from .solver_config import resolve

_TOP = {"name", "description", "robot", "camera", "start", "goal", "horizon", "noise",
        "constraints", "objective", "solver", "gradient", "timing", "limits", "detection"}
_REQUIRED_TOP = {"robot", "camera", "start", "goal", "horizon"}


def problem_fields(tree: Any, path: Path) -> dict:
    """`tree` (a problem file's YAML) read into the fields of a Problem. Each top-level section is
    read even when another has an error, so every error of a file is reported at once: one error is
    a ProblemError, several a `ProblemErrors` (one line each; a section is read again without each
    bad key until it reads, so all its errors are found; `limits`, which needs the robot's joints,
    is read only when the robot is right)."""
    rd = Reader(str(path))
    errors: list[ProblemError] = []
    top = _top(rd, tree, errors)
    section = _section_reader(top, errors)
    fields = _scene_sections(rd, top, path, section, errors)
    fields.update(_model_sections(rd, top, path, section, fields["timing"], fields["robot"]))
    if errors:
        order = {str(k): i for i, k in enumerate(tree)}  # the file's order of its sections
        errors.sort(key=lambda e: order.get(re.split(r"[.\[]", e.key or "")[0], len(order)))
        raise errors[0] if len(errors) == 1 else ProblemErrors(errors)
    # which covariance the planners minimise: Sigma_T|T (the paper's) or Sigma_T|T-1, the one that
    # governs the executed error under closed-loop control (section 8)
    objective, covariance = fields.pop("objective")
    fields.update(noise=replace(fields["noise"], objective=covariance), objective=objective,
                  path=path, source=tree)
    # the solver choices against the noise model, when the file is read (the robot's
    # rule: build_setup)
    resolve(fields["solver"], BeliefModel(fields["noise"], fields["camera"].intrinsics), None,
            file=str(path), limited=fields["limits"].enforce)
    return fields


def _section_reader(top: dict, errors: list[ProblemError]) -> Callable:
    """`section(key, read, *args, required=False, **kwargs)`: `read(*args, **kwargs)`, or None
    with its errors (all of the section's, `parse_errors.more_errors`) added to `errors`; a
    required section that is missing is None (its error is the top level's)."""

    def section(key: str, read, *args, required: bool = False, **kwargs):
        if required and key not in top:  # (its error is the top level's)
            return None
        try:
            return read(*args, **kwargs)
        except ProblemError as exc:
            errors.append(exc)
            errors.extend(more_errors(key, top.get(key), read, args, kwargs, exc))
            return None

    return section


def _scene_sections(rd: Reader, top: dict, path: Path, section: Callable,
                    errors: list[ProblemError]) -> dict:
    """The robot, camera, start, goal, horizon, timing, detection and grasp sections read (None
    where in error), and the timing's cap against the horizon checked."""
    robot = section("robot", _robot, rd, top.get("robot"), "robot", path, default_frame="tool",
                    required=True)
    camera = section("camera", _camera, rd, top.get("camera"), path, required=True)
    start = section("start", _endpoint, rd, top.get("start"), "start", path, required=True)
    goal = section("goal", _endpoint, rd, top.get("goal"), "goal", path, required=True)
    horizon = section("horizon", rd.integer, top.get("horizon"), "horizon", minimum=1,
                      maximum=MAX_HORIZON, required=True)
    timing = section("timing", _timing, rd, top.get("timing", {}))
    detection = section("detection", read_detection, rd, top.get("detection"), enabled=False)
    grasp = section("goal", _grasp, rd, top.get("goal"), required=True)
    if timing is not None and horizon is not None and timing.max_duration is not None \
            and timing.max_duration < horizon * timing.step_s - 1e-9:
        errors.append(rd.fail("timing.max_duration", f"must be at least the problem's duration "
                              f"(horizon x timing.step_s = {horizon * timing.step_s:g} s), got "
                              f"{timing.max_duration:g}"))
    return {"robot": robot, "camera": camera, "start": start, "goal": goal, "horizon": horizon,
            "timing": timing, "detection": detection, "grasp": grasp}


def _model_sections(rd: Reader, top: dict, path: Path, section: Callable, timing, robot) -> dict:
    """The noise, constraints, objective (with the covariance it names), solver, gradient, limits,
    name and description read (None where in error)."""
    # (a wrong timing: the noise read with one frame per step, so that its own
    # errors are still found)
    noise = section("noise", _noise, rd, top.get("noise", {}),
                    frames=(timing or TimingSpec()).frames)
    cons = section("constraints", rd.mapping, top.get("constraints", {}), "constraints",
                   {"min_depth"})
    min_depth = None if cons is None else section(
        "constraints", rd.number, cons.get("min_depth", 0.03), "constraints.min_depth",
        positive=True, low=1e-4, high=10.0)
    objective = (section("objective", _objective, rd, top.get("objective", {}))
                 or (None, None))
    solver = section("solver", _solver, rd, top.get("solver", {}))
    gradient = section("gradient", _gradient, rd, top.get("gradient", {}))
    limits = None if robot is None else section("limits", _limits, rd, top.get("limits", {}), robot)
    name = section("name", rd.string, top.get("name", path.stem), "name")
    description = section("description", rd.string, top.get("description", ""), "description")
    return {"noise": noise, "min_depth": min_depth, "objective": objective, "solver": solver,
            "gradient": gradient, "limits": limits, "name": name, "description": description}


def _top(rd: Reader, tree: Any, errors: list[ProblemError]) -> dict:
    """The top-level mapping's known keys; each unknown and each missing required key an error in
    `errors` (not a mapping at all: raised, nothing else can be read)."""
    if not isinstance(tree, Mapping):
        rd.mapping(tree, "", _TOP)  # raises, naming what is expected
    unknown = sorted(set(tree) - _TOP, key=str)
    missing = sorted(_REQUIRED_TOP - set(tree))
    # a misspelt required key is one error, naming the key it stands for
    meant = {k: next(iter(difflib.get_close_matches(str(k), missing, 1)), None) for k in unknown}
    errors += [rd.fail(str(k), f"unknown key; allowed keys here: {', '.join(sorted(_TOP))}"
                       + (f"; missing here: {meant[k]}" if meant[k] else "")) for k in unknown]
    errors += [rd.fail(k, "missing required key") for k in missing if k not in meant.values()]
    return {k: v for k, v in tree.items() if k in _TOP}


