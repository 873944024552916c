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
    is any expression of the program's variables, differentiated by CasADi."""

    name: str
    value: Any  # a CasADi scalar expression (SX) in the variable vector; None for a least-squares term
    squares: list | None = None

    @staticmethod
    def least_squares(name: str, squares: list) -> CostTerm:
        """sum_k w_k |M_k x - t_k|^2 from (w_k, M_k, t_k) blocks: M_k (m, n) scipy sparse, t_k (m,)."""
        return CostTerm(name, None, squares)

    def expression(self, x):
        """The term as an expression of x (SX or MX): a least-squares term's from its matrices, any other's value
        (written on x)."""
        if self.squares is None:
            return self.value
        value = type(x)(0)
        for weight, matrix, target in self.squares:
            value = value + weight * ca.sumsqr(ca.mtimes(to_dm(matrix), x) - ca.DM(target))
        return value

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
STALLED_STATUS = "Stalled_Constraint_Violation"  # stopped by IterationWatch


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


# IPOPT's constr_viol_tol unless the options set it: the largest violation an optimum may have.
IPOPT_CONSTR_VIOL_TOL = 1e-4
# Iterations without halving the constraint violation after which a watched run that is not yet feasible is
# stopped: converging runs on the validation clips went at most 37, a wandering one hundreds
# (docs/decisions/trajopt-long-clips.md, "A first try that stalls gives way").
STALL_ITERATIONS = 100


