"""The benchmarks' harness: the test set, the solve calls, the statistics, the report and the
command line that the studies in benchmarks/ share (after qpbenchmark: one harness, short studies on
top of it).

Import it first, before NumPy (`import harness as h` at the top of a study; a study run as
`python benchmarks/<study>.py` finds it beside itself): it pins BLAS and OpenMP to one thread. It is
also the one module of benchmarks/ that imports `surestep_ocp`: when the package's internals move,
fix the imports below and the wrappers under them, not the studies.

- The test set: the evaluation's configurations (`sampler`, `configurations`:
  problems/evaluations/*.yaml at a given horizon), the default problems (`DEFAULT_PROBLEM`,
  `PAPER_PACE_PROBLEM`, `load_problem`), the scenario files (`SCENARIOS`, `scenario_file`).
- The methods: `initial_guess`, `ocp`, `ocp_warm`, `gradient`, `baseline`, `method` (the CLI's
  methods by name), `newton` (the projected Newton solver), `diagonal_model`; `repeat` for repeated
  runs. Times are the solution's own `solve_time_s` (builds excluded), as the studies report them.
- The statistics: `stats` (median, p90, p95, worst, worst / median), `ratio_of_medians` (e.g.
  against the gradient variant measured in the same run), `median_ratio`, `geomean`.
- The report: `row`, `table` (markdown), `write_result` (benchmarks/results/*.md, atomically),
  `key_values` and `last_line` (the one machine-readable line a study prints last:
  `name: key=value ...`).
- The command line: `parser` (--configs, --seed, --horizons, --output, each where the study has it).

The studies: benchmarks/README.md gives each one's claim, command and result files (solve_speed,
realtime, general_models, closed_loop, grasp_ceiling, certificate, serve_loop; the evaluation and
Table I through the CLI); what the removed one-off studies found is in docs/findings.md.
"""

from __future__ import annotations

import os
import sys

# One BLAS / OpenMP thread, before NumPy is imported (the studies import this module first). Forced,
# not defaulted: every result file says it was measured so.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
if "numpy" in sys.modules:  # imported before the harness: its BLAS read the variables already
    try:
        from threadpoolctl import threadpool_limits  # not a dependency of the package

        threadpool_limits(1)
    except ImportError:
        print("harness: NumPy was imported before benchmarks/harness.py; its BLAS may use more "
              "than one thread (import the harness first)", file=sys.stderr)

import argparse  # noqa: E402
import math  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable, Iterable, Iterator, Sequence  # noqa: E402

import numpy as np  # noqa: E402

# --- every import of the package's internals (the one place to fix when they move) ----------------
from surestep_ocp.errors import ProblemError, SurestepError  # noqa: E402
from surestep_ocp.evaluation.configs import ConfigurationSampler, load_evaluation  # noqa: E402
from surestep_ocp.evaluation.evaluation import read_progress  # noqa: E402
from surestep_ocp.evaluation.rollout import MODES as ROLLOUT_MODES, rollout  # noqa: E402
from surestep_ocp.evaluation.tracker import SimulatedTracker  # noqa: E402
from surestep_ocp.evaluation.tracker_loop import tracker_loop  # noqa: E402
from surestep_ocp.evaluation.table2 import TYPES, success_table  # noqa: E402
from surestep_ocp.evaluation.table2_figure import error_figure  # noqa: E402
from surestep_ocp.evaluation.executed_motion import stitched, violations  # noqa: E402
from surestep_ocp.evaluation.closed_loop import robot_pace  # noqa: E402
from surestep_ocp.evaluation.sure_grasp import METHODS as SURE_METHODS, scenario_rows  # noqa: E402
from surestep_ocp.evaluation.grasp_rule import GraspRule  # noqa: E402
from surestep_ocp.model.detection import Detection  # noqa: E402
from surestep_ocp.model.grasp import nees, within  # noqa: E402
from surestep_ocp.evaluation.configs import GRASP_ANGLE_RAD, GRASP_POSITION_M  # noqa: E402
from surestep_ocp.model import limits as _limits  # noqa: E402
from surestep_ocp.model.belief import unvech, vech  # noqa: E402
from surestep_ocp.model.lie import np_exp, np_means  # noqa: E402
from surestep_ocp.model.limits import motion_limits, plan_report, problem_limits  # noqa: E402
from surestep_ocp.output.export import time_parametrise, within_position_limits  # noqa: E402
from surestep_ocp.output.plots_motion import tool_speeds  # noqa: E402
from surestep_ocp.output.solution import write_text_atomic  # noqa: E402
from surestep_ocp.problem.load import load_problem  # noqa: E402
from surestep_ocp.problem.spec import LimitsSpec, TimingSpec  # noqa: E402
from surestep_ocp.problem.setup import build_setup  # noqa: E402
from surestep_ocp.solvers import nlp_cache as _nlp_cache  # noqa: E402
from surestep_ocp.methods.baseline import _timed, solve_baseline, time_optimal_law  # noqa: E402
from surestep_ocp.methods.gradient import solve_gradient  # noqa: E402
from surestep_ocp.methods.registry import method_setup, ocp_initial_guess, run_method  # noqa: E402,F401
from surestep_ocp.ocp.certificate import certify  # noqa: E402,F401 (benchmarks/certificate.py)
from surestep_ocp.ocp.iterate import InitialGuess  # noqa: E402
from surestep_ocp.solvers.nlp_cache import cached_transcriptions, newton_solver  # noqa: E402
from surestep_ocp.methods.ocp import _objective_at, diagonal_model_setup, solve_ocp, solve_ocp_warm  # noqa: E402
from surestep_ocp.methods.planner import Planner  # noqa: E402

