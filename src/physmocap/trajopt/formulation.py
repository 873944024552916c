"""The centroidal trajectory optimisation of Rempe et al. 2020 (section 3.1, figure 3, appendix C) for one window
of frames, as named pieces (chosen by name in TrajoptSettings, as ifopt/TOWR assemble theirs):

variable sets
  com                 COM position and Z-Y-X Euler orientation: Hermite nodes (value, rate) every com_interval
                      (0.05 s; the paper 0.1 s), on multiples of it in seconds (the clock)
  foot_<point>        per heel/toe: one (x, y) per contact phase (z = 0: on the floor; constant: no slip), and
                      Hermite nodes through each flight (at least 6 polynomials per phase)
  force_<point>       per heel/toe, in body weights: Hermite nodes through each contact phase (at least 6
                      polynomials, none longer than the COM's); zero in flight by construction; zero where a
                      contact phase meets a flight
  durations           (last stage only) the phase boundary times, each within +-0.1 s (at most a quarter of either
                      neighbouring phase); the polynomials next to a boundary are long enough that it never
                      passes a node, so only samples near a boundary choose between two polynomials
constraint sets
  dynamics            m r'' = sum f + m g; I_w w' + w x I_w w (+ the input limbs' share, ours) = sum (p - r) x f,
                      I_w from the input's I_b(t);
                      Euler's equation every 0.1 s (the paper), Newton's twice per frame (ours, see settings)
  acceleration_continuity  COM position and orientation C2 at their nodes (ours, see there)
  velocity_boundaries COM velocity at the clip's first and last frame = mean input velocity of 1/6 s
  foot_length         |heel - toe| = foot length: once per overlap of a heel and a toe contact phase, and at the
                      kinematic samples where either flies (no row nearly repeats another)
  leg_length          |point - hip| <= leg reach, the hip placed from the COM pose with the input's offset
  force_limits        0 <= f_n <= f_max and |f_t| <= mu f_n (friction pyramid) at force nodes and frames
  above_floor         z >= 0 for feet in flight
cost terms
  data, velocity, acceleration   equations (1), (3), (4) at every frame (the feet's derivatives per 1/30 s); the
                                 smoothing terms also between frames below 30 fps (ours, smoothing_samples)
  duration                       equation (2) (last stage only)
  force_rate                     the contact forces' rates between the same samples (ours)

Everything is written on whole rows of samples (3, n): a trajectory sampled at fixed times is one sparse
product with x, so building the program costs little more than its size. World frame: Z up, floor z = 0 (the
kinematic stage moves the world there). Times in seconds, absolute (frame k at k / fps).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp

from ..body.model import CONTACT_POINTS
from ..config import TrajoptSettings
from .phases import Phase, flags_from_phases, segment_count
from .problem import ConstraintSet, CostTerm, VariableSet
from .reduced import ReducedMotion
from .splines import Node, Segment, Trajectory, to_dm

# The pieces' symbols. Scalar graphs (SX) differentiate and evaluate fastest row by row (measured: pieces written
# in MX iterate 5x slower); problem.Program joins the pieces' SX Functions with sparse products in MX.
SYMBOL = ca.SX

POINT_NAMES = tuple(name.replace("left_", "l_").replace("right_", "r_") for name in CONTACT_POINTS)
FOOT_PAIRS = ((0, 1), (2, 3))  # (heel, toe) of the left and right foot


@dataclass
class WindowStart:
    """The state a window must start in, taken from the previous window's solution at the junction time.
    com, com_rate, euler, euler_rate: (3,); feet, feet_rate: (4, 3) m, m/s (held); forces, force_rates: (4, 3)
    body weights (zero for points in flight; for information, not held)."""

    com: np.ndarray
    com_rate: np.ndarray
    euler: np.ndarray
    euler_rate: np.ndarray
    feet: np.ndarray
    feet_rate: np.ndarray
    forces: np.ndarray
    force_rates: np.ndarray


@dataclass
class Window:
    """One window's inputs: the reduced motion at its frames (absolute times), the phases of each contact point
    (covering exactly the window's time span), the velocities the clip's ends must match (None: not a clip end),
    the start state and the end state (None: free; the end state is the next window's start, when windows are
    solved two at a time) and the time after which phase boundaries stay put (the junction)."""

    reduced: ReducedMotion
    phases: list[list[Phase]]
    start_velocity: np.ndarray | None = None
    end_velocity: np.ndarray | None = None
    start: WindowStart | None = None
    freeze_after: float = np.inf
    end: WindowStart | None = None

    @property
    def t0(self) -> float:
        return float(self.reduced.times[0])

    @property
    def t1(self) -> float:
        return float(self.reduced.times[-1])


def clock_times(t0: float, t1: float, interval: float) -> np.ndarray:
    """t0, t1 and the multiples of `interval` seconds between them (times from the clip's first frame), none
    nearer than half an interval to t0 or t1: a grid fixed in seconds, so that the same motion at another frame
    rate, or a clip a frame shorter, keeps the same knots and samples (a grid spread evenly over [t0, t1] moves
    all of them when t1 moves: docs/decisions/trajopt-frame-rate.md)."""
    inner = np.arange(np.ceil(t0 / interval - 1e-9), np.floor(t1 / interval + 1e-9) + 1) * interval
    inner = inner[(inner > t0 + interval / 2) & (inner < t1 - interval / 2)]
    return np.concatenate([[t0], inner, [t1]])


def sample_times(t0: float, t1: float, interval: float, frames: np.ndarray) -> np.ndarray:
    """Constraint sample times: t0, t1 and every `interval` seconds of the clock between them (`clock_times`),
    or the frame times when interval is 0."""
    if interval <= 0:
        return np.asarray(frames, float)
    return clock_times(t0, t1, interval)


def frame_sample_times(frames: np.ndarray, interval: float) -> np.ndarray:
    """Every frame time and, between two frames, evenly spaced times at most `interval` seconds apart (frames
    only when interval is 0): samples that land on the frames whatever the frame rate, so that values read at the
    frames are held too (a grid of `interval` from the first frame misses every other frame at 24 fps)."""
    frames = np.asarray(frames, float)
    if interval <= 0 or len(frames) < 2:
        return frames
    pieces = max(1, int(np.ceil(np.max(np.diff(frames)) / interval - 1e-9)))
    steps = np.arange(pieces) / pieces
    inner = frames[:-1, None] + np.diff(frames)[:, None] * steps[None]
    return np.concatenate([inner.ravel(), frames[-1:]])


def newton_sample_times(frames: np.ndarray, interval: float) -> np.ndarray:
    """Newton's equation's sample times (s): `frame_sample_times` where frames come at most every `interval`
    seconds, and where they come faster (above 60 fps at the default) the clock's multiples of `interval`
    (`clock_times`; every other frame at 120 fps). The equation constrains the COM's and the forces' polynomials,
    whose resolution is fixed in seconds: held at every frame at 120 fps (six samples to a 0.05 s COM piece, on
    which the residual is a cubic) the rows became nearly dependent and the net force was tied to the COM's
    piecewise-linear acceleration, and IPOPT failed to converge on half of the clips
    (docs/decisions/trajopt-frame-rate.md). Between its samples the residual is what the 60 fps run has between
    its frames."""
    frames = np.asarray(frames, float)
    if interval > 0 and len(frames) > 1 and np.max(np.diff(frames)) < interval * (1 - 1e-6):
        return clock_times(frames[0], frames[-1], interval)
    return frame_sample_times(frames, interval)


def free_times(window: Window, times: np.ndarray) -> np.ndarray:
    """`times` without the window's first instant when the window continues another, and without its last when it
    must arrive in another's start: the state there is fixed, and a kinematic constraint on fixed values (sampled
    elsewhere before) could be unsatisfiable."""
    if window.start is not None:
        times = times[times > window.t0 + 1e-9]
    if window.end is not None:
        times = times[times < window.t1 - 1e-9]
    return times


def interpolate(times: np.ndarray, values: np.ndarray, t) -> np.ndarray:
    """Linear interpolation of values (T, ...) at times t (n,) -> (n, ...)."""
    flat = values.reshape(len(values), -1)
    t = np.atleast_1d(np.asarray(t, float))
    out = np.stack([np.interp(t, times, flat[:, k]) for k in range(flat.shape[1])], axis=-1)
    return out.reshape((len(t),) + values.shape[1:])


def rate(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Time derivative of values (T, ...) by finite differences."""
    if len(times) < 2:
        return np.zeros_like(values)
    return np.gradient(values, times, axis=0)


# ---- rigid-body kinematics of Z-Y-X Euler angles, on rows of samples --------------------------------------------
def rotate(e, v, inverse: bool = False):
    """R(e) v (or R(e)^T v) for Z-Y-X Euler angles e = (yaw, pitch, roll) with R = Rz Ry Rx; e and v (3, n)
    CasADi or numpy, column by column."""
    cy, sy, cp, sp, cr, sr = (ca.cos(e[0, :]), ca.sin(e[0, :]), ca.cos(e[1, :]), ca.sin(e[1, :]),
                              ca.cos(e[2, :]), ca.sin(e[2, :]))
    x, y, z = v[0, :], v[1, :], v[2, :]
    if not inverse:
        y, z = cr * y - sr * z, sr * y + cr * z  # Rx
        x, z = cp * x + sp * z, -sp * x + cp * z  # Ry
        x, y = cy * x - sy * y, sy * x + cy * y  # Rz
    else:
        x, y = cy * x + sy * y, -sy * x + cy * y  # Rz^T
        x, z = cp * x - sp * z, sp * x + cp * z  # Ry^T
        y, z = cr * y + sr * z, -sr * y + cr * z  # Rx^T
    return ca.vertcat(x, y, z)


def angular_velocity(e, de, dde):
    """World angular velocity w and acceleration w' (3, n) from Z-Y-X Euler angles and their first and second
    time derivatives (3, n): w = E(e) e', w' = E(e) e'' + E'(e, e') e'."""
    cy, sy, cp, sp = ca.cos(e[0, :]), ca.sin(e[0, :]), ca.cos(e[1, :]), ca.sin(e[1, :])
    dy, dp, dr = de[0, :], de[1, :], de[2, :]
    ddy, ddp, ddr = dde[0, :], dde[1, :], dde[2, :]
    w = ca.vertcat(-sy * dp + cy * cp * dr, cy * dp + sy * cp * dr, dy - sp * dr)
    dw = ca.vertcat(-cy * dy * dp - sy * ddp + (-sy * dy * cp - cy * sp * dp) * dr + cy * cp * ddr,
                    -sy * dy * dp + cy * ddp + (cy * dy * cp - sy * sp * dp) * dr + sy * cp * ddr,
                    ddy - cp * dp * dr - sp * ddr)
    return w, dw


def cross(a, b):
    """Column-wise cross product of (3, n) rows."""
    return ca.vertcat(a[1, :] * b[2, :] - a[2, :] * b[1, :], a[2, :] * b[0, :] - a[0, :] * b[2, :],
                      a[0, :] * b[1, :] - a[1, :] * b[0, :])


def apply_inertia(inertia: np.ndarray, v):
    """I v column by column: inertia (n, 3, 3) numbers, v (3, n)."""
    rows = []
    for i in range(3):
        rows.append(sum(ca.DM(inertia[:, i, j]).T * v[j, :] for j in range(3)))
    return ca.vertcat(*rows)


def euler_torque(e, de, dde, inertia: np.ndarray):
    """I_w w' + w x I_w w in the world frame (3, n), with I_w = R I_b R^T and I_b (n, 3, 3) per sample,
    evaluated in the body frame."""
    w, dw = angular_velocity(e, de, dde)
    wb, dwb = rotate(e, w, inverse=True), rotate(e, dw, inverse=True)
    return rotate(e, apply_inertia(inertia, dwb) + cross(wb, apply_inertia(inertia, wb)))


# ---- variable sets -----------------------------------------------------------------------------------------
class ComVariables:
    """COM position and orientation: Hermite nodes (value and rate of both) at the window's ends and every
    `interval` seconds of the clock between them (`clock_times`); 12 numbers per node. Initialised from the input."""

    def __init__(self, window: Window, interval: float, offset: int):
        red = window.reduced
        self.node_times = t = clock_times(window.t0, window.t1, interval)
        n = len(t) - 1
        self.set = VariableSet.create("com", 12 * (n + 1))
        pos = interpolate(red.times, red.com, t)
        vel = interpolate(red.times, rate(red.times, red.com), t)
        ang = interpolate(red.times, red.euler, t)
        ang_rate = interpolate(red.times, rate(red.times, red.euler), t)
        self.set.initial = np.concatenate([pos, vel, ang, ang_rate], axis=1).ravel()
        for state, at in ((window.start, slice(0, 12)), (window.end, slice(12 * n, 12 * (n + 1)))):
            if state is not None:  # continue from the previous window, or arrive in the next one's start
                fixed = np.concatenate([state.com, state.com_rate, state.euler, state.euler_rate])
                self.set.lower[at] = self.set.upper[at] = self.set.initial[at] = fixed
        base = offset + 12 * np.arange(n + 1)
        self.position = self._trajectory(base, 0)
        self.orientation = self._trajectory(base, 6)

    def _trajectory(self, base: np.ndarray, row: int) -> Trajectory:
        nodes = [Node.at(b + row, b + row + 3) for b in base]
        t = self.node_times
        return Trajectory([Segment(float(t[j]), float(t[j + 1]), nodes[j], nodes[j + 1], (t[j], t[j + 1]))
                           for j in range(len(t) - 1)])


def boundary_moves(phases: list[Phase], settings: TrajoptSettings, freeze_after: float = np.inf) -> np.ndarray:
    """(len(phases) + 1,) how far (s) each phase boundary of one contact point may move in the duration stage:
    max_duration_change, at most a quarter of either neighbouring phase (so no phase shrinks below half its
    length), zero for the window's ends, for boundaries near or after the junction `freeze_after`, and for all
    when durations are not optimised."""
    moves = np.zeros(len(phases) + 1)
    if not settings.optimize_durations or settings.max_duration_change <= 0:
        return moves
    for j in range(1, len(phases)):
        b = phases[j].start
        if b >= freeze_after - settings.max_duration_change:
            continue
        moves[j] = min(settings.max_duration_change, 0.25 * phases[j - 1].duration, 0.25 * phases[j].duration)
    return moves


def phase_layout(start: float, end: float, m: int, move_start: float, move_end: float) -> np.ndarray:
    """(m + 1,) node times of a phase cut into m polynomials: evenly, except that the first and last polynomials
    are at least 1.5 times as long as their boundary may move, so a moving boundary never passes a node."""
    d = end - start
    if m == 1:
        return np.array([start, end])
    first = max(d / m, 1.5 * move_start)
    last = max(d / m, 1.5 * move_end)
    if m == 2:
        return np.array([start, start + 0.5 * d if first + last > d else start + first, end])
    inner = np.linspace(start + first, end - last, m - 1)
    return np.concatenate([[start], inner, [end]])


class Schedule:
    """The phases of one contact point and their boundary times: floats at the input timing, or expressions of
    the `durations` variables; `moves` (len(phases) + 1,) how far each boundary may move (zero: fixed).
    boundaries[j] is the start of phase j; boundaries[-1] the window's end."""

    def __init__(self, phases: list[Phase], moves: np.ndarray, boundaries: list | None = None):
        self.phases = phases
        self.moves = moves
        self.nominal = [p.start for p in phases] + [phases[-1].end]
        self.boundaries = list(self.nominal) if boundaries is None else boundaries

    def nodes(self, j: int, m: int) -> np.ndarray:
        """Nominal node times (m + 1,) of phase j cut into m polynomials."""
        return phase_layout(self.nominal[j], self.nominal[j + 1], m, self.moves[j], self.moves[j + 1])

    def segment(self, j: int, k: int, m: int, first: Node, second: Node) -> Segment:
        """Segment k of the m of phase j: its ends are the phase boundaries (which may move) or fixed nodes."""
        nominal = self.nodes(j, m)
        start = self.boundaries[j] if k == 0 else float(nominal[k])
        end = self.boundaries[j + 1] if k + 1 == m else float(nominal[k + 1])
        slack = (self.moves[j] if k == 0 else 0.0, self.moves[j + 1] if k + 1 == m else 0.0)
        return Segment(start, end, first, second, (float(nominal[k]), float(nominal[k + 1])), slack)


class _Packer:
    """Collects a variable set's entries: initial values and bounds, handing out indices."""

    def __init__(self, offset: int):
        self.offset = offset
        self.initial: list[np.ndarray] = []
        self.lower: list[np.ndarray] = []
        self.upper: list[np.ndarray] = []

    def take(self, values, lower, upper) -> int:
        index = self.offset + sum(len(v) for v in self.initial)
        self.initial.append(np.asarray(values, float))
        self.lower.append(np.broadcast_to(np.asarray(lower, float), (len(self.initial[-1]),)))
        self.upper.append(np.broadcast_to(np.asarray(upper, float), (len(self.initial[-1]),)))
        return index

    def variable_set(self, name: str) -> VariableSet:
        size = sum(len(v) for v in self.initial)
        out = VariableSet.create(name, size)
        if size:
            out.initial = np.concatenate(self.initial)
            out.lower, out.upper = np.concatenate(self.lower).copy(), np.concatenate(self.upper).copy()
        return out


class FootVariables:
    """One heel or toe: a constant (x, y, 0) per contact phase (no slip, on the floor), Hermite nodes through
    each flight phase (z >= 0 at the nodes) with zero velocity where it meets a contact; the nodes at the
    window's ends are free unless the window continues a previous one."""

    def __init__(self, index: int, window: Window, schedule: Schedule, settings: TrajoptSettings, offset: int):
        red, phases = window.reduced, schedule.phases
        frame_step = (window.t1 - window.t0) / max(1, red.num_frames - 1)
        feet = red.feet[:, index]
        feet_rate = rate(red.times, feet)
        pack = _Packer(offset)
        contact_at: dict[int, int] = {}
        for j, p in enumerate(phases):
            if p.contact:
                inside = (red.times >= p.start - 1e-9) & (red.times <= p.end + 1e-9)
                xy = np.median(feet[inside, :2], axis=0) if inside.any() else interpolate(red.times, feet,
                                                                                          p.start)[0, :2]
                contact_at[j] = pack.take(xy, -np.inf, np.inf)
        flight_nodes: dict[tuple[int, int], int] = {}
        self.segment_counts = []
        for j, p in enumerate(phases):
            # No flight polynomial shorter than a frame: the costs read the feet at the frames only, so the
            # nodes of shorter ones were free in directions nothing sees (a null space of the whole program).
            m = 1 if p.contact else segment_count(p.duration, settings.segments_per_phase,
                                                  settings.segment_phase_seconds, shortest=frame_step)
            self.segment_counts.append(m)
            if p.contact:
                continue
            times = schedule.nodes(j, m)
            for k in range(m + 1):
                if (k == 0 and j > 0) or (k == m and j < len(phases) - 1):
                    continue  # shared with the neighbouring contact phase
                pos = interpolate(red.times, feet, times[k])[0]
                vel = interpolate(red.times, feet_rate, times[k])[0]
                pos[2] = max(pos[2], 0.0)
                flight_nodes[(j, k)] = pack.take(np.concatenate([pos, vel]), [-np.inf, -np.inf, 0.0] + [-np.inf] * 3,
                                                 np.inf)
        self.set = pack.variable_set(f"foot_{POINT_NAMES[index]}")
        self._fix_ends(index, window, phases, contact_at, flight_nodes, offset)
        contact_nodes = {j: Node.resting(a) for j, a in contact_at.items()}
        segments = []
        for j, p in enumerate(phases):
            m = self.segment_counts[j]
            if p.contact:
                segments.append(schedule.segment(j, 0, 1, contact_nodes[j], contact_nodes[j]))
                continue
            nodes = []
            for k in range(m + 1):
                if (j, k) in flight_nodes:
                    a = flight_nodes[(j, k)]
                    nodes.append(Node.at(a, a + 3))
                else:
                    nodes.append(contact_nodes[j - 1] if k == 0 else contact_nodes[j + 1])
            segments += [schedule.segment(j, k, m, nodes[k], nodes[k + 1]) for k in range(m)]
        self.trajectory = Trajectory(segments)

    def _fix_ends(self, index: int, window: Window, phases: list[Phase], contact_at: dict[int, int],
                  flight_nodes: dict[tuple[int, int], int], offset: int) -> None:
        """Holds the point's first node at the previous window's state and its last at the next one's start,
        where the window continues or arrives in a neighbour (contact_at, flight_nodes: program indices)."""
        if window.start is not None:  # continue from the previous window
            s = window.start
            if phases[0].contact:
                self._fix(contact_at[0] - offset, s.feet[index, :2])
            else:
                self._fix(flight_nodes[(0, 0)] - offset, np.concatenate([s.feet[index], s.feet_rate[index]]))
        last = len(phases) - 1
        if window.end is not None:  # arrive where the next window starts
            s = window.end
            if not phases[last].contact:
                self._fix(flight_nodes[(last, self.segment_counts[last])] - offset,
                          np.concatenate([s.feet[index], s.feet_rate[index]]))
            elif last > 0 or window.start is None:
                # A contact held through the whole window keeps the previous window's place: the next window's
                # fit of the same planted point differs by millimetres, a step at the junction.
                self._fix(contact_at[last] - offset, s.feet[index, :2])

    def _fix(self, local: int, values: np.ndarray) -> None:
        sl = slice(local, local + len(values))
        self.set.lower[sl] = self.set.upper[sl] = self.set.initial[sl] = values


class ForceVariables:
    """One heel's or toe's contact force in body weights: Hermite nodes (value, rate) through each contact phase;
    zero in flight. A contact phase's ends that meet a flight phase are held at zero force (the force fades in
    at touch-down and out at lift-off, which keeps it continuous when phase durations move). Normal force within
    [0, f_max] and tangential within mu f_max at the nodes by bounds."""

    def __init__(self, index: int, window: Window, schedule: Schedule, settings: TrajoptSettings,
                 support: np.ndarray, offset: int):
        phases = schedule.phases
        fmax = settings.max_force / (window.reduced.mass * settings.gravity)
        tangential = settings.friction * fmax
        pack = _Packer(offset)
        self.segment_counts, self.node_times, self.value_index = [], [], []
        segments = []
        zero = Node.zero()
        for j, p in enumerate(phases):
            if not p.contact:
                self.segment_counts.append(1)
                segments.append(schedule.segment(j, 0, 1, zero, zero))
                continue
            # No force polynomial longer than the COM's: with Newton's equation at every frame the net force
            # must follow the COM's piecewise-linear acceleration, which 6 cubics over a long stance cannot
            # (measured: IPOPT reports the take-off of a 1.4 s stance infeasible).
            m = segment_count(p.duration, settings.segments_per_phase, settings.segment_phase_seconds,
                              settings.com_interval)
            self.segment_counts.append(m)
            times = np.linspace(p.start, p.end, m + 1)
            share = np.interp(times, window.reduced.times, support)
            nodes = []
            for k in range(m + 1):
                meets_flight = (k == 0 and j > 0) or (k == m and j < len(phases) - 1)
                limit = 0.0 if meets_flight else 1.0
                a = pack.take([0.0, 0.0, share[k] * limit, 0.0, 0.0, 0.0],
                              [-tangential * limit, -tangential * limit, 0.0] + [-np.inf] * 3,
                              [tangential * limit, tangential * limit, fmax * limit] + [np.inf] * 3)
                nodes.append(Node.at(a, a + 3))
                self.node_times.append(float(times[k]))
                self.value_index.append(a)
            segments += [schedule.segment(j, k, m, nodes[k], nodes[k + 1]) for k in range(m)]
        self.set = pack.variable_set(f"force_{POINT_NAMES[index]}")
        # A window that continues another starts from its state (COM, orientation, contact points) but not from
        # its forces: forces may change at once, and holding them too made IPOPT report windows that start
        # mid-push infeasible (the previous window's leg reach held only at its own samples).
        self.trajectory = Trajectory(segments)
        self.any_contact = bool(self.value_index)


class DurationVariables:
    """The phase boundaries that may move (Rempe's contact durations T_ij, as the times between them: the
    durations then add up to the window by construction), each within +-moves of its input time."""

    def __init__(self, moves: list[np.ndarray], phases: list[list[Phase]]):
        self.index: list[list[int | None]] = []
        nominal: list[float] = []
        lower: list[float] = []
        upper: list[float] = []
        for point_phases, point_moves in zip(phases, moves, strict=True):
            row: list[int | None] = []
            for j, p in enumerate(point_phases[1:], start=1):
                if point_moves[j] <= 0:
                    row.append(None)
                    continue
                row.append(len(nominal))
                nominal.append(p.start)
                lower.append(p.start - point_moves[j])
                upper.append(p.start + point_moves[j])
            self.index.append(row)
        self.set = VariableSet.create("durations", len(nominal))
        self.set.initial, self.set.lower, self.set.upper = (np.array(nominal, float), np.array(lower, float),
                                                            np.array(upper, float))
        self.offset = 0

    def boundaries(self, point: int, phases: list[Phase], x=None) -> list:
        """Phase boundary times of one point: floats, or entries of x (the program's variables)."""
        out = [phases[0].start]
        for p, k in zip(phases[1:], self.index[point], strict=True):
            out.append(p.start if k is None or x is None else x[self.offset + k])
        return out + [phases[-1].end]


# ---- the problem of one window ---------------------------------------------------------------------------------
@dataclass
class WindowProblem:
    """Every piece of one window's program: the variable vector x, variable sets, trajectories, constraint sets
    and cost terms by name."""

    window: Window
    settings: TrajoptSettings
    x: ca.SX
    com: ComVariables
    feet: list[FootVariables]
    forces: list[ForceVariables]
    durations: DurationVariables | None
    constraints: dict[str, ConstraintSet] = field(default_factory=dict)
    costs: dict[str, CostTerm] = field(default_factory=dict)

    @property
    def variable_sets(self) -> list[VariableSet]:
        sets = [self.com.set] + [f.set for f in self.feet] + [f.set for f in self.forces]
        return sets + ([self.durations.set] if self.durations is not None else [])

    @property
    def force_set_names(self) -> tuple[str, ...]:
        return tuple(f.set.name for f in self.forces)

    def sample(self, trajectory: Trajectory, times: np.ndarray | list[float], order: int = 0) -> ca.SX:
        return trajectory.sample(self.x, times, order)

    def values(self, trajectory: Trajectory, times: np.ndarray | list[float], x: np.ndarray,
               order: int = 0) -> np.ndarray:
        """(3, n) numbers: `sample` at the solution x (n,), by the sampling matrix where the times are fixed."""
        times = np.asarray(times, float)
        if not trajectory.symbolic_times:
            return (trajectory.matrix(times, order, len(x)) @ x).reshape(len(times), 3).T
        return np.asarray(ca.Function("values", [self.x], [self.sample(trajectory, times, order)])(x))

    def read(self, out: ConstraintSet, trajectory: Trajectory, times: np.ndarray | list[float], order: int = 0):
        """(3, n) samples like `sample`, for the rows of `out`: symbols read by `out` (the program differentiates
        the rows in them) where the trajectory's times are fixed, else expressions of x."""
        if trajectory.symbolic_times:
            return self.sample(trajectory, times, order)
        times = np.asarray(times, float)
        return ca.reshape(out.read(trajectory.matrix(times, order, int(self.x.shape[0])), self.x), 3, len(times))

    def select(self, starts: np.ndarray) -> ca.SX:
        """(3, k) the entries x[a:a + 3] for each a in starts (k,), by one sparse product."""
        rows = np.arange(3 * len(starts))
        cols = (np.asarray(starts)[:, None] + np.arange(3)).ravel()
        M = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(rows), int(self.x.shape[0])))
        return ca.reshape(ca.mtimes(to_dm(M), self.x), 3, len(starts))

    def contacts(self) -> np.ndarray:
        """(n, 4) contact flags of the window's frames under the input timing."""
        return np.stack([flags_from_phases(p, self.window.reduced.times) for p in self.window.phases], axis=1)


