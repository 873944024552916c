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


def to_dm(matrix: sp.spmatrix) -> ca.DM:
    """A scipy sparse matrix as a CasADi DM with the same entries (explicit zeros kept), built from its compressed
    columns: several times faster than ca.DM(matrix) on the program's sampling matrices."""
    csc = sp.csc_matrix(matrix)
    csc.sort_indices()
    return ca.DM(ca.Sparsity(csc.shape[0], csc.shape[1], csc.indptr.tolist(), csc.indices.tolist()), csc.data)


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
    def at(value_index: int, derivative_index: int) -> Node:
        """Value at x[value_index:+3], derivative at x[derivative_index:+3]."""
        return Node(value_index + np.arange(DIM), derivative_index + np.arange(DIM))

    @staticmethod
    def zero() -> Node:
        return Node(np.full(DIM, -1), np.full(DIM, -1))

    @staticmethod
    def resting(xy_index: int) -> Node:
        """(x, y, 0) from x[xy_index:+2], zero derivative: a foot in contact."""
        return Node(np.array([xy_index, xy_index + 1, -1]), np.full(DIM, -1))

    def symbols(self, x):
        def pick(idx):
            return ca.vertcat(*[x[int(i)] if i >= 0 else type(x)(0) for i in idx])

        return pick(self.value), pick(self.derivative)


@dataclass
class Segment:
    """A cubic from `first` at time `start` to `second` at time `end`. Times are floats or CasADi scalars;
    `nominal` holds their values at the input timing and `slack` how far (s) each may move from it."""

    start: Any
    end: Any
    first: Node
    second: Node
    nominal: tuple[float, float]
    slack: tuple[float, float] = (0.0, 0.0)

    @property
    def moves(self) -> bool:
        return not (_is_number(self.start) and _is_number(self.end))

    def evaluate(self, x, t: float, order: int):
        h = self.end - self.start
        w = hermite_weights((t - self.start) / h, h, order)
        (p0, v0), (p1, v1) = self.first.symbols(x), self.second.symbols(x)
        return w[0] * p0 + w[1] * v0 + w[2] * p1 + w[3] * v1


def _is_number(value) -> bool:
    return isinstance(value, (float, int, np.floating, np.integer))


class Trajectory:
    """Segments in time order, end to end, each (DIM,) valued."""

    def __init__(self, segments: list[Segment]):
        self.segments = segments
        self._starts = np.array([s.nominal[0] for s in segments])
        self._ends = np.array([s.nominal[1] for s in segments])
        # (segments, 4, DIM) indices of each segment's p0, v0, p1, v1 in x (-1: zero), read by `matrix`.
        self._nodes = np.array([[s.first.value, s.first.derivative, s.second.value, s.second.derivative]
                                for s in segments]).reshape(len(segments), 4, DIM)
        self.symbolic_times = any(s.moves for s in segments)

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
        t0 z, t1 x, ...), at the nominal timing."""
        times = np.asarray(times, float)
        seg = self.segment_at(times)
        t0 = self._starts[seg]
        h = self._ends[seg] - t0
        weights = hermite_weights((times - t0) / h, h, order)
        rows, cols, vals = [], [], []
        r = DIM * np.arange(len(times))[:, None] + np.arange(DIM)
        for k, w in enumerate(weights):
            idx = self._nodes[seg, k]  # (n, DIM)
            keep = idx >= 0
            rows.append(r[keep])
            cols.append(idx[keep])
            vals.append(np.broadcast_to(np.asarray(w, float)[:, None], idx.shape)[keep])
        # Without the weights that are exactly zero (a sample on a node reads only that node's value): a
        # derivative built from the matrix then has no structural entries an expression graph would not have.
        matrix = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(DIM * len(times), size))
        matrix.eliminate_zeros()
        return matrix

    def knot_jumps(self, order: int, size: int) -> sp.csr_matrix:
        """(DIM * (segments - 1), size) sparse map from x to the jump of the `order`-th derivative at every inner
        node (left limit minus right limit); fixed times only. Zero jumps of the second derivative make the
        trajectory C2."""
        rows, cols, vals = [], [], []
        pairs = (("first", "value"), ("first", "derivative"), ("second", "value"), ("second", "derivative"))
        for j in range(1, len(self.segments)):
            for seg, s, sign in ((self.segments[j - 1], 1.0, 1.0), (self.segments[j], 0.0, -1.0)):
                h = seg.nominal[1] - seg.nominal[0]
                for w, (node_attr, field_name) in zip(hermite_weights(s, h, order), pairs, strict=True):
                    idx = getattr(getattr(seg, node_attr), field_name)
                    keep = idx >= 0
                    rows.append(DIM * (j - 1) + np.arange(DIM)[keep])
                    cols.append(idx[keep])
                    vals.append(np.full(keep.sum(), sign * w))
        if not rows:
            return sp.csr_matrix((0, size))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(DIM * (len(self.segments) - 1), size))

    def candidates(self, t: float) -> list[int]:
        """Segments that may hold time t when their ends move within their slack."""
        return [k for k, s in enumerate(self.segments)
                if s.nominal[0] - s.slack[0] - 1e-9 <= t <= s.nominal[1] + s.slack[1] + 1e-9]

    def sample(self, x, times: np.ndarray | list[float], order: int = 0):
        """(DIM, n) samples at `times` (n,) of the value or a time derivative. Samples that only fixed segments
        can hold are one sparse product with x; the others are built per group of samples with the same
        candidate segments, the segment holding each sample chosen in the expression graph."""
        times = np.asarray(times, float)
        M = self.matrix(times, order, int(x.shape[0]))
        fixed = ca.reshape(ca.mtimes(to_dm(M), x), DIM, len(times))
        if not self.symbolic_times:
            return fixed
        groups: dict[tuple[int, ...], list[int]] = {}
        for k, t in enumerate(times):
            cands = tuple(self.candidates(t))
            if len(cands) == 1 and not self.segments[cands[0]].moves:
                continue
            groups.setdefault(cands, []).append(k)
        if not groups:
            return fixed
        columns = [fixed[:, k] for k in range(len(times))]
        for cands, ks in groups.items():
            values = self._evaluate_moving(x, times[ks], cands, order)
            for j, k in enumerate(ks):
                columns[k] = values[:, j]
        return ca.horzcat(*columns)

    def _evaluate_moving(self, x, times: np.ndarray, cands: tuple[int, ...], order: int):
        """(DIM, n) values at `times` held by one of the consecutive segments `cands`: the last one started."""
        t = ca.DM(times).T  # (1, n)
        ones = ca.DM.ones(DIM, 1)
        out = self._segment_rows(x, self.segments[cands[0]], t, order)
        for k in cands[1:]:
            seg = self.segments[k]
            started = t >= seg.start  # (1, n) 0/1
            value = self._segment_rows(x, seg, t, order)
            out = out + ca.mtimes(ones, started) * (value - out)
        return out

    @staticmethod
    def _segment_rows(x, seg: Segment, t, order: int):
        """(DIM, n) one segment's cubic at times t (1, n), extrapolated beyond its ends."""
        h = seg.end - seg.start
        w = hermite_weights((t - seg.start) / h, h, order)
        (p0, v0), (p1, v1) = seg.first.symbols(x), seg.second.symbols(x)
        return p0 @ w[0] + v0 @ w[1] + p1 @ w[2] + v1 @ w[3]
