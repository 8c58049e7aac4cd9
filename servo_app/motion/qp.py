"""A persistent QP solver for the per-cycle diff-IK problem

    minimize 1/2 x' P x + q' x   subject to   G x <= h

with a FIXED size (n variables, m rows) from cycle to cycle.

mink's ``solve_ik(..., solver="osqp")`` builds a new OSQP problem every call (setup, factorisation,
cold start: over a millisecond here). ``PersistentQP`` sets OSQP up once with a dense-but-fixed
sparsity pattern (the whole upper triangle of P, every entry of G, explicit zeros included) and then
only writes new values in place (``update(Px=..., Ax=..., q=..., u=...)``) and warm-starts from the
last solution. Rows that a limit leaves inactive keep their place with ``h = +inf``, so the pattern
never changes. ``solver="daqp"`` calls DAQP (dual active set, no setup to keep) on the same data.

Scaling: the IK's variable is a per-cycle increment (~1e-3 rad), so absolute tolerances of 1e-6
would be loose. With ``var_scale=dt`` the solver works on ``x / dt`` (a velocity, ~1 rad/s):
P unchanged, q / dt, G unchanged, h / dt, which keeps eps_abs meaningful; the returned x is in the
caller's units.

Failure never returns NaN: ``QpSolution.ok`` is False and ``x`` is zero.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from types import ModuleType
from typing import Literal

import numpy as np
import osqp
import scipy.sparse as sp

from servo_app.motion import ik_kernels as kernels

INF = 1e30  # OSQP_INFTY; DAQP treats +-1e30 as unbounded as well
SolverName = Literal["osqp", "daqp"]
SOLVERS: tuple[SolverName, ...] = ("osqp", "daqp")


@dataclass(frozen=True)
class QpSettings:
    eps_abs: float = 1e-6
    eps_rel: float = 1e-6
    max_iter: int = 1000  # bounded (~1 ms worst case here); ~100 are typical on the IK problem
    feasibility_tol: float = 1e-6  # accepted violation of G x <= h (caller's units) for inexact exits
    check_termination: int = 5  # OSQP checks convergence every N iterations (1 would cost more per iteration)


@dataclass(frozen=True)
class QpSolution:
    x: np.ndarray  # zero when not ok
    ok: bool
    status: str
    iterations: int


class PersistentQP:
    """One problem shape, solved many times; see the module docstring."""

    def __init__(self, n: int, m: int, solver: SolverName = "osqp", *, var_scale: float = 1.0,
                 settings: QpSettings | None = None) -> None:
        if solver not in SOLVERS:
            raise ValueError(f"solver={solver!r} must be one of {SOLVERS}")
        if n <= 0 or m < 0:
            raise ValueError(f"problem size n={n}, m={m} is invalid")
        if not var_scale > 0.0:
            raise ValueError(f"var_scale={var_scale} must be > 0")
        self.n, self.m, self.solver, self.var_scale = n, m, solver, float(var_scale)
        self.settings = settings or QpSettings()
        self._triu = np.triu_indices(n)
        # CSC of the dense upper triangle lists column by column, rows 0..j: reorder triu_indices.
        order = np.lexsort((self._triu[0], self._triu[1]))
        self._p_rows, self._p_cols = self._triu[0][order], self._triu[1][order]
        self._osqp: osqp.OSQP | None = None
        self._l = np.full(m, -INF)
        self._qs, self._hs = np.zeros(n), np.zeros(m)
        self._sense = np.zeros(m, dtype=np.intc)  # all rows inequalities, no warm start
        # DAQP imported only for DAQP: an optional backend, import time kept down for OSQP users.
        self._daqp: ModuleType | None = importlib.import_module("daqp") if solver == "daqp" else None
        self.solves = 0
        self.failures = 0

    # ------------------------------------------------------------------------------------------
    def solve(self, p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray) -> QpSolution:
        """Solve for this cycle's data; shapes must match the constructor's (n, m)."""
        n, m = self.n, self.m
        if p.shape != (n, n) or q.shape != (n,) or g.shape != (m, n) or h.shape != (m,):
            raise ValueError(f"QP data shapes P{p.shape} q{q.shape} G{g.shape} h{h.shape} "
                             f"do not match the fixed size n={n}, m={m}")
        s = self.var_scale
        p, g = np.ascontiguousarray(p, dtype=float), np.ascontiguousarray(g, dtype=float)
        qs, hs = self._qs, self._hs  # the solver's units, checked and scaled in one kernel (per cycle)
        self.solves += 1
        if not kernels.scaled_qp_data(p, np.ascontiguousarray(q, dtype=float), g, np.ascontiguousarray(h, dtype=float),
                                      s, INF, qs, hs):
            return self._fail("non-finite data")
        if self.solver == "osqp":
            xs, status, iters, exact = self._solve_osqp(p, qs, g, hs)
        else:
            xs, status, iters, exact = self._solve_daqp(p, qs, g, hs)
        if xs is None or not kernels.all_finite(xs):
            return self._fail(status, iters)
        if not exact and m and float(np.max(g @ xs - hs)) > self.settings.feasibility_tol / s:
            return self._fail(status, iters)
        return QpSolution(xs * s, True, status, iters)

    def reset(self) -> None:
        """Forget the warm start (after a failure or a jump in state)."""
        if self._osqp is not None:
            self._osqp.warm_start(x=np.zeros(self.n), y=np.zeros(self.m))

    # ------------------------------------------------------------------------------------------
    def _fail(self, status: str, iters: int = 0) -> QpSolution:
        self.failures += 1
        self.reset()
        return QpSolution(np.zeros(self.n), False, status, iters)

    def _solve_osqp(self, p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray
                    ) -> tuple[np.ndarray | None, str, int, bool]:
        px = p[self._p_rows, self._p_cols]
        ax = g.ravel(order="F")  # CSC of a dense matrix: column-major values
        if self._osqp is None:
            self._setup_osqp(px, q, ax, h)
        else:
            self._osqp.update(Px=px, Ax=ax, q=q, u=h)
        assert self._osqp is not None
        res = self._osqp.solve(raise_error=False)
        status = str(res.info.status)
        iters = int(res.info.iter)
        if res.info.status_val == osqp.SolverStatus.OSQP_SOLVED:
            return np.array(res.x), status, iters, True
        if res.info.status_val in (osqp.SolverStatus.OSQP_SOLVED_INACCURATE,
                                   osqp.SolverStatus.OSQP_MAX_ITER_REACHED):
            return np.array(res.x), status, iters, False  # accepted only if feasible (checked above)
        return None, status, iters, False

    def _setup_osqp(self, px: np.ndarray, q: np.ndarray, ax: np.ndarray, h: np.ndarray) -> None:
        n, m = self.n, self.m
        p_indptr = np.concatenate([[0], np.cumsum(np.arange(1, n + 1))])
        p_csc = sp.csc_matrix((px, self._p_rows, p_indptr), shape=(n, n))
        a_csc = sp.csc_matrix((ax, np.tile(np.arange(m), n), np.arange(0, m * n + 1, m)), shape=(m, n))
        st = self.settings
        solver = osqp.OSQP()
        solver.setup(p_csc, q, a_csc, self._l, h, eps_abs=st.eps_abs, eps_rel=st.eps_rel,
                     max_iter=st.max_iter, polishing=False, warm_starting=True, verbose=False,
                     check_termination=st.check_termination)
        self._osqp = solver

    def _solve_daqp(self, p: np.ndarray, q: np.ndarray, g: np.ndarray, h: np.ndarray
                    ) -> tuple[np.ndarray | None, str, int, bool]:
        # daqp.solve sets a workspace up per call, and still costs less than a kept daqp.Model: its
        # update() took 5 us here (12 us after other work), its solve() 2.5 us, daqp.solve 5.5 us
        # in all (12-16 us after other work); 6 variables, 65 rows. It leaves the sense array it is
        # given as it was (all zeros): every solve starts cold, the same iterations, the same answer.
        assert self._daqp is not None
        x, _fval, exitflag, info = self._daqp.solve(p, q, g, h, self._l, self._sense)
        iters = int(info.get("iterations", 0)) if isinstance(info, dict) else 0
        if exitflag >= 1:
            return x, f"daqp:{exitflag}", iters, True
        return None, f"daqp:{exitflag}", iters, False