def support_shares(contacts: np.ndarray) -> np.ndarray:
    """(T, 4) initial normal force of each point in body weights: the weight shared among the points in contact."""
    n = contacts.sum(axis=1, keepdims=True)
    return np.where(contacts, 1.0 / np.maximum(n, 1), 0.0)


def build_window_problem(window: Window, settings: TrajoptSettings, durations: bool = False) -> WindowProblem:
    """All variable sets, constraint sets and cost terms of one window; with `durations`, the phase boundaries
    that may move are variables too (the last stage of the staged solve). Both programs share the layout of
    every other variable, so a solution of one starts the other."""
    red = window.reduced
    contacts = np.stack([flags_from_phases(p, red.times) for p in window.phases], axis=1)
    shares = support_shares(contacts)
    moves = [boundary_moves(p, settings, window.freeze_after) for p in window.phases]
    fixed = [Schedule(p, m) for p, m in zip(window.phases, moves, strict=True)]
    com = ComVariables(window, settings.com_interval, 0)
    offset = com.set.size
    feet, forces = [], []
    for i in range(4):
        feet.append(FootVariables(i, window, fixed[i], settings, offset))
        offset += feet[-1].set.size
    for i in range(4):
        forces.append(ForceVariables(i, window, fixed[i], settings, shares[:, i], offset))
        offset += forces[-1].set.size
    duration_vars = None
    if durations:
        duration_vars = DurationVariables(moves, window.phases)
        duration_vars.offset = offset
        offset += duration_vars.set.size
    x = SYMBOL.sym("x", offset)
    problem = WindowProblem(window, settings, x, com, feet, forces, duration_vars)
    start = 0
    for v in problem.variable_sets:
        v.symbols = x[start:start + v.size]
        start += v.size
    if duration_vars is not None:  # the same variables; the trajectories re-timed by the boundary variables
        for i in range(4):
            moving = Schedule(window.phases[i], moves[i], duration_vars.boundaries(i, window.phases[i], x))
            feet[i].trajectory = FootVariables(i, window, moving, settings,
                                               _offset_of(problem, feet[i].set)).trajectory
            forces[i].trajectory = ForceVariables(i, window, moving, settings, shares[:, i],
                                                  _offset_of(problem, forces[i].set)).trajectory
    for name in settings.constraints:
        problem.constraints[name] = CONSTRAINTS[name](problem)
    for name in settings.costs:
        if name == "duration" and not durations:
            continue
        problem.costs[name] = COSTS[name](problem)
    return problem


