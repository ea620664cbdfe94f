"""The structured solvers' scalar-coefficient form (surestep_ocp.ocp.surrogate): Tr(Sigma_T) =
S(c) of the noise coefficients with constant base matrices, the 6x6 matrix recursion and its weights
dS/dc, against a plain NumPy EKF (tests/numpy_ekf.py) and central differences of it. The models
beyond the paper's constants (full 6x6 base covariances, a noise floor) are test_lifted.py's
`MODELS`.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from numpy_ekf import ekf_step
from test_lifted import MODELS, problem

from surestep_ocp.problem.setup import build_setup
from surestep_ocp.ocp.surrogate import recursion_weights


@pytest.mark.parametrize("name", list(MODELS))
def test_matrix_recursion_weights_match_a_numpy_ekf_and_finite_differences(name):
    """S(c) of the structured solvers (6x6 recursion) equals the NumPy EKF's trace for the same
    noise matrices, and its weights dS/dc equal central differences of that NumPy trace."""
    setup = build_setup(problem(4, **MODELS[name]))
    m, n, T = setup.model, setup.ocp.noise, 4
    assert m.structured and not m.scalar
    Wm, Vm = m.motion_matrices(), m.observation_matrices()
    rng = np.random.default_rng(0)
    cm, co = rng.uniform(1e-4, 1e-2, (2, T)), rng.uniform(1e-3, 5e-2, (3, T))

    def numpy_trace(cm, co):
        sig = np.asarray(n.Sigma0, float)
        for t in range(T):
            W = sum(cm[k, t] * Wm[k] for k in range(2))
            V = np.asarray(n.V_min) + sum(co[k, t] * Vm[k] for k in range(3))
            sig, _ = ekf_step(sig, W, V)
        return np.trace(sig)

    fn = recursion_weights(m, T, ca.SX.sym("s", 21), ca.SX.sym("r"))
    S, dm, do, _ = (np.asarray(v) for v in fn(cm, co, np.zeros((0, T)),
                                              m.recursion_sigma0(n.Sigma0), 1.0))
    assert S.item() == pytest.approx(numpy_trace(cm, co), rel=1e-12)
    for c, d in ((cm, dm), (co, do)):
        for idx in np.ndindex(c.shape):
            h = 1e-4 * c[idx]
            up, dn = c.copy(), c.copy()
            up[idx] += h
            dn[idx] -= h
            args = (up, co) if c is cm else (cm, up)
            argsd = (dn, co) if c is cm else (cm, dn)
            fd = (numpy_trace(*args) - numpy_trace(*argsd)) / (2 * h)
            assert d[idx] == pytest.approx(fd, rel=1e-5, abs=1e-12)
            assert d[idx] >= 0  # S is nondecreasing in the coefficients
