"""Dense QPs solved by daqp's C entry point (daqp_quadprog) on preallocated buffers.

`daqp.solve` wraps the same function but costs about as much again as the solver itself on the tracker's small
problems (typed views of every argument, fresh result arrays, an info dictionary); the tracker solves two or three
QPs per integration step. The structures below are daqp 0.11's (DAQPProblem, DAQPSettings, DAQPResult, as its
debug information gives them), and the settings are `daqp.solve`'s own defaults, read from its signature, so a
solve here returns what `daqp.solve` returns for the same data bit for bit (tests/test_physcap.py checks it).
"""

from __future__ import annotations

import ctypes
import inspect

import daqp
import numpy as np

_double, _int, _pointer = ctypes.c_double, ctypes.c_int, ctypes.c_void_p


class _Problem(ctypes.Structure):
    _fields_ = [("n", _int), ("m", _int), ("ms", _int), ("H", _pointer), ("f", _pointer), ("A", _pointer),
                ("bupper", _pointer), ("blower", _pointer), ("sense", _pointer), ("break_points", _pointer),
                ("nh", _int), ("problem_type", _int)]


class _Settings(ctypes.Structure):
    _fields_ = ([(name, _double) for name in ("primal_tol", "dual_tol", "zero_tol", "pivot_tol", "progress_tol")]
                + [("cycle_tol", _int), ("iter_limit", _int)]
                + [(name, _double) for name in ("fval_bound", "eps_prox", "eta_prox", "rho_soft", "rel_subopt",
                                                "abs_subopt", "sing_tol", "refactor_tol", "time_limit", "w_soft")]
                + [("eq_reduction", _int), ("presolve", _int)])


class _Result(ctypes.Structure):
    _fields_ = [("x", _pointer), ("lam", _pointer), ("fval", _double), ("soft_slack", _double), ("exitflag", _int),
                ("iter", _int), ("nodes", _int), ("solve_time", _double), ("setup_time", _double)]


_quadprog = ctypes.CDLL(daqp.__file__).daqp_quadprog
_quadprog.argtypes = (_pointer, _pointer, _pointer)
_quadprog.restype = None
_SOLVE_DEFAULTS = inspect.signature(daqp.solve).parameters
_SETTINGS = _Settings(**{name: _SOLVE_DEFAULTS[name].default for name, _ in _Settings._fields_})


def _address(array: np.ndarray) -> int:
    return array.ctypes.data


class DenseQP:
    """min 1/2 x'Hx + f'x subject to lower <= A x <= upper, for n variables and at most max_rows rows of A. The
    caller writes H (n, n), f (n,), A[:m], upper[:m] and lower[:m] (C-contiguous buffers at fixed addresses, read
    by daqp without being changed) and calls solve(m)."""

    def __init__(self, n: int, max_rows: int):
        self.H, self.f = np.zeros((n, n)), np.zeros(n)
        self.A = np.zeros((max_rows, n))
        self.upper, self.lower = np.zeros(max_rows), np.zeros(max_rows)
        self._sense = np.zeros(max_rows, dtype=np.intc)  # every row an inequality, as daqp.solve's default
        self._x, self._multipliers = np.zeros(n), np.zeros(max(max_rows, 1))
        self._problem = _Problem(n, 0, 0, _address(self.H), _address(self.f))
        self._result = _Result(_address(self._x), None)
        self._pointers = (_address(self.A), _address(self.upper), _address(self.lower), _address(self._sense))
        self._call = (ctypes.addressof(self._result), ctypes.addressof(self._problem), ctypes.addressof(_SETTINGS))
        self._rows = -1

    def solve(self, rows: int) -> tuple[np.ndarray, int]:
        """(x (n,), a new array; daqp's exit flag, 1: solved) with the first `rows` rows of A."""
        if rows != self._rows:  # daqp.solve passes no constraint arrays when there are no rows
            problem, self._rows = self._problem, rows
            problem.m = rows
            problem.A, problem.bupper, problem.blower, problem.sense = self._pointers if rows else (None,) * 4
            self._result.lam = _address(self._multipliers) if rows else None
        _quadprog(*self._call)
        return self._x.copy(), self._result.exitflag