__all__ = [
    "ROOT", "RESULTS", "PROBLEMS", "EVALUATION", "DEFAULT_PROBLEM", "PAPER_PACE_PROBLEM",
    "SCENARIOS", "scenario_file", "evaluation", "sampler", "config_problem", "configurations",
    "config_setup", "load_problem", "setup",
    "limits_spec", "timing_spec", "with_solver", "initial_guess", "guess", "ocp", "ocp_warm",
    "gradient", "baseline", "method", "newton", "diagonal_model", "objective_at", "transcriptions",
    "clear_solver_cache", "set_curve_rows",
    "repeat", "timed", "Stats", "stats", "median", "percentile", "ratio_of_medians", "median_ratio",
    "geomean", "row", "table", "write_result", "key_values", "last_line", "parser",
    # package names the studies use as they are (classes, constants, helpers of the limits, export
    # and evaluation)
    "ProblemError", "SurestepError", "Planner", "SimulatedTracker", "tracker_loop", "ROLLOUT_MODES",
    "rollout",
    "read_progress", "motion_limits", "plan_report", "problem_limits", "time_parametrise",
    "within_position_limits", "tool_speeds",
    "np_exp", "write_text_atomic", "time_optimal_law", "played_line",
    "TYPES", "success_table", "error_figure", "stitched", "violations", "robot_pace",
    "GRASP_POSITION_M", "GRASP_ANGLE_RAD", "vech", "unvech", "np_means", "SURE_METHODS",
    "scenario_rows", "GraspRule", "Detection", "nees", "within",
]

# --- the test set ---------------------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
PROBLEMS = ROOT / "problems"
EVALUATION = PROBLEMS / "evaluations" / "evaluation.yaml"
DEFAULT_PROBLEM = PROBLEMS / "needle_regrasp.yaml"
PAPER_PACE_PROBLEM = PROBLEMS / "needle_regrasp_paper_pace.yaml"
SCENARIOS = ["needle_regrasp", "needle_regrasp_paper_pace", "type1_easy", "type1_medium",
             "type1_hard", "type2_needle_arm_moves", "type3_camera_moves_once",
             "type4_camera_moves", "ur5_fixed_camera"]


def scenario_file(name: str) -> Path:
    """problems/<name>.yaml."""
    return PROBLEMS / f"{name}.yaml"


def evaluation(path: str | Path = EVALUATION):
    """The evaluation spec of problems/evaluations/*.yaml."""
    return load_evaluation(path)


def sampler(spec_or_path: Any = EVALUATION) -> ConfigurationSampler:
    """The configurations of an evaluation (a spec, or its file)."""
    spec = evaluation(spec_or_path) if isinstance(spec_or_path, (str, Path)) else spec_or_path
    return ConfigurationSampler(spec)


