"""A nonlinear program assembled from small named pieces, in the manner of ifopt: variable sets (symbols, bounds,
initial values), constraint sets (expressions and bounds) and cost terms (scalar expressions), solved by IPOPT
through CasADi with exact first and second derivatives (CasADi's algorithmic differentiation).

A stage of a staged solve is the same program with some variable sets held at their values (`fixed`) and some
constraint sets switched off (`relaxed`, left out of what IPOPT solves), so the program and its derivatives are
built once and solved several times (one IPOPT instance per choice of switched-off sets).
"""

from __future__ import annotations

import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp

from .splines import to_dm

INF = np.inf


@dataclass
class VariableSet:
    """n optimisation variables: bounds and initial values (n,); `symbols` (n, 1) is their part of the
    program's variable vector once the program is laid out."""

    name: str
    size: int
    lower: np.ndarray
    upper: np.ndarray
    initial: np.ndarray
    symbols: object = None

    @staticmethod
    def create(name: str, size: int) -> VariableSet:
        return VariableSet(name, size, np.full(size, -INF), np.full(size, INF), np.zeros(size))


@dataclass
class ConstraintSet:
    """Constraints lower <= g(x) <= upper, collected row block by row block. `linear`: g is linear in x (its
    Hessian is zero and is not built). Rows may be written on `read` symbols, each standing for a sparse linear
    map of x: they are then differentiated in those few symbols and mapped to x by the chain rule."""

    name: str
    linear: bool = False
    rows: list = field(default_factory=list)
    lower: list = field(default_factory=list)
    upper: list = field(default_factory=list)
    inputs: list = field(default_factory=list)  # (symbols (k, 1), scipy sparse map (k, n)) of every read

    def read(self, matrix: sp.spmatrix, x):
        """(k, 1) standing for matrix @ x, matrix a scipy sparse (k, n) map, x the program's variables: a symbol
        per row that reads x, a structural zero per empty row (a force in flight), so that, as in an expression
        graph, nothing multiplied by it depends on x."""
        matrix = sp.csr_matrix(matrix)
        used = np.flatnonzero(np.diff(matrix.indptr))
        symbols = type(x).sym(f"{self.name}_{len(self.inputs)}", len(used))
        self.inputs.append((symbols, matrix[used]))
        place = sp.csr_matrix((np.ones(len(used)), (used, np.arange(len(used)))), shape=(matrix.shape[0], len(used)))
        return ca.mtimes(to_dm(place), symbols)

    def local_form(self):
        """(rows in the read symbols z, z, the sparse map S with z = S x), or None when nothing was read."""
        if not self.inputs:
            return None
        return (ca.densify(self.expression()), ca.vertcat(*[z for z, _ in self.inputs]),
                sp.vstack([m for _, m in self.inputs]).tocsr())

    def expression_in(self, x):
        """The rows as expressions of x (the read symbols replaced by their maps)."""
        local = self.local_form()
        if local is None:
            return self.expression()
        rows, z, S = local
        return ca.substitute(rows, z, ca.densify(ca.mtimes(to_dm(S), x)))

    def add(self, expression, lower=0.0, upper=0.0) -> None:
        expression = ca.vec(expression)
        n = int(expression.shape[0])
        self.rows.append(expression)
        self.lower.append(np.broadcast_to(np.asarray(lower, float), (n,)).copy())
        self.upper.append(np.broadcast_to(np.asarray(upper, float), (n,)).copy())

    @property
    def size(self) -> int:
        return int(sum(r.shape[0] for r in self.rows))

    def expression(self):
        return ca.vertcat(*self.rows) if self.rows else None

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.rows:
            return np.zeros(0), np.zeros(0)
        return np.concatenate(self.lower), np.concatenate(self.upper)