def _offset_of(problem: WindowProblem, target: VariableSet) -> int:
    start = 0
    for v in problem.variable_sets:
        if v is target:
            return start
        start += v.size
    raise KeyError(target.name)


# ---- constraint sets ---------------------------------------------------------------------------------------
def dynamics_residuals(problem: WindowProblem, times: np.ndarray, out: ConstraintSet):
    """Newton and Euler residuals (3, n) each at `times`, written for the rows of `out` (WindowProblem.read),
    scaled by body weight (and 1 m), forces f in body weights: r''/g + z - sum f and
    (I_w w' + w x I_w w + tau_int)/(m g) - sum (p - r) x f, tau_int the input's internal torque
    (ReducedMotion.internal_torque) when `internal_momentum` is on, else zero."""
    s, red = problem.settings, problem.window.reduced
    n = len(times)
    r = problem.read(out, problem.com.position, times, 0)
    acc = problem.read(out, problem.com.position, times, 2)
    e = [problem.read(out, problem.com.orientation, times, k) for k in range(3)]
    torque = euler_torque(e[0], e[1], e[2], interpolate(red.times, red.inertia, times))
    if s.internal_momentum:
        torque = torque + ca.DM(interpolate(red.times, red.internal_torque, times).T)
    total, moment = SYMBOL.zeros(3, n), SYMBOL.zeros(3, n)
    for i, force in enumerate(problem.forces):
        if not force.any_contact:
            continue
        f = problem.read(out, force.trajectory, times)
        total = total + f
        moment = moment + cross(problem.read(out, problem.feet[i].trajectory, times) - r, f)
    up = ca.DM([[0.0], [0.0], [1.0]]) @ ca.DM.ones(1, n)
    return acc / s.gravity + up - total, torque / (red.mass * s.gravity) - moment