def config_problem(smp: ConfigurationSampler, seed: int, index: int, horizon: int | None = None):
    """Configuration `index` of `seed` as a problem, at `horizon` steps if given."""
    p = smp.problem(smp.sample(seed, index))
    return replace(p, horizon=horizon) if horizon else p


def configurations(smp: ConfigurationSampler, n: int, seed: int = 0,
                   horizon: int | None = None) -> Iterator[tuple[int, Any]]:
    """(index, problem) of the first `n` configurations."""
    for c in range(n):
        yield c, config_problem(smp, seed, c, horizon)


def config_setup(smp: ConfigurationSampler, seed: int, index: int):
    """Configuration `index` of `seed` as a setup, as `surestep evaluate` builds it (the sampler's
    robots)."""
    return smp.setup_of(smp.sample(seed, index))


def setup(problem):
    """The problem's setup (robot, camera, models)."""
    return build_setup(problem)


def limits_spec(enforce: bool = True) -> LimitsSpec:
    """The default limits, enforced or not."""
    return LimitsSpec(enforce=enforce)


def timing_spec(step_s: float, tracker_hz: float | None = None) -> TimingSpec:
    """`step_s` per step; `tracker_hz` default 1 / step_s (one observation per waypoint)."""
    return TimingSpec(step_s=step_s, tracker_hz=1.0 / step_s if tracker_hz is None else tracker_hz)


def with_solver(obj, **changes):
    """A problem, or a setup, with its `solver` settings changed."""
    if hasattr(obj, "solver"):
        return replace(obj, solver=replace(obj.solver, **changes))
    return obj.with_ocp(solver=replace(obj.ocp.solver, **changes))


# --- the methods ----------------------------------------------------------------------------------
def initial_guess(setup):
    """The OCP's initial guess (the straight line's IK)."""
    return ocp_initial_guess(setup)


def guess(q, label: str):
    """An initial guess from joints `q`."""
    return InitialGuess(np.array(q), label)


def ocp(setup, init=None):
    """The OCP, the default strategy (`solve_ocp`), from `init` (default: `initial_guess`)."""
    return solve_ocp(setup, initial_guess(setup) if init is None else init)


def ocp_warm(setup, init, warm=None):
    """The OCP and its warm-start point (`solve_ocp_warm`); `warm` None: cold."""
    return solve_ocp_warm(setup, init, warm=warm)


def gradient(setup, **kwargs):
    """The paper's gradient variant (L-BFGS)."""
    return solve_gradient(setup, **kwargs)


def baseline(setup):
    """The straight-line baseline."""
    return solve_baseline(setup)


def played_line(setup, steps: int, law) -> dict | None:
    """The straight line in `steps` steps at the time law `law` (steps -> fractions of the way): its
    played curve's peak ratios to the problem's limits (None: a waypoint unreachable)."""
    return _timed(setup, problem_limits(setup), steps, "", law).played


def method(setup, name: str, cache: dict | None = None):
    """A method by the CLI's name (`surestep solve --method NAME`)."""
    return run_method(setup, name, cache)


def newton(setup):
    """The projected Newton solver of the setup (its `.run`, `.solve`)."""
    return newton_solver(setup)


def diagonal_model(setup):
    """The setup with every base covariance replaced by its diagonal (the fast scalar path)."""
    return diagonal_model_setup(setup)


def objective_at(setup, sol, other) -> float:
    """The objective of `other`'s plan in `setup`'s model, as `sol` was measured (the second start's
    gate)."""
    return _objective_at(setup, sol, other)


def transcriptions(T: int | None = None) -> list:
    """The cached OCP transcriptions (builds), of horizon `T` if given."""
    return [tr for tr in cached_transcriptions() if T is None or tr.T == T]


def clear_solver_cache() -> None:
    """Drop the cached NLPs (their memory)."""
    _nlp_cache._CACHE.clear()


def set_curve_rows(mode: str) -> None:
    """The OCP's limit rows: "curve" (the played curve's, the default) or "steps" (finite
    differences)."""
    _limits.CURVE_ROWS = mode


