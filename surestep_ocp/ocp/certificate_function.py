"""The certificate's CasADi Function of one structure, built once per process and compiled late.

`(Q, camera, sigma0, trace_ref) -> (f, trace, grad f, means, mean Jacobians, W, V, F, Q, H, R, W_q)`
for a structure (robot, belief model, horizon, smoothness): interpreted at first, compiled to C
(or loaded from the compile cache) at its `COMPILE_AFTER`-th use in the process. A re-plan's
certificate is evaluated by the padded Function of its horizon's bucket (`PAD_STEPS`,
`_padded_call`), with the values its own horizon's would give (docs/certificate.md, "Re-plans").
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from ..buffered import thread_buffered
from ..model.belief import DIAG, NV, NX
from ..model.joint_noise import joint_noise_function
from ..model.robot import CAMERA_PARAMETERS
from ..problem.setup import Setup
from .codegen import available as compiler_available
from .codegen import compiled_or_interpreted

# the certificate of one structure in a process at which its Function is compiled (or loaded from
# the compile cache): `surestep solve` (its plan and the baseline it is compared with: two) stays
# interpreted (a compile takes about 1 s, a cached load about 20 ms, one interpreted evaluation
# 0.5-1.5 ms); a process that plans the structure again (compare, evaluate, a benchmark, a
# re-planning loop) evaluates it compiled from its third certificate on
COMPILE_AFTER = 3
# a re-plan's certificate is evaluated by the Function of its horizon rounded up to a multiple of
# this (padded; `_padded_call`): a re-planning loop's horizons share a few Functions, compiled in
# its first episode, instead of one per horizon, each compiled at its third use
PAD_STEPS = 16


class _Function:
    """A certificate's Function of one structure: interpreted at first, compiled to C (or loaded
    from the compile cache) at its `COMPILE_AFTER`-th use in the process where the problem's
    `solver.codegen` allows (auto with a C compiler, or true; a compile that fails leaves it
    interpreted, `note` says why: the certificate never stops a solve)."""

    def __init__(self, fn: ca.Function, **facts):
        self.fn, self.facts = fn, facts
        self.uses, self.settled, self.compiled, self.note = 0, False, False, None

    def current(self, codegen, built: list[float]) -> ca.Function:
        """The Function to evaluate now (`built[0]` += the seconds a compile or load took)."""
        self.uses += 1
        if self.uses >= COMPILE_AFTER:
            self.settle(codegen, built)
        return self.fn

    def settle(self, codegen, built: list[float]) -> None:
        """Compiled (or loaded) now, once, where `codegen` allows: at its `COMPILE_AFTER`-th use,
        or before a re-planning loop (`certificate.prepare_replans`)."""
        if self.settled:
            return
        self.settled = True
        if codegen is True or (codegen == "auto" and compiler_available()):
            t0 = time.perf_counter()
            name = self.fn.name()
            fns, self.note = compiled_or_interpreted({name: self.fn}, required=False)
            self.fn, self.compiled = fns[name], self.note is None
            built[0] += time.perf_counter() - t0


_FUNCTIONS: dict[tuple, _Function] = {}


def padded_steps(T: int) -> int:
    """The steps of the padded Function a re-plan over T steps is certified with: T rounded up
    to a multiple of PAD_STEPS (a re-planning loop's horizons share a few Functions)."""
    return -(-T // PAD_STEPS) * PAD_STEPS


def _function(setup: Setup, built: list[float], padded: bool = False) -> _Function:
    """The certificate's Function of this setup's structure, `(Q, camera, sigma0, trace_ref) ->
    (f, trace, grad f, means, mean Jacobians, W, V, F, Q, H, R, W_q)` (built once per process).
    `padded`: over `padded_steps(T)` steps N instead, with two more inputs, `(select, steps)` (1 x
    N each): the trace is `select`'s weighted sum of the steps' traces (one-hot at step T) and the
    smoothness sums the steps `steps` weighs (ones on the first T); the joints after q_T repeat it
    (`_padded_call`)."""
    robot, model, T = setup.robot, setup.model, setup.ocp.horizon
    if padded:
        T = padded_steps(T)
    key = (str(robot.urdf), robot.frame, robot.offset.tobytes(), model.key(), T,
           setup.ocp.smoothness, padded)
    if key in _FUNCTIONS:
        return _FUNCTIONS[key]
    t0 = time.perf_counter()
    nq = robot.nq
    Q = ca.MX.sym("Q", nq, T + 1)
    cam, s0, ref = ca.MX.sym("camera", CAMERA_PARAMETERS), ca.MX.sym("sigma0", NV), ca.MX.sym("r")
    M = robot.camera_pose.map(T + 1)(Q, cam)
    a, b = M[:, :T], M[:, 1:]
    if model.joint_noise:
        w = joint_noise_function(robot, model.noise.joint_sigma).map(T)(Q[:, :T], Q[:, 1:], cam)
    else:
        w = ca.MX.zeros(NV, T)
    roll = model.step_pair.mapaccum("certificate_roll", T, [2], [0])
    post, prior = roll(a, b, s0, w)
    kept = prior if model.noise.objective == "predicted" else post
    extra = []
    if padded:
        select, steps = ca.MX.sym("select", 1, T), ca.MX.sym("steps", 1, T)
        extra = [select, steps]
        trace = ca.dot(select, sum(kept[i, :] for i in DIAG))
        dQ = Q[:, 1:] - Q[:, :T]
        f = trace / ref + setup.ocp.smoothness * ca.dot(steps, ca.sum1(dQ * dQ))
    else:
        last = kept[:, T - 1]
        trace = sum(last[i] for i in DIAG)
        f = trace / ref + setup.ocp.smoothness * ca.sumsqr(Q[:, 1:] - Q[:, :T])
    q1 = ca.SX.sym("q", nq)
    c1 = ca.SX.sym("camera", CAMERA_PARAMETERS)
    jac = ca.Function("mean_jacobian", [q1, c1],
                      [ca.densify(ca.jacobian(robot.camera_pose(q1, c1), q1))])
    J = jac.map(T + 1)(Q, cam)  # 7 x nq (T+1)
    # what the NumPy EKF takes: the model's noise (and, not identity, its maps) at the means
    has_v = model.noise.observation_noise == "mean"
    none = ca.MX.zeros(1, 1)
    W = model.motion_noise.map(T)(a, b)
    V = model.observation_noise.map(T)(b) if has_v else none
    maps = list(model.jacobians.map(T)(a, b)) if not model.identity_maps else [none] * 4
    fn = ca.Function("certificate_padded" if padded else "certificate", [Q, cam, s0, ref, *extra],
                     [ca.densify(v) for v in
                      (f, trace, ca.gradient(f, ca.vec(Q)), M, J, W, V, *maps,
                       w if model.joint_noise else none)])
    _FUNCTIONS[key] = _Function(fn, has_v=has_v, has_maps=not model.identity_maps,
                                has_joint=model.joint_noise, steps=T)
    built[0] += time.perf_counter() - t0
    return _FUNCTIONS[key]


def _padded_call(setup: Setup, q: np.ndarray, args: tuple, built: list[float]):
    """(holder, outputs) of the padded Function at the plan `q` (T + 1 waypoints): the joints
    after q_T repeat it, the trace selected at step T, the smoothness over the first T steps;
    each output cut to what the plan's own Function gives (every output's first T or T + 1
    columns: the steps after T do not reach them). None where an output is not finite."""
    T = len(q) - 1
    holder = _function(setup, built, padded=True)
    N = holder.facts["steps"]
    fn = holder.current(setup.ocp.solver.codegen, built)
    Q = np.vstack([q, np.repeat(q[-1:], N - T, axis=0)])
    select, steps = np.zeros(N), np.zeros(N)
    select[T - 1], steps[:T] = 1.0, 1.0
    out = thread_buffered(("certificate", fn), lambda: fn)(Q.T, *args, select, steps)
    nq = q.shape[1]
    # per column: f, trace, grad f, M, J, W, V, F, Q, H, R, W_q (one-column outputs: the whole)
    size = [1, 1, nq * (T + 1), 7 * (T + 1), 7 * nq * (T + 1)] + [NX * NX * T] * 6 + [NV * T]
    cut = [v if v.size <= 1 else v[:n] for v, n in zip(out, size)]
    if not all(np.all(np.isfinite(v)) for v in cut[:5]):
        return None
    return holder, cut