@dataclass
class CostTerm:
    """A scalar term of the objective. `squares`: the term is sum_k w_k |M_k x - t_k|^2, given as (w_k, M_k
    scipy sparse, t_k) blocks, so its gradient and (constant) Hessian are built from the matrices; None: `value`
    is any expression, differentiated by CasADi."""

    name: str
    value: Any  # a CasADi scalar expression (SX or MX) in the variable vector
    squares: list | None = None

    @staticmethod
    def least_squares(name: str, x, squares: list) -> CostTerm:
        """sum_k w_k |M_k x - t_k|^2 from (w_k, M_k, t_k) blocks: M_k (m, n) scipy sparse, t_k (m,)."""
        value = type(x)(0)
        for weight, matrix, target in squares:
            value = value + weight * ca.sumsqr(ca.mtimes(to_dm(matrix), x) - ca.DM(target))
        return CostTerm(name, value, squares)

    def hessian_and_offset(self, size: int) -> tuple[sp.csr_matrix, np.ndarray]:
        """(H, b) of a least-squares term: its gradient is H x - b, its Hessian H (constant)."""
        hessian, offset = sp.csr_matrix((size, size)), np.zeros(size)
        for weight, matrix, target in self.squares or []:
            hessian = hessian + 2 * weight * (matrix.T @ matrix)
            offset += 2 * weight * (matrix.T @ target)
        return sp.csr_matrix(hessian), offset


@dataclass
class Solution:
    """One IPOPT run. x: (n,) values; values: the same split by variable set; costs: each term's value;
    status: IPOPT's return status; converged: it reports an optimum (to its tolerance or its acceptable one)."""

    x: np.ndarray
    values: dict[str, np.ndarray]
    objective: float
    costs: dict[str, float]
    status: str
    converged: bool
    iterations: int
    seconds: float
    max_violation: float


CONVERGED_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")


@contextmanager
def interrupts_noted():
    """Within: Ctrl-C (SIGINT) is noted in the yielded list, then handled as before (by default: KeyboardInterrupt
    raised). CasADi catches that KeyboardInterrupt inside IPOPT, stops the solve and returns a status
    (NonIpopt_Exception_Thrown) that cannot be told from other failures; the list tells the caller to raise it
    again. Only in the main thread and where SIGINT has a Python handler (not where it is ignored, as in pool
    workers)."""
    noted: list[int] = []
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield noted
        return

    def note(signum, frame):
        noted.append(signum)
        previous(signum, frame)

    signal.signal(signal.SIGINT, note)
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, previous)