def repeat(fn: Callable[[], Any], n: int) -> list:
    """`fn()` run `n` times; the results."""
    return [fn() for _ in range(n)]


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """`fn()` and its wall time [s]."""
    import time

    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


# --- the statistics -------------------------------------------------------------------------------
def median(xs: Iterable[float]) -> float:
    xs = list(xs)
    return float(np.median(xs)) if xs else float("nan")


def percentile(xs: Iterable[float], q: float) -> float:
    xs = list(xs)
    return float(np.percentile(xs, q)) if xs else float("nan")


@dataclass(frozen=True)
class Stats:
    n: int
    median: float
    p90: float
    p95: float
    worst: float
    best: float

    @property
    def worst_over_median(self) -> float:
        return self.worst / self.median if self.median else float("nan")


def replan_first_mu(value: float | None = None) -> float:
    """The Planner's first barrier parameter of a re-plan within the limits, set to `value` (None:
    kept); the one in force."""
    from surestep_ocp.methods import planner as _planner

    if value is not None:
        _planner.REPLAN_MU = float(value)
    return _planner.REPLAN_MU


def stats(xs: Iterable[float]) -> Stats:
    """Median, 90th and 95th percentile (NumPy's linear interpolation), worst (largest) and best."""
    a = np.asarray(list(xs), float)
    if not a.size:
        nan = float("nan")
        return Stats(0, nan, nan, nan, nan, nan)
    return Stats(int(a.size), float(np.median(a)), float(np.percentile(a, 90)),
                 float(np.percentile(a, 95)), float(a.max()), float(a.min()))


def ratio_of_medians(xs: Iterable[float], ref: Iterable[float]) -> float:
    """median(xs) / median(ref): e.g. the OCP's times against the gradient variant's in the same
    run."""
    return median(xs) / median(ref)


def median_ratio(xs: Sequence[float], ref: Sequence[float]) -> float:
    """The median of the per-instance ratios xs[i] / ref[i]."""
    return median(x / r for x, r in zip(xs, ref, strict=True))


def geomean(xs: Iterable[float]) -> float:
    xs = list(xs)
    return math.exp(sum(math.log(x) for x in xs) / len(xs)) if xs else float("nan")


# --- the report -----------------------------------------------------------------------------------
def row(*cells: Any) -> str:
    """A markdown table row: `| a | b |`."""
    return "| " + " | ".join(str(c) for c in cells) + " |"


def table(header: Sequence[str], rows: Iterable[Any] = ()) -> list[str]:
    """A markdown table's lines: the header, `|---|...`, then `rows` (lines, or sequences of
    cells)."""
    return [row(*header), "|" + "---|" * len(header),
            *(r if isinstance(r, str) else row(*r) for r in rows)]


def write_result(name: str | Path, text: str) -> Path:
    """`text` to benchmarks/results/<name> (a bare file name), or to the path `name` (a Path, or a
    str with a folder), whole or not at all."""
    return write_text_atomic(RESULTS / name if isinstance(name, str) and "/" not in name
                             else Path(name), text)


def key_values(**values: Any) -> str:
    """`key=value key=value` (values formatted by the caller)."""
    return " ".join(f"{k}={v}" for k, v in values.items())


def last_line(name: str, *groups: str) -> str:
    """The machine-readable last line: `name: key=value ... | key=value ...` (one group per horizon,
    say)."""
    return f"{name}: " + " | ".join(groups)


# --- the command line -----------------------------------------------------------------------------
def parser(doc: str | None, *, configs: int | None = None, configs_flag: str = "--configs",
           seed: int | None = None, horizons: list[int] | None = None, horizons_nargs: str = "+",
           output: str | Path | None = None,
           output_flag: str = "--output") -> argparse.ArgumentParser:
    """The common options, each added when its default is given; the description is the docstring's
    first line."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0] if doc else None)
    if configs is not None:
        ap.add_argument(configs_flag, type=int, default=configs)
    if seed is not None:
        ap.add_argument("--seed", type=int, default=seed)
    if horizons is not None:
        ap.add_argument("--horizons", type=int, nargs=horizons_nargs, default=list(horizons))
    if output is not None:
        ap.add_argument(output_flag, type=Path, default=Path(output))
    return ap
