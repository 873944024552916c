"""Piecewise cubic Hermite trajectories (Rempe et al. 2020 C.1, after Winkler et al. 2018): a trajectory is a
chain of segments, each a cubic fixed by the value and time derivative at its two ends (its nodes), so that
neighbouring segments sharing a node join with continuous value and velocity. The optimiser works on the node
values and derivatives (and, in the last stage, on the phase boundary times), not on polynomial coefficients.

Nodes refer to entries of the program's variable vector x by index (-1: the component is zero). With segment
times fixed, a trajectory sampled at given times is a linear map of x: a sparse matrix built with numpy, so the
whole sampling is one CasADi product. With times that are expressions (phase durations optimised), samples
are built one by one and the segment holding each time is chosen in the expression graph among those that may
hold it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp

DIM = 3


def hermite_weights(s, h, order: int) -> tuple:
    """Weights of (p0, v0, p1, v1) giving the value (order 0), first (1) or second (2) time derivative at
    normalised time s in [0, 1] of a cubic segment of duration h seconds. Floats, arrays or CasADi expressions."""
    if order == 0:
        return (2 * s**3 - 3 * s**2 + 1, h * (s**3 - 2 * s**2 + s), -2 * s**3 + 3 * s**2, h * (s**3 - s**2))
    if order == 1:
        return ((6 * s**2 - 6 * s) / h, 3 * s**2 - 4 * s + 1, (-6 * s**2 + 6 * s) / h, 3 * s**2 - 2 * s)
    if order == 2:
        return ((12 * s - 6) / h**2, (6 * s - 4) / h, (-12 * s + 6) / h**2, (6 * s - 2) / h)
    raise ValueError(f"order must be 0, 1 or 2, got {order}")


@dataclass(frozen=True)
class Node:
    """Where a node's value and time derivative live in x: (3,) indices each, -1 for a zero component."""

    value: np.ndarray
    derivative: np.ndarray

    @staticmethod
    def at(value_index: int, derivative_index: int) -> "Node":
        """Value at x[value_index:+3], derivative at x[derivative_index:+3]."""
        return Node(value_index + np.arange(DIM), derivative_index + np.arange(DIM))

    @staticmethod
    def zero() -> "Node":
        return Node(np.full(DIM, -1), np.full(DIM, -1))

    @staticmethod
    def resting(xy_index: int) -> "Node":
        """(x, y, 0) from x[xy_index:+2], zero derivative: a foot in contact."""
        return Node(np.array([xy_index, xy_index + 1, -1]), np.full(DIM, -1))

    def symbols(self, x):
        def pick(idx):
            return ca.vertcat(*[x[int(i)] if i >= 0 else type(x)(0) for i in idx])

        return pick(self.value), pick(self.derivative)


@dataclass
class Segment:
    """A cubic from `first` at time `start` to `second` at time `end`. Times are floats or CasADi scalars;
    `nominal` holds their values at the input timing and `slack` how far (s) they may move from it."""

    start: Any
    end: Any
    first: Node
    second: Node
    nominal: tuple[float, float]
    slack: float = 0.0

    def evaluate(self, x: ca.SX, t: float, order: int) -> ca.SX:
        h = self.end - self.start
        w = hermite_weights((t - self.start) / h, h, order)
        (p0, v0), (p1, v1) = self.first.symbols(x), self.second.symbols(x)
        return w[0] * p0 + w[1] * v0 + w[2] * p1 + w[3] * v1


class Trajectory:
    """Segments in time order, end to end, each (DIM,) valued."""

    def __init__(self, segments: list[Segment]):
        self.segments = segments
        self._starts = np.array([s.nominal[0] for s in segments])
        self.symbolic_times = any(not isinstance(s.start, (float, int, np.floating)) or
                                  not isinstance(s.end, (float, int, np.floating)) for s in segments)

    @property
    def start(self) -> float:
        return self.segments[0].nominal[0]

    @property
    def end(self) -> float:
        return self.segments[-1].nominal[1]

    def segment_at(self, times: np.ndarray) -> np.ndarray:
        """Index of the segment holding each time at the nominal timing; a time on a node belongs to the later
        segment (the very end to the last)."""
        idx = np.searchsorted(self._starts, np.asarray(times) + 1e-12, side="right") - 1
        return np.clip(idx, 0, len(self.segments) - 1)

    def matrix(self, times: np.ndarray, order: int, size: int) -> sp.csr_matrix:
        """(DIM * n, size) sparse map from x to the samples at `times` (n,), rows ordered time-major (t0 x, t0 y,
        t0 z, t1 x, ...). Fixed times only."""
        times = np.asarray(times, float)
        seg = self.segment_at(times)
        t0 = np.array([self.segments[k].nominal[0] for k in seg])
        t1 = np.array([self.segments[k].nominal[1] for k in seg])
        h = t1 - t0
        weights = hermite_weights((times - t0) / h, h, order)
        rows, cols, vals = [], [], []
        for part, (w, pick) in enumerate(zip(weights, ("first.value", "first.derivative", "second.value",
                                                          "second.derivative"))):
            node_attr, field_name = pick.split(".")
            idx = np.stack([getattr(getattr(self.segments[k], node_attr), field_name) for k in seg])  # (n, DIM)
            r = DIM * np.arange(len(times))[:, None] + np.arange(DIM)
            keep = idx >= 0
            rows.append(r[keep])
            cols.append(idx[keep])
            vals.append(np.broadcast_to(np.asarray(w, float)[:, None], idx.shape)[keep])
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(DIM * len(times), size))

    def sample(self, x: ca.SX, times: np.ndarray, order: int = 0) -> ca.SX:
        """(DIM, n) samples at `times` (n,) of the value or a time derivative."""
        times = np.asarray(times, float)
        if not self.symbolic_times:
            M = self.matrix(times, order, int(x.shape[0]))
            return ca.reshape(ca.mtimes(ca.DM(M), x), DIM, len(times))
        return ca.horzcat(*[self._evaluate_moving(x, float(t), order) for t in times])

    def _evaluate_moving(self, x: ca.SX, t: float, order: int) -> ca.SX:
        candidates = [k for k, s in enumerate(self.segments)
                      if s.nominal[0] - s.slack - 1e-9 <= t <= s.nominal[1] + s.slack + 1e-9]
        if len(candidates) == 1:
            return self.segments[candidates[0]].evaluate(x, t, order)
        out = type(x).zeros(DIM, 1)
        last = len(self.segments) - 1
        for k in candidates:
            seg = self.segments[k]
            inside = (t >= seg.start) if k > 0 else True
            if k < last:
                inside = ca.logic_and(inside, t < seg.end) if not isinstance(inside, bool) else (t < seg.end)
            if isinstance(inside, (bool, np.bool_)):  # both ends fixed: decided here
                if inside:
                    out = out + seg.evaluate(x, t, order)
            else:
                out = out + ca.if_else(inside, seg.evaluate(x, t, order), type(x).zeros(DIM, 1))
        return out
