"""The reduced (KKT) matrix's band layout (LAPACK's lower band storage, half-bandwidth WINDOW
nodes), built once per structure, and the matrix's assembly from its parts and factorisation at
each iteration."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpbtrf, dpbtrs

from .jacobian import _csr_dot
from .options import WINDOW


class BandPart:
    """`InteriorNewton`'s band: where each part of the reduced matrix goes, its assembly and its
    banded Cholesky factorisation."""

    def _build_windows(self) -> None:
        """The tool points' windows: their slots, their maps from the waypoints and the windows'
        weights and band entries (`tool_*`, `window_*`, `point_*`)."""
        nq, npts, n = self.nq, self.n_pts, self.n
        # the band layout (lower storage, half-bandwidth WINDOW nodes)
        self.bw = WINDOW * nq
        r, cc = np.meshgrid(np.arange(WINDOW * nq), np.arange(WINDOW * nq), indexing="ij")
        # the points of one piece share its window: their blocks are summed per window, then
        # scattered
        windows_u, self.point_window = np.unique(self.tool_nodes, axis=0, return_inverse=True)
        self.point_window = self.point_window.ravel()
        slot = np.zeros(npts, int)
        for p in range(1, npts):
            slot[p] = slot[p - 1] + 1 if self.point_window[p] == self.point_window[p - 1] else 0
        self.point_slot, self.n_windows, self.window_points = (slot, len(windows_u),
                                                               int(slot.max()) + 1)
        # (points, 2 nq, W nq): each point's (q(s), q'(s)) from its window's waypoints
        cw, eye = self.point_cw, np.eye(nq)
        self.tool_map = np.concatenate([np.concatenate([cw[:, a, m, None, None] * eye
                                                        for m in range(WINDOW)], axis=2)
                                        for a in range(2)], axis=1)
        # (windows, W W, points x (a, b)): C_pa[m] C_pb[n] of each window's points (zero-padded)
        self.point_flat = self.point_window * self.window_points + slot
        U = np.zeros((self.n_windows * self.window_points, 4, WINDOW * WINDOW))
        U[self.point_flat] = np.einsum("pam,pbn->pabmn", cw, cw).reshape(npts, 4, -1)
        self.window_weights = (U.reshape(self.n_windows, -1, WINDOW * WINDOW)
                               .transpose(0, 2, 1).copy())
        if np.any(np.diff(self.point_window) < 0):
            raise ValueError("tool points are not ordered by window")
        wvar = (windows_u[:, :, None] * nq
                + np.arange(nq)[None, None, :]).reshape(len(windows_u), -1)
        vr, vc = wvar[:, r.ravel()], wvar[:, cc.ravel()]  # (windows, (W nq)^2)
        self.tool_low = vr >= vc
        self.tool_band = ((vr - vc) * n + vc)[self.tool_low]

    def _build_band_scatter(self) -> None:
        """The band entries of the linear rows, the surrogate and the depths, the free variables
        and the sparse matrices that sum every part into the band (`band_scatter`)."""
        newton, T, nq, n = self.newton, self.T, self.nq, self.n
        width = self.lin_idx.shape[1]
        li = self.lin_idx
        lr, lc = li[:, :, None].repeat(width, 2), li[:, None, :].repeat(width, 1)
        self.lin_low = ((lr >= lc) & (self.lin_coef[:, :, None] != 0)
                        & (self.lin_coef[:, None, :] != 0))
        self.lin_band = ((lr - lc) * n + lc)[self.lin_low]
        self.lin_pair = (self.lin_coef[:, :, None] * self.lin_coef[:, None, :])[self.lin_low]
        self.lin_pair_row = np.broadcast_to(np.arange(self.n_lin)[:, None, None],
                                            lr.shape)[self.lin_low]
        hr, hc = newton.h_rows, newton.h_cols
        self.h_low = hr >= hc
        self.h_band = ((hr - hc) * n + hc)[self.h_low]
        a, b = newton.node_pairs
        self.node_band = np.concatenate([(a - b) * n + t * nq + b for t in range(T + 1)])
        self.band_partner = np.minimum(np.arange(n)[None, :] + np.arange(self.bw)[:, None], n)
        self._set_bounds()
        self._jac_pattern(self.free_idx)
        self._held = None  # (free indices, held mask, band entries outside the free block)
        # every band entry as one sparse product with (the surrogate's blocks, the linear rows'
        # weights, the nodes' depth blocks, the windows' blocks): sums over a fixed pattern
        nbw = self.bw * n
        nodes = (np.arange(T + 1)[:, None] * nq * nq + a * nq + b).ravel()
        # the windows' entries in `_window_terms`' order: each one's place in the (windows, W nq,
        # W nq) blocks
        nw_ = self.n_windows
        place = (np.arange(self.tool_low.size).reshape(nw_, WINDOW, nq, WINDOW, nq)
                 .transpose(0, 1, 3, 2, 4).ravel())
        order = np.argsort(place)  # block entry -> its position in the terms
        tool_cols = order[np.flatnonzero(self.tool_low)]
        # the windows' part alone too: the end-game adds the tool rows' exact curvature with it
        self.tool_scatter = sp.csr_matrix(
            (np.ones(len(tool_cols)), (self.tool_band, tool_cols)), shape=(nbw, self.tool_low.size))
        parts = [(self.h_band, np.flatnonzero(self.h_low), np.ones(self.h_low.sum()),
                  len(self.h_low)),
                 (self.lin_band, self.lin_pair_row, self.lin_pair, self.n_lin),
                 (self.node_band, nodes, np.ones(len(nodes)), (T + 1) * nq * nq)]
        # one matrix per part, their products summed into the band in turn: each entry's sum runs
        # in the order of one product with them side by side (without concatenating the parts)
        self.band_scatter = [sp.csr_matrix((v, (r, c_)), shape=(nbw, size))
                             for r, c_, v, size in parts] + [self.tool_scatter]
        # the entries outside the free block (a held joint's row or column) are left out: the
        # factorisation sees the held joints as identity rows (`_factor`), so the band holds
        # zeros there without clearing them at every iteration
        inside = np.ones(nbw)
        inside[self._held_entries(self.free_idx)[1]] = 0.0
        keep = sp.diags(inside, format="csr")
        self.band_scatter = [keep @ S for S in self.band_scatter]
        for S in self.band_scatter:
            S.eliminate_zeros()
            S.sort_indices()
        self.tool_scatter = self.band_scatter[-1]

    @staticmethod
    def _tool_blocks(A: np.ndarray, gy: np.ndarray, wk: np.ndarray, st: np.ndarray
                     ) -> np.ndarray:
        """Each tool point's block of the reduced matrix in its (q(s), q'(s)), (points, 2 nq,
        2 nq): Gauss-Newton's curvature of wk . g (the velocities' Jacobian A weighted by 2 wk_0,
        wk_1) plus sum_k st_k gy_k gy_k^T (st: the rows' w / c)."""
        wv = np.empty(A.shape[:2])
        wv[:, :3], wv[:, 3:] = 2 * wk[0][:, None], wk[1][:, None]
        return ((A * wv[:, :, None]).transpose(0, 2, 1) @ A
                + (gy * st[:, :, None]).transpose(0, 2, 1) @ gy)

    def _band(self, HB: np.ndarray, wl: np.ndarray, blocks: np.ndarray, JW: np.ndarray
              ) -> np.ndarray:
        """The reduced matrix in LAPACK's lower band storage (bw, n) from its parts: the
        surrogate's interval blocks, the linear rows' weights, the depths' node blocks (flat) and
        the tool windows' terms (`_window_terms`), each part's sparse product added in turn."""
        ab = np.zeros(self.bw * self.n)
        for S, part in zip(self.band_scatter, (HB, wl, blocks, JW)):
            _csr_dot(S, part, ab)
        return ab.reshape(self.bw, self.n)

    def _to_window(self, Y: np.ndarray) -> np.ndarray:
        """(points, r, 2 nq) derivatives in each point's (q(s), q'(s)) -> (points, r, W nq) in
        its window's waypoints."""
        return Y @ self.tool_map

    def _window_terms(self, H: np.ndarray) -> np.ndarray:
        """(points, 2 nq, 2 nq) Hessians in each point's (q(s), q'(s)) -> the windows' blocks
        summed over each window's points, sum_p K_p^T H_p K_p with K_p = C_p kron I, i.e. sum_p,a,b
        (C_pa C_pb^T) kron H_p,ab: one product per window, flat in its (window, m, n, i, j) order
        (node m's joint i, node n's joint j), the order `tool_scatter` takes."""
        nq, nw, npts = self.nq, self.n_windows, self.n_pts
        V = np.zeros((nw * self.window_points, 4, nq * nq))
        V[self.point_flat] = (H.reshape(npts, 2, nq, 2, nq).transpose(0, 1, 3, 2, 4)
                              .reshape(npts, 4, nq * nq))
        return (self.window_weights @ V.reshape(nw, -1, nq * nq)).ravel()

    def _factor(self, ab: np.ndarray, idx: np.ndarray, shift: float, may_shift: bool = True):
        """The banded matrix on the free variables (held ones: identity) factorised, shifted until
        positive definite (with `may_shift` false: only as it is): (solve(rhs), shift, its banded
        factor, the held mask) or None."""
        n = self.n
        if self._held is None or self._held[0] is not idx:
            self._held = (idx, *self._held_entries(idx))
        _, fixed, outside = self._held
        if idx is not self.free_idx:
            np.put(ab, outside, 0.0)  # (the band's parts leave out the held entries of free_idx)
        ab[0, fixed] = 1.0
        shift = shift / 4 if shift > 1e-14 else 0.0

        def diagonal_scale() -> float:  # bounds the shift: computed only once one is applied
            return max(float(np.max(np.abs(ab[0, idx]))) if len(idx) else 0.0, 1e-12)

        scale = diagonal_scale() if shift else None
        while scale is None or shift <= 1e12 * scale:
            shifted = ab.copy()
            if shift:
                shifted[0, idx] += shift
            factor, info = dpbtrf(shifted, lower=1, overwrite_ab=1)
            if info == 0:
                def solve(rhs, factor=factor):
                    d = dpbtrs(factor, np.where(fixed, 0.0, rhs)[:, None], lower=1)[0][:, 0]
                    return d if np.all(np.isfinite(d)) else np.zeros(n)
                return solve, shift, factor, fixed
            if not may_shift:
                return None
            scale = diagonal_scale() if scale is None else scale
            shift = max(1e-8 * scale, 10 * shift)
        return None

    def _held_entries(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(held mask, flat band entries in a held joint's row or column) for free indices idx."""
        fixed = np.ones(self.n + 1, bool)
        fixed[idx] = False
        return fixed[:self.n], np.flatnonzero(fixed[:self.n][None, :] | fixed[self.band_partner])