def max_violation(g: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """The most any row of g (rows,) lies outside its bounds lower <= g <= upper: 0 inside them or without rows,
    NaN where g is."""
    return max(float(np.max(lower - g, initial=0.0)), float(np.max(g - upper, initial=0.0)))


class IterationWatch(ca.Callback):
    """IPOPT's iteration callback, which stops a run after `limit` iterations (one solver serves runs with
    different limits; IPOPT's own max_iter is fixed when the solver is built) and, where asked, once it has
    stalled: its constraint violation still above `feasible` and not halved in STALL_ITERATIONS iterations."""

    def __init__(self, variables: int, constraints: int, feasible: float):
        ca.Callback.__init__(self)
        self.variables, self.constraints, self.feasible = variables, constraints, feasible
        self.g_index = ca.nlpsol_out().index("g")
        self.start(None, np.zeros(0), np.zeros(0), stop_stalled=False)
        self.construct("iteration_watch", {})

    def start(self, limit: int | None, lower: np.ndarray, upper: np.ndarray, stop_stalled: bool) -> None:
        """Before a run: its iteration limit, the bounds (rows,) of the constraints it solves, and whether a
        stall stops it."""
        self.limit, self.lower, self.upper, self.stop_stalled = limit, lower, upper, stop_stalled
        self.count = 0
        self.best, self.best_at = np.inf, 0
        self.stalled = False

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
        violation = max_violation(np.asarray(arg[self.g_index]).ravel(), self.lower, self.upper)
        if violation < 0.5 * self.best:
            self.best, self.best_at = violation, self.count
        self.stalled = (self.stop_stalled and self.best > self.feasible
                        and self.count - self.best_at > STALL_ITERATIONS)
        return [int(self.stalled or (self.limit is not None and self.count > self.limit))]


class Program:
    """The program of the given pieces, with its IPOPT solver built once. x: the variable vector the pieces are
    written on (an SX symbol), the variable sets laid out along it in order.

    What IPOPT evaluates is a small graph of matrix operations (MX) on a variable vector of its own: each
    constraint set's rows, Jacobian and Hessian are SX Functions of the few symbols it reads, called on S x and
    mapped to x by sparse products (J S, S^T H S); a least-squares cost's gradient and Hessian are its constant
    matrices. Nothing is expanded into one scalar graph of the whole program, which was most of a window's build
    (docs/decisions/trajopt-build-cost.md)."""

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
        self.lbg = np.concatenate([c.bounds()[0] for c in constraints]) if constraints else np.zeros(0)
        self.ubg = np.concatenate([c.bounds()[1] for c in constraints]) if constraints else np.zeros(0)
        self.ipopt_options = dict(ipopt_options)
        self.variable_vector = ca.MX.sym("x", int(x.shape[0]))  # what IPOPT's Functions take
        self._objective = self._objective_parts()
        self._parts = {c.name: self._constraint_part(c) for c in constraints}
        self._solvers: dict[tuple[str, ...], tuple[Any, IterationWatch, np.ndarray]] = {}
        self._solver(tuple(c.name for c in constraints))
        values = [c.expression(self.variable_vector) if c.squares is not None else self._of_x(c.value)
                  for c in costs]
        self.cost_values = ca.Function("costs", [self.variable_vector], values or [ca.MX(0)])

    def _of_x(self, expression, *more):
        """An SX expression of the pieces' x (and of SX symbols `more`, as (symbol, MX argument) pairs) as an MX
        expression of the variable vector, by one call of an SX Function (not expanded)."""
        symbols = [self.x] + [s for s, _ in more]
        arguments = [self.variable_vector] + [a for _, a in more]
        return ca.Function("piece", symbols, [ca.SX(expression)])(*arguments)

    def _objective_parts(self) -> tuple:
        """(value, gradient, Hessian without its multiplier) of the objective, MX of the variable vector: the
        least-squares terms' from their matrices (constant Hessian), any other term's by CasADi's
        differentiation in x."""
        x, X = self.x, self.variable_vector
        size = int(x.shape[0])
        constant_hessian, offset = sp.csr_matrix((size, size)), np.zeros(size)
        value, gradient, hessian = ca.MX(0), ca.MX(size, 1), ca.MX(size, size)
        for cost in self.costs:
            if cost.squares is None:
                value = value + self._of_x(cost.value)
                gradient = gradient + self._of_x(ca.gradient(ca.SX(cost.value), x))
                hessian = hessian + self._of_x(ca.hessian(ca.SX(cost.value), x)[0])
            else:
                value = value + cost.expression(X)
                h, b = cost.hessian_and_offset(size)
                constant_hessian, offset = constant_hessian + h, offset + b
        gradient = gradient + ca.mtimes(to_dm(constant_hessian), X) - ca.DM(offset)
        return value, gradient, hessian + to_dm(constant_hessian)

    def _constraint_part(self, c: ConstraintSet) -> tuple:
        """(multipliers, rows, Jacobian, Hessian of the multiplied rows or None for a linear set) of one constraint
        set, MX of the variable vector and the multipliers: a set written on read symbols z = S x differentiated
        in z and mapped by the chain rule (each row depends on a few of the many x), any other in x."""
        X = self.variable_vector
        n = c.size
        lam_mx, lam = ca.MX.sym(f"lam_{c.name}", n), ca.SX.sym("lam", n)
        local = c.local_form()
        if local is not None and not ca.depends_on(local[0], self.x):
            rows, z, S = local
            S_dm = to_dm(S)
            z_of_x = ca.densify(ca.mtimes(S_dm, X))
            values = ca.Function(f"{c.name}_rows", [z], [rows])(z_of_x)
            jacobian = ca.mtimes(ca.Function(f"{c.name}_jacobian", [z], [ca.jacobian(rows, z)])(z_of_x), S_dm)
            hessian = None
            if not c.linear:
                local_hessian = ca.Function(f"{c.name}_hessian", [z, lam], [ca.hessian(ca.dot(lam, rows), z)[0]])
                hessian = ca.mtimes(S_dm.T, ca.mtimes(local_hessian(z_of_x, lam_mx), S_dm))
            return lam_mx, values, jacobian, hessian
        rows = ca.densify(c.expression_in(self.x))
        hessian = None if c.linear else self._of_x(ca.hessian(ca.dot(lam, rows), self.x)[0], (lam, lam_mx))
        return lam_mx, self._of_x(rows), self._of_x(ca.jacobian(rows, self.x)), hessian

    def _derivatives(self, active: tuple[str, ...] | None = None) -> dict:
        """CasADi's grad_f, jac_g and hess_lag Functions of the program with the constraint sets `active` (None:
        all), and its rows g (MX of the variable vector)."""
        X = self.variable_vector
        active = tuple(c.name for c in self.constraints) if active is None else active
        no_parameters = ca.MX(0, 1)
        value, gradient, cost_hessian = self._objective
        lam_f = ca.MX.sym("lam_f")
        parts = [self._parts[c.name] for c in self.constraints if c.name in active]
        hessian = lam_f * cost_hessian
        for _, _, _, share in parts:
            if share is not None:
                hessian = hessian + share
        lam_g = ca.vertcat(*[lam for lam, _, _, _ in parts]) if parts else ca.MX(0, 1)
        g = ca.vertcat(*[rows for _, rows, _, _ in parts]) if parts else ca.MX(0, 1)
        jacobian = ca.vertcat(*[jac for _, _, jac, _ in parts]) if parts else ca.MX(0, X.shape[0])
        return {"grad_f": ca.Function("grad_f", [X, no_parameters], [value, gradient]),
                "hess_lag": ca.Function("hess_lag", [X, no_parameters, lam_f, lam_g], [ca.triu(hessian)]),
                "jac_g": ca.Function("jac_g", [X, no_parameters], [g, jacobian]), "g": g, "f": value}

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
        watch and the rows of g it holds."""
        if active not in self._solvers:
            rows = self._rows(active)
            watch = IterationWatch(int(self.x.shape[0]), len(rows),
                                   self.ipopt_options.get("constr_viol_tol", IPOPT_CONSTR_VIOL_TOL))
            derivatives = self._derivatives(active)
            g, f = derivatives.pop("g"), derivatives.pop("f")
            # No 'nlp_grad' (the Lagrangian's gradient, by differentiating the whole program, for multipliers
            # that are never read): the larger part of nlpsol's build.
            options: dict[str, Any] = {"ipopt": dict(self.ipopt_options), "print_time": False,
                                       "error_on_fail": False, "iteration_callback": watch, "no_nlp_grad": True,
                                       "calc_lam_p": False, **derivatives}
            options["ipopt"].setdefault("print_level", 0)
            options["ipopt"].setdefault("sb", "yes")
            solver = ca.nlpsol("trajopt", "ipopt", {"x": self.variable_vector, "f": f, "g": g}, options)
            self._solvers[active] = (solver, watch, rows)
        return self._solvers[active]

    @property
    def num_variables(self) -> int:
        return int(self.x.shape[0])

    @property
    def num_constraints(self) -> int:
        return len(self.lbg)

    def initial(self) -> np.ndarray:
        return np.concatenate([v.initial for v in self.variables])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (np.concatenate([v.lower for v in self.variables]), np.concatenate([v.upper for v in self.variables]))

    def solve(self, x0: np.ndarray, fixed: tuple[str, ...] = (), relaxed: tuple[str, ...] = (),
              lower: np.ndarray | None = None, upper: np.ndarray | None = None,
              max_iterations: int | None = None, stop_stalled: bool = False) -> Solution:
        """Solve from x0 (n,), with the variable sets named in `fixed` held at their x0 values and the
        constraint sets named in `relaxed` switched off. lower/upper override the variable bounds;
        max_iterations stops this run sooner than the solver's own limit (status Maximum_Iterations_Exceeded);
        with stop_stalled, so does a stall of its constraint violation (IterationWatch; status
        Stalled_Constraint_Violation)."""
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
        solver, watch, rows = self._solver(tuple(c.name for c in self.constraints if c.name not in relaxed))
        lbg, ubg = self.lbg[rows], self.ubg[rows]
        start = time.perf_counter()
        watch.start(max_iterations, lbg, ubg, stop_stalled)
        with interrupts_noted() as interrupted:
            out = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        if interrupted:  # Ctrl-C inside IPOPT: the run stops, this solve's result is not used
            raise KeyboardInterrupt
        seconds = time.perf_counter() - start
        stats = solver.stats()
        x = np.asarray(out["x"]).ravel()
        g = np.asarray(out["g"]).ravel()
        violation = max_violation(g, lbg, ubg)
        costs = [float(c) for c in self.cost_values.call([x])] if self.costs else []
        status = str(stats.get("return_status", "unknown"))
        if status == "User_Requested_Stop" and watch.stalled:
            status = STALLED_STATUS  # stopped by the watch: wandering, not converging
        elif (max_iterations is not None and status == "User_Requested_Stop"
                and watch.count > max_iterations):
            status = "Maximum_Iterations_Exceeded"  # stopped by max_iterations, not by the user
        return Solution(x, {v.name: x[self.var_slices[v.name]] for v in self.variables}, float(out["f"]),
                        {c.name: v for c, v in zip(self.costs, costs, strict=True)}, status,
                        status in CONVERGED_STATUSES, int(stats.get("iter_count", -1)), seconds, violation)