def dynamics(problem: WindowProblem) -> ConstraintSet:
    """m r'' = sum f + m g and I_w w' + w x I_w w = sum (p - r) x f at the dynamics samples (every
    `dynamics_interval`), and Newton's equation also at every frame and between frames at most
    `linear_dynamics_interval` apart, so that the forces read at the frames are the ones that move the COM; where
    frames come faster, every `linear_dynamics_interval` (newton_sample_times)."""
    s, w, red = problem.settings, problem.window, problem.window.reduced
    times = sample_times(w.t0, w.t1, s.dynamics_interval, red.times)
    out = ConstraintSet("dynamics")
    linear, angular = dynamics_residuals(problem, times, out)
    linear_times = newton_sample_times(red.times, s.linear_dynamics_interval)
    if not np.array_equal(linear_times, times):
        linear, _ = dynamics_residuals(problem, linear_times, out)
    out.add(linear)
    out.add(angular)
    return out


def acceleration_continuity(problem: WindowProblem) -> ConstraintSet:
    """The COM position's and orientation's second derivatives continuous at their inner nodes (C2; ours).
    Hermite cubics alone are C1: their accelerations may jump at every node, and with the dynamics held only at
    samples the optimiser hides accelerations between them (measured: forces at the frames 5% above what the COM
    motion needs on average). Knots within `contact_change_reach` COM intervals of a contact phase's start or end
    are left out: the net force, and with it the COM's acceleration, changes fast where a point lands or
    lifts off (one leg taking the weight, a hop's take-off), and held C2 there the optimiser moved the body far
    from its input to meet such a change smoothly."""
    out = ConstraintSet("acceleration_continuity", linear=True)
    size = int(problem.x.shape[0])
    s = problem.settings
    changes = np.array([p.start for phases in problem.window.phases for p in phases[1:]])
    for trajectory in (problem.com.position, problem.com.orientation):
        M = trajectory.knot_jumps(2, size)
        if M.shape[0]:
            knots = np.array([seg.nominal[0] for seg in trajectory.segments[1:]])
            reach = s.contact_change_reach * s.com_interval + 1e-9
            free = (np.abs(knots[:, None] - changes[None]) <= reach).any(axis=1)  # none without changes
            M = M[np.repeat(~free, M.shape[0] // len(knots))]  # rows: DIM per inner knot
            if M.shape[0]:
                out.add(ca.mtimes(to_dm(M), problem.x))
    return out


def velocity_boundaries(problem: WindowProblem) -> ConstraintSet:
    """COM velocity at the clip's first and last frame equals the input's mean over `boundary_seconds`."""
    w = problem.window
    out = ConstraintSet("velocity_boundaries", linear=True)
    if w.start_velocity is not None and w.start is None:
        out.add(problem.sample(problem.com.position, [w.t0], 1) - w.start_velocity.reshape(3, 1))
    if w.end_velocity is not None:
        out.add(problem.sample(problem.com.position, [w.t1], 1) - w.end_velocity.reshape(3, 1))
    return out


def foot_length_times(window: Window, heel_phases: list[Phase], toe_phases: list[Phase],
                      interval: float) -> np.ndarray:
    """Times at which a foot's length is held, so that no two rows say (nearly) the same thing: one time inside
    each overlap of a heel and a toe contact phase (two planted places: every time there gives the same row), and
    the kinematic samples (every `interval`; 0: the frames) where either point flies, except those closer to such
    an overlap than half the samples' spacing (a point just lifted is still almost at its planted place, so the
    row almost repeats the overlap's). Sampled everywhere, a stance repeated one equation and a sample just after
    a lift-off nearly repeated it: IPOPT's multipliers of those rows grew to 1e5 and cancelled, and the window
    crawled to its budget (docs/decisions/trajopt-turn-window.md)."""
    edges = np.unique(np.round([p.start for p in heel_phases + toe_phases] + [window.t1], 9))
    middles = 0.5 * (edges[:-1] + edges[1:])  # one per stretch between consecutive phase boundaries
    planted = flags_from_phases(heel_phases, middles) & flags_from_phases(toe_phases, middles)
    grid = sample_times(window.t0, window.t1, interval, window.reduced.times)
    stretch = np.clip(np.searchsorted(edges, grid, side="right") - 1, 0, len(middles) - 1)
    keep = ~planted[stretch]
    stance_ends = np.concatenate([edges[:-1][planted], edges[1:][planted]])
    if len(stance_ends) and len(grid) > 1:
        spacing = (grid[-1] - grid[0]) / (len(grid) - 1)
        keep &= np.abs(grid[:, None] - stance_ends[None]).min(axis=1) >= 0.5 * spacing
    return free_times(window, np.sort(np.concatenate([middles[planted], grid[keep]])))


def foot_length(problem: WindowProblem) -> ConstraintSet:
    """|heel - toe|^2 / l_foot^2 = 1 for both feet at `foot_length_times`."""
    s, w, red = problem.settings, problem.window, problem.window.reduced
    out = ConstraintSet("foot_length")
    for side, (heel, toe) in enumerate(FOOT_PAIRS):
        feet = problem.feet
        times = foot_length_times(w, w.phases[heel], w.phases[toe], s.kinematic_interval)
        d = problem.read(out, feet[heel].trajectory, times) - problem.read(out, feet[toe].trajectory, times)
        out.add(ca.sum1(d * d) / red.foot_length[side] ** 2 - 1.0)
    return out


def leg_length(problem: WindowProblem) -> ConstraintSet:
    """|p_i - hip_i|^2 <= l_leg,i^2 at the kinematic samples; hip_i = r + R(theta) h_i(t), h_i the input's hip
    offset from the COM in the root frame."""
    s, w, red = problem.settings, problem.window, problem.window.reduced
    times = free_times(w, sample_times(w.t0, w.t1, s.kinematic_interval, red.times))
    out = ConstraintSet("leg_length")
    r = problem.read(out, problem.com.position, times)
    e = problem.read(out, problem.com.orientation, times)
    hips = interpolate(red.times, red.hips, times)  # (n, 4, 3)
    for i, foot in enumerate(problem.feet):
        d = problem.read(out, foot.trajectory, times) - r - rotate(e, ca.DM(hips[:, i].T))
        out.add(ca.sum1(d * d) / red.leg_length[i] ** 2, -np.inf, 1.0)
    return out


def _pyramid(out: ConstraintSet, f, mu: float) -> None:
    """|f_x| <= mu f_z and |f_y| <= mu f_z for columns f (3, n): four linear rows <= 0 each."""
    out.add(ca.vertcat(f[0, :] - mu * f[2, :], -f[0, :] - mu * f[2, :], f[1, :] - mu * f[2, :],
                       -f[1, :] - mu * f[2, :]), -np.inf, 0.0)


def force_limits(problem: WindowProblem) -> ConstraintSet:
    """Pushing, at most f_max, inside the friction pyramid: at every force node (the normal force's limits are
    variable bounds there) and, in contact, at the frames and between them where Newton's equation is held
    (frame_sample_times; above 60 fps every frame, a superset of Newton's samples). Held at the frames only, the
    cubics between them pulled on the floor and pushed tens of body weights where Newton's equation still read them
    (12 fps: docs/decisions/trajopt-force-chatter.md)."""
    s, red = problem.settings, problem.window.reduced
    fmax = s.max_force / (red.mass * s.gravity)
    out = ConstraintSet("force_limits", linear=not any(f.trajectory.symbolic_times for f in problem.forces))
    samples = frame_sample_times(red.times, s.linear_dynamics_interval)
    for i, force in enumerate(problem.forces):
        if not force.any_contact:
            continue
        _pyramid(out, problem.select(np.array(force.value_index)), s.friction)
        # Also the samples a contact phase may grow over when its boundaries are free.
        reach = s.max_duration_change if force.trajectory.symbolic_times else 0.0
        inside = [(samples >= p.start - reach - 1e-9) & (samples <= p.end + reach + 1e-9)
                  for p in problem.window.phases[i] if p.contact]
        times = samples[np.logical_or.reduce(inside)]
        if len(times):
            f = problem.sample(force.trajectory, times)
            _pyramid(out, f, s.friction)
            out.add(f[2, :], 0.0, fmax)
    return out


def above_floor(problem: WindowProblem) -> ConstraintSet:
    """z >= 0 of each heel and toe at the floor samples (in contact it is 0 by construction)."""
    s, w, red = problem.settings, problem.window, problem.window.reduced
    times = free_times(w, sample_times(w.t0, w.t1, s.floor_interval, red.times))
    out = ConstraintSet("above_floor", linear=not any(f.trajectory.symbolic_times for f in problem.feet))
    for foot in problem.feet:
        out.add(problem.sample(foot.trajectory, times)[2, :], 0.0, np.inf)
    return out


CONSTRAINTS = dict(dynamics=dynamics, acceleration_continuity=acceleration_continuity,
                   velocity_boundaries=velocity_boundaries, foot_length=foot_length,
                   leg_length=leg_length, force_limits=force_limits, above_floor=above_floor)


# ---- cost terms ------------------------------------------------------------------------------------------------
# The feet's smoothing terms take their derivatives per 1/30 s step (a velocity in metres per step, an
# acceleration in metres per step squared), like the finite differences of the same authors' kinematic terms
# (B2-B4); the COM's and orientation's are per second, as written. Read per second, the paper's gamma_p = 0.1
# and beta_p = 1e-4 outweigh the feet's data term so much that swinging feet are pulled 10-20 cm off their path
# (measured), which the paper's figures do not show; read per step, its beta_r and beta_theta would leave the
# COM's acceleration unsmoothed, and the forces at the frames noisy (max 239% of body weight against 137% on
# the synthetic walks, measured).
FEET_SMOOTHING_STEP = 1.0 / 30.0  # s
# The smoothing terms (velocity, acceleration, force_rate) are read at the frames and, below 30 fps, also between
# them at most this far apart, each sample weighted 1 / samples per frame interval (a frame interval weighs as
# before against the data term; 30 and 60 fps unchanged): read at 10 fps frames only, the polynomials swung
# between frames without cost (docs/decisions/trajopt-frame-rate.md).
SMOOTHING_INTERVAL = 1.0 / 30.0  # s


def smoothing_samples(frames: np.ndarray) -> tuple[np.ndarray, float]:
    """Times (n,) s at which the smoothing terms are read (`frame_sample_times` every SMOOTHING_INTERVAL) and each
    sample's weight: 1 / samples per frame interval."""
    times = frame_sample_times(frames, SMOOTHING_INTERVAL)
    return times, (len(frames) - 1) / max(1, len(times) - 1)


def _frame_cost(problem: WindowProblem, name: str, order: int, weights: tuple[float, float, float],
                targets: bool) -> CostTerm:
    red = problem.window.reduced
    times, share = (red.times, 1.0) if targets else smoothing_samples(red.times)
    w_p = weights[2] * FEET_SMOOTHING_STEP ** (2 * order)
    parts = [(share * weights[0], problem.com.position, red.com),
             (share * weights[1], problem.com.orientation, red.euler)]
    parts += [(share * w_p, foot.trajectory, red.feet[:, i]) for i, foot in enumerate(problem.feet)]
    if not any(trajectory.symbolic_times for _, trajectory, _ in parts):
        size = int(problem.x.shape[0])
        return CostTerm.least_squares(name, [
            (weight, trajectory.matrix(times, order, size), target.ravel() if targets else np.zeros(3 * len(times)))
            for weight, trajectory, target in parts])
    total: Any = 0
    for weight, trajectory, target in parts:
        value = problem.sample(trajectory, times, order)
        total = total + weight * ca.sumsqr(value - ca.DM(target.T) if targets else value)
    return CostTerm(name, total)


def data(problem: WindowProblem) -> CostTerm:
    """E_data (1): w_r |r - r_in|^2 + w_theta |theta - theta_in|^2 + w_p sum |p_i - p_in,i|^2 at every frame."""
    s = problem.settings
    return _frame_cost(problem, "data", 0, (s.weight_com, s.weight_orientation, s.weight_feet), True)


def velocity(problem: WindowProblem) -> CostTerm:
    """E_vel (3): gamma_r |r'|^2 + gamma_theta |theta'|^2 + gamma_p sum |p_i'|^2 at every frame and between frames
    (smoothing_samples; the feet's per 1/30 s step)."""
    s = problem.settings
    return _frame_cost(problem, "velocity", 1, (s.velocity_com, s.velocity_orientation, s.velocity_feet), False)


def acceleration(problem: WindowProblem) -> CostTerm:
    """E_acc (4): beta_r |r''|^2 + beta_theta |theta''|^2 + beta_p sum |p_i''|^2 at every frame and between frames
    (smoothing_samples; the feet's per (1/30 s)^2)."""
    s = problem.settings
    return _frame_cost(problem, "acceleration", 2,
                       (s.acceleration_com, s.acceleration_orientation, s.acceleration_feet), False)


def duration(problem: WindowProblem) -> CostTerm:
    """E_dur (2): w_d sum (T_ij - T_in,ij)^2 over every phase."""
    s, w, durations = problem.settings, problem.window, problem.durations
    total: Any = 0  # a CasADi expression once a phase adds to it
    if durations is None:
        return CostTerm("duration", total)
    for i, phases in enumerate(w.phases):
        bounds = durations.boundaries(i, phases, problem.x)
        for j, p in enumerate(phases):
            total = total + s.weight_duration * (bounds[j + 1] - bounds[j] - p.duration) ** 2
    return CostTerm("duration", total)


def force_rate(problem: WindowProblem) -> CostTerm:
    """E_force_rate (ours): w_f sum |(f_i(t_k+1) - f_i(t_k)) / (t_k+1 - t_k)|^2 over consecutive samples (the
    frames and, below 30 fps, between them: smoothing_samples, each weighted), forces in body weights. Without it
    the split of the load among the points in contact is free, and the forces read at the frames chatter
    (docs/decisions/trajopt-force-chatter.md). Differences of the samples' values, not the polynomials'
    derivative there, which the optimiser could keep at zero at the samples and steep between them."""
    s = problem.settings
    times, share = smoothing_samples(problem.window.reduced.times)
    weight = share * s.force_rate
    total: Any = 0  # a CasADi expression once a force adds to it
    if len(times) < 2:
        return CostTerm("force_rate", total)
    forces = [force for force in problem.forces if force.any_contact]
    if not any(force.trajectory.symbolic_times for force in forces):
        # Rows 3k + d of the samples (time-major): (f(t_k+1) - f(t_k)) / (t_k+1 - t_k), component d.
        n, size = len(times), int(problem.x.shape[0])
        step = np.repeat(1.0 / np.diff(times), 3)
        rows = np.arange(3 * (n - 1))
        rate_of = sp.csr_matrix((np.concatenate([-step, step]), (np.concatenate([rows, rows]),
                                                                 np.concatenate([rows, rows + 3]))),
                                shape=(3 * (n - 1), 3 * n))
        return CostTerm.least_squares("force_rate", [
            (weight, rate_of @ force.trajectory.matrix(times, 0, size), np.zeros(3 * (n - 1)))
            for force in forces])
    rate = ca.DM(1.0 / np.diff(times)).T
    for force in forces:
        f = problem.sample(force.trajectory, times)
        total = total + weight * ca.sumsqr((f[:, 1:] - f[:, :-1]) * ca.repmat(rate, 3, 1))
    return CostTerm("force_rate", total)


COSTS = dict(data=data, velocity=velocity, acceleration=acceleration, duration=duration, force_rate=force_rate)