class IterationLimit(ca.Callback):
    """IPOPT's iteration callback that stops a run after `limit` iterations: one solver serves runs with
    different limits (IPOPT's own max_iter is fixed when the solver is built)."""

    def __init__(self, variables: int, constraints: int):
        ca.Callback.__init__(self)
        self.variables, self.constraints = variables, constraints
        self.limit: int | None = None
        self.count = 0
        self.construct("iteration_limit", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "stop"

    def get_sparsity_in(self, i):
        name = ca.nlpsol_out(i)
        if name == "f":
            return ca.Sparsity.scalar()
        if name in ("x", "lam_x"):
            return ca.Sparsity.dense(self.variables)
        if name in ("g", "lam_g"):
            return ca.Sparsity.dense(self.constraints)
        return ca.Sparsity(0, 0)

    def eval(self, arg):
        self.count += 1  # called once for the starting point too
        return [int(self.limit is not None and self.count > self.limit)]


class Program:
    """The program of the given pieces, with its IPOPT solver built once. x: the variable vector (a CasADi
    symbol, SX or MX), the variable sets laid out along it in order."""

    def __init__(self, x, variables: list[VariableSet], constraints: list[ConstraintSet], costs: list[CostTerm],
                 ipopt_options: dict):
        self.variables, self.costs = variables, costs
        constraints = [c for c in constraints if c.size]
        self.constraints = constraints
        self.x = x
        self.var_slices: dict[str, slice] = {}
        start = 0
        for v in variables:
            self.var_slices[v.name] = slice(start, start + v.size)
            start += v.size
        self.con_slices: dict[str, slice] = {}
        start = 0
        for c in constraints:
            self.con_slices[c.name] = slice(start, start + c.size)
            start += c.size
        if sum(v.size for v in variables) != x.shape[0]:
            raise ValueError("the variable sets do not lay out the whole variable vector")
        zero = type(x)(0)
        self.g = (ca.densify(ca.vertcat(*[c.expression_in(x) for c in constraints])) if constraints
                  else type(x)(0, 1))
        self.f = sum((c.value for c in costs), zero)
        self.lbg = np.concatenate([c.bounds()[0] for c in constraints]) if constraints else np.zeros(0)
        self.ubg = np.concatenate([c.bounds()[1] for c in constraints]) if constraints else np.zeros(0)
        self.ipopt_options = dict(ipopt_options)
        self._pieces = self._differentiate() if isinstance(x, ca.SX) else None
        self._solvers: dict[tuple[str, ...], tuple[Any, IterationLimit, np.ndarray]] = {}
        self._solver(tuple(c.name for c in constraints))
        self.cost_values = ca.Function("costs", [self.x], [c.value for c in costs] or [zero])
        self.constraint_values = ca.Function("constraints", [self.x], [self.g])

    def _differentiate(self) -> dict:
        """Exact gradient of the objective, and each constraint set's Jacobian and share of the Lagrangian's
        Hessian, piece by piece: a least-squares cost's from its matrices (its Hessian is constant), a constraint
        set written on read symbols z = S x by CasADi's differentiation in z and the chain rule (J S, S^T H S; each
        row depends on a few of the many x), any other piece by CasADi's differentiation in x; linear constraint
        sets add no Hessian. Much faster to build than differentiating the whole program at once (same values up
        to rounding)."""
        x = self.x
        size = int(x.shape[0])
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", self.g.shape[0])
        constant_hessian, offset = sp.csr_matrix((size, size)), np.zeros(size)
        gradient, hessian = ca.SX(size, 1), ca.SX(size, size)
        for cost in self.costs:
            if cost.squares is None:
                gradient = gradient + ca.gradient(cost.value, x)
                hessian = hessian + lam_f * ca.hessian(cost.value, x)[0]
            else:
                h, b = cost.hessian_and_offset(size)
                constant_hessian, offset = constant_hessian + h, offset + b
        gradient = gradient + ca.mtimes(to_dm(constant_hessian), x) - ca.DM(offset)
        hessian = hessian + lam_f * to_dm(sp.triu(constant_hessian))
        pieces: dict[str, tuple] = {}
        for c in self.constraints:
            local = c.local_form()
            lam = lam_g[self.con_slices[c.name]]
            if local is not None and not ca.depends_on(local[0], x):
                rows, z, S = local
                S_dm = to_dm(S)
                jacobian_z = ca.jacobian(rows, z)
                outputs = [jacobian_z] if c.linear else [jacobian_z, ca.hessian(ca.dot(lam, rows), z)[0]]
                values = ca.Function("piece", [z, lam], outputs)(ca.densify(ca.mtimes(S_dm, x)), lam)
                share = None if c.linear else ca.triu(ca.mtimes(S_dm.T, ca.mtimes(values[1], S_dm)))
                pieces[c.name] = (lam, ca.mtimes(values[0], S_dm), share)
                continue
            g = ca.densify(c.expression_in(x))
            share = None if c.linear else ca.triu(ca.hessian(ca.dot(lam, g), x)[0])
            pieces[c.name] = (lam, ca.jacobian(g, x), share)
        return dict(lam_f=lam_f, gradient=gradient, hessian=hessian, constraints=pieces)

    def _derivatives(self, active: tuple[str, ...] | None = None) -> dict:
        """CasADi's grad_f, jac_g and hess_lag Functions of the program with the constraint sets `active` (None:
        all), from the pieces (a program on SX symbols only)."""
        pieces, x = self._pieces, self.x
        if pieces is None:
            raise ValueError("derivatives from pieces need a program on SX symbols")
        active = tuple(c.name for c in self.constraints) if active is None else active
        no_parameters = ca.SX(0, 1)
        lam_f, hessian = pieces["lam_f"], pieces["hessian"]
        parts = [pieces["constraints"][c.name] for c in self.constraints if c.name in active]
        for _, _, share in parts:
            if share is not None:
                hessian = hessian + share
        lam_g = ca.vertcat(*[lam for lam, _, _ in parts]) if parts else ca.SX(0, 1)
        jacobian = ca.vertcat(*[jac for _, jac, _ in parts]) if parts else ca.SX(0, x.shape[0])
        g = self.g[self._rows(active).tolist()] if parts else ca.SX(0, 1)
        return {"grad_f": ca.Function("grad_f", [x, no_parameters], [self.f, pieces["gradient"]]),
                "hess_lag": ca.Function("hess_lag", [x, no_parameters, lam_f, lam_g], [ca.triu(hessian)]),
                "jac_g": ca.Function("jac_g", [x, no_parameters], [g, jacobian])}

    def prepare(self, relaxed: tuple[str, ...]) -> None:
        """Build now the IPOPT instance that `solve` uses with the constraint sets `relaxed` switched off."""
        self._solver(tuple(c.name for c in self.constraints if c.name not in relaxed))

    def _rows(self, active: tuple[str, ...]) -> np.ndarray:
        """Indices of the rows of g of the constraint sets `active`, in program order."""
        ranges = [np.arange(self.con_slices[c.name].start, self.con_slices[c.name].stop)
                  for c in self.constraints if c.name in active]
        return np.concatenate(ranges) if ranges else np.zeros(0, int)

    def _solver(self, active: tuple[str, ...]):
        """IPOPT on the program with only the constraint sets `active` (built once per such set), its iteration
        limit and the rows of g it holds."""
        if active not in self._solvers:
            rows = self._rows(active)
            g = self.g[rows.tolist()] if len(rows) else type(self.x)(0, 1)
            limit = IterationLimit(int(self.x.shape[0]), len(rows))
            # No 'nlp_grad' (the Lagrangian's gradient, by differentiating the whole program, for multipliers
            # that are never read): the larger part of nlpsol's build.
            options: dict[str, Any] = {"ipopt": dict(self.ipopt_options), "print_time": False,
                                       "error_on_fail": False, "iteration_callback": limit, "no_nlp_grad": True,
                                       "calc_lam_p": False}
            options["ipopt"].setdefault("print_level", 0)
            options["ipopt"].setdefault("sb", "yes")
            if self._pieces is not None:
                options.update(self._derivatives(active))
            solver = ca.nlpsol("trajopt", "ipopt", {"x": self.x, "f": self.f, "g": g}, options)
            self._solvers[active] = (solver, limit, rows)
        return self._solvers[active]

    @property
    def num_variables(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_constraints(self) -> int:
        return int(self.g.shape[0])

    def initial(self) -> np.ndarray:
        return np.concatenate([v.initial for v in self.variables])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.concatenate([v.lower for v in self.variables]), np.concatenate([v.upper for v in self.variables]))

    def solve(self, x0: np.ndarray, fixed: tuple[str, ...] = (), relaxed: tuple[str, ...] = (),
              lower: np.ndarray | None = None, upper: np.ndarray | None = None,
              max_iterations: int | None = None) -> Solution:
        """Solve from x0 (n,), with the variable sets named in `fixed` held at their x0 values and the
        constraint sets named in `relaxed` switched off. lower/upper override the variable bounds;
        max_iterations stops this run sooner than the solver's own limit (status Maximum_Iterations_Exceeded)."""
        lbx, ubx = self.bounds()
        if lower is not None:
            lbx = lower.copy()
        if upper is not None:
            ubx = upper.copy()
        x0 = np.clip(x0, lbx, ubx)
        for name in fixed:
            sl = self.var_slices[name]
            lbx[sl] = ubx[sl] = x0[sl]
        # A switched-off set is left out of the program IPOPT solves (not held with infinite bounds: its rows
        # would still be in every linear system).
        solver, limit, rows = self._solver(tuple(c.name for c in self.constraints if c.name not in relaxed))
        lbg, ubg = self.lbg[rows], self.ubg[rows]
        start = time.perf_counter()
        limit.limit, limit.count = max_iterations, 0
        with interrupts_noted() as interrupted:
            out = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        if interrupted:  # Ctrl-C inside IPOPT: the run stops, this solve's result is not used
            raise KeyboardInterrupt
        seconds = time.perf_counter() - start
        stats = solver.stats()
        x = np.asarray(out["x"]).ravel()
        g = np.asarray(out["g"]).ravel()
        violation = np.maximum(lbg - g, 0) + np.maximum(g - ubg, 0)
        violation = float(violation.max()) if len(violation) else 0.0
        costs = [float(c) for c in self.cost_values.call([x])] if self.costs else []
        status = str(stats.get("return_status", "unknown"))
        if (max_iterations is not None and status == "User_Requested_Stop"
                and limit.count > max_iterations):
            status = "Maximum_Iterations_Exceeded"  # stopped by max_iterations, not by the user
        return Solution(x, {v.name: x[self.var_slices[v.name]] for v in self.variables}, float(out["f"]),
                        {c.name: v for c, v in zip(self.costs, costs, strict=True)}, status,
                        status in CONVERGED_STATUSES, int(stats.get("iter_count", -1)), seconds, violation)
