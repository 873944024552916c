"""The trajopt physics stage: Rempe et al. 2020's trajectory optimisation over a whole clip, in windows.

Long clips are cut into windows of `window_seconds` that overlap by `window_overlap`: each window is solved
(stages fit, dynamics, durations; solve.solve_window) but keeps only its part before the next window starts;
the next window starts exactly in the state the previous one reached there (COM position, velocity,
orientation and its rate; the contact points and forces), so the stitched motion stays continuous in position
and velocity and obeys the dynamics across the junction, and the overlap lets each window see what follows.
Time and memory grow linearly with the clip's length. (Blending two independent solutions over the overlap
instead would break no-slip and the dynamics there.) With `parallel_windows` (off by default) the windows are solved
two at a time: the even ones from free starts, then each odd one from its predecessor's state to its successor's
start, so every junction still continues position and velocity (a contact held through a whole odd window may
step at its end, 11 mm measured: why it is off; docs/decisions/trajopt-long-clips.md).

Failures are loud: a window whose dynamics stage IPOPT does not converge keeps the kinematic motion for its
frames, flagged in `converged`, and is logged as a warning; the next window starts afresh.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import logging
import math
import multiprocessing
import signal
import time
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel
from ..body.support import observed_unexplained_frames
from ..config import TrajoptSettings
from ..contacts.flights import held_flights_in_runs
from ..cores import may_use_two_cores, usable_cores
from ..motion import frame_ranges, valid_runs
from .formulation import Window, WindowStart
from .ik import ik_targets, solve_ik
from .phases import clean_flags, contact_phases, split_drifting
from .reduced import boundary_velocity, reduced_motion
from .solve import StageReport, WindowResult, solve_window

log = logging.getLogger("physmocap")


# A converged window whose motion departs this far from its input (mean over the kept frames) is reported: the
# physics could only be met far from the observations, typically because of wrong contact labels (ours).
DEPARTURE_COM, DEPARTURE_FEET = 0.10, 0.15  # m
MIN_FRAMES = 3  # a run of valid frames shorter than this keeps the kinematic motion
# The final motion passes from the physics' to frames kept kinematic (unexplained, not converged) and back over
# this: no jump at a flagged segment (issue 17). PhysCap's own offline blend, physics.unexplained_blend_offline,
# was measured longer on its validation clips (docs/decisions/physics-limits.md); this one was not measured again.
BLEND_SECONDS = 0.2  # s
PARALLEL_WORKERS = 2  # windows solved at a time with settings.parallel_windows (the even, then the odd ones)


@dataclass
class WindowReport:
    """One window: frames [start, stop] solved, [start, keep) kept; converged; the stage whose solution was kept;
    every IPOPT run; program size; seconds to build and in total; com_departure, feet_departure: mean distance
    (m) of the optimised COM and contact points from the input over the kept frames, com_departure_max the COM's
    largest (nan if not converged); restarted: the first solve did not converge and the window was solved again:
    from a free start when it continued a neighbour's state, else with its start velocity free (the input's
    estimate of it dropped); departed: converged, but its COM farther from the input than
    settings.reject_departure on some kept frame, so not used."""

    start: int
    stop: int
    keep: int
    converged: bool
    chosen: str
    stages: list[StageReport]
    variables: int
    constraints: int
    build_seconds: float
    seconds: float
    com_departure: float = float("nan")
    feet_departure: float = float("nan")
    com_departure_max: float = float("nan")
    restarted: bool = False
    departed: bool = False

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, values: dict) -> WindowReport:
        return cls(**{**values, "stages": [StageReport(**s) for s in values["stages"]]})

    def describe(self) -> str:
        """One line: the frames, whether it converged, the solution kept, and every IPOPT run."""
        runs = "; ".join(f"{s.name} {s.status}, {s.iterations} iterations, objective {s.objective:.4g}"
                         for s in self.stages)
        if self.departed:
            verdict = (f"converged up to {100 * self.com_departure_max:.0f} cm from the input (COM), NOT used, "
                       "kinematic motion kept")
        elif self.converged:
            verdict = f"converged, kept {self.chosen}"
        else:
            verdict = "NOT converged, kinematic motion kept"
        restart = " (solved afresh)" if self.restarted else ""
        return f"frames {self.start}-{self.keep - 1} (solved to {self.stop}): {verdict}{restart}; {runs}"


@dataclass
class TrajoptMotion:
    """The trajopt stage's output, shaped like dynamics.stage.PhysicsMotion so the result file takes it as is.

    qpos: (T, nq) final motion (world frame, floor z = 0); where the optimisation did not converge, the kinematic
        motion, flagged;
    grf: (T, 4, 3) N, contact forces of l heel, l toe, r heel, r toe in the world frame (zeros where not
        converged);
    residual: (T, 6) zeros: the formulation has no residual root actuation;
    contacts: (T, 4) bool, the contact phases used (after the optional duration stage);
    converged: (T,) bool, the frame's window converged (IPOPT's dynamics stage) within settings.reject_departure
        of the input; the rest kept kinematic;
    corrected: (T,) zeros (PhysCap's balance correction has no counterpart here);
    qp_failures: (T,) int, 1 where not converged (so `qp_failures > 0` flags fallback frames as for PhysCap);
    com, com_acceleration, euler, feet: (T, 3), (T, 3), (T, 3), (T, 4, 3) the optimised reduced motion (m,
        m/s^2, Z-Y-X Euler angles in rad, m; nan where not converged);
    windows: one report per window; seconds: time spent, ik_seconds of it in the full-body output (C.4);
    unexplained: (T,) bool, observed frames the contact model cannot explain (`unexplained_frames`, and flights
        of the labels that the COM does not fall through with no foot to hold it up), not optimised and kept
        kinematic (so also not converged); None: not diagnosed.
    """

    qpos: np.ndarray
    grf: np.ndarray
    residual: np.ndarray
    contacts: np.ndarray
    converged: np.ndarray
    corrected: np.ndarray
    qp_failures: np.ndarray
    com: np.ndarray
    com_acceleration: np.ndarray
    euler: np.ndarray
    feet: np.ndarray
    windows: list[WindowReport] = field(default_factory=list)
    seconds: float = 0.0
    ik_seconds: float = 0.0
    unexplained: np.ndarray | None = None

    @property
    def failed_frames(self) -> list[str]:
        """Frame ranges where the optimisation did not converge, e.g. ['0-59', '120-179']."""
        return frame_ranges(np.flatnonzero(~self.converged))

    def report(self) -> dict:
        """What the run summary (summary.json) says about the optimisation: the summary line, converged frames,
        the ranges kept kinematic and every window's report."""
        return dict(summary=self.summary(), converged_frames=int(self.converged.sum()),
                    frames=len(self.converged), not_converged_frames=self.failed_frames,
                    windows=[w.to_dict() for w in self.windows], seconds=self.seconds, ik_seconds=self.ik_seconds)

    def summary(self) -> str:
        """One line for the terminal."""
        done = int(self.converged.sum())
        line = (f"trajopt: {len(self.windows)} window(s), {done}/{len(self.converged)} frames converged, "
                f"{self.seconds:.1f} s")
        if done < len(self.converged):
            why = " or departed from the input" if any(w.departed for w in self.windows) else ""
            line += f"; NOT converged{why} (kinematic motion kept): frames {', '.join(self.failed_frames)}"
        if self.unexplained is not None and self.unexplained.any():
            below = ", ".join(frame_ranges(np.flatnonzero(self.unexplained)))
            line += (f"; of these, the contact model cannot explain frames {below} (the input's centre of mass "
                     "below the floor, the body resting on a knee, an elbow or the seat, or held up with no foot on "
                     "it)")
        return line

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every field as named arrays for an .npz file (the window reports as JSON text); `from_arrays`
        rebuilds it."""
        import json

        arrays = {f.name: np.asarray(getattr(self, f.name)) for f in dataclasses.fields(self)}
        arrays["windows"] = np.array(json.dumps([w.to_dict() for w in self.windows]))
        arrays["unexplained"] = np.zeros(0, bool) if self.unexplained is None else np.asarray(self.unexplained, bool)
        return arrays

    @classmethod
    def from_arrays(cls, arrays) -> TrajoptMotion:
        """The motion `to_arrays` gave (a KeyError names a missing array)."""
        import json

        values = {f.name: arrays[f.name] for f in dataclasses.fields(cls)}
        values["windows"] = [WindowReport.from_dict(w) for w in json.loads(str(values["windows"]))]
        values["seconds"], values["ik_seconds"] = float(values["seconds"]), float(values["ik_seconds"])
        values["unexplained"] = None if len(values["unexplained"]) == 0 else values["unexplained"]
        return cls(**values)


def window_ranges(frames: int, fps: float, settings: TrajoptSettings) -> list[tuple[int, int, int]]:
    """(start, stop, keep) frame indices of the windows: frames start..stop (inclusive) are solved and start..keep-1
    kept (the last window keeps to the end). Windows have equal strides and at most window_seconds."""
    last = frames - 1
    length = max(2, int(round(settings.window_seconds * fps)))  # frame intervals per window
    overlap = min(int(round(settings.window_overlap * fps)), length // 2)
    if last <= length:
        return [(0, last, frames)]
    count = math.ceil((last - overlap) / (length - overlap))
    stride = math.ceil((last - overlap) / count)
    out = []
    for k in range(count):
        start = k * stride
        if k == count - 1:
            out.append((start, last, frames))
        else:
            out.append((start, min(start + stride + overlap, last), (k + 1) * stride))
    return out


def run_trajopt(body: BodyModel, qpos_kin: np.ndarray, fps: float, contacts: np.ndarray,
                settings: TrajoptSettings | None = None,
                progress: Callable[[int, int], None] | None = None,
                valid: np.ndarray | None = None) -> TrajoptMotion:
    """Physics by trajectory optimisation (Rempe et al. 2020, 3.1 and C) over a kinematic motion.

    body: the calibrated body model (its de Leva masses and inertias give the COM and inertia over time);
    qpos_kin: (T, nq) kinematic motion in the floor's world frame (Z up, floor z = 0), e.g. from
        `refine_kinematics` (Rempe B.4) or the offline kinematic fit;
    fps: frames per second; contacts: (T, 4) bool contact flags (l heel, l toe, r heel, r toe), e.g. the
        centred contact network's, relabelled by `refine_kinematics`;
    settings: TrajoptSettings (None: the defaults); progress: called with (frames done, T) after each window;
    valid: (T,) bool, frames with observations (None: all). Each run of valid frames is optimised on its own
        (a gap without observations has no contact labels and would read as a long flight); invalid frames
        keep the kinematic motion and count as not converged.
    Returns a TrajoptMotion (see there); never raises for a non-converged solve: it flags the frames.
    """
    start_time = time.perf_counter()
    settings = TrajoptSettings() if settings is None else settings
    settings.check()
    T = len(qpos_kin)
    observed = np.ones(T, bool) if valid is None else np.asarray(valid, bool)
    pose = kin.forward_kinematics(body, qpos_kin)
    reduced = reduced_motion(body, qpos_kin, fps, pose)
    unexplained = observed_unexplained_frames(body.point_names, pose.points, reduced.com, fps, observed, "trajopt",
                                              contacts)
    del pose  # the rotations of every body and frame: not kept through the solve
    valid = observed & ~unexplained
    min_frames = max(1, math.ceil(settings.min_phase_seconds * fps - 1e-9))
    flags = np.stack([clean_flags(contacts[:, i], min_frames) for i in range(4)], axis=1) & valid[:, None]
    flags, unheld = held_flights_in_runs(flags, valid, reduced.com, reduced.feet, reduced.times, settings.gravity,
                                         np.repeat(reduced.foot_length, 2), "trajopt")
    unexplained |= unheld
    valid &= ~unheld
    flags &= valid[:, None]
    flags = split_drifting(flags, reduced.feet[..., :2], settings.contact_drift, min_frames)
    out = TrajoptMotion(
        qpos=qpos_kin.copy(), grf=np.zeros((T, 4, 3)), residual=np.zeros((T, 6)), contacts=flags.copy(),
        converged=np.zeros(T, bool), corrected=np.zeros(T, bool), qp_failures=np.ones(T, int),
        com=np.full((T, 3), np.nan), com_acceleration=np.full((T, 3), np.nan), euler=np.full((T, 3), np.nan),
        feet=np.full((T, 4, 3), np.nan), unexplained=unexplained)
    # The fit stage's orientation (no dynamics) on converged frames: what the upper body turns against (C.4).
    fitted_euler = reduced.euler.copy()
    solver = _Solver(settings)
    try:
        for first, end in valid_runs(valid):
            if end - first < MIN_FRAMES:
                log.warning("trajopt: frames %d-%d are too few to optimise; the kinematic motion is kept there.",
                            first, end - 1)
                continue
            _solve_run(out, reduced, flags, first, end, fps, settings, progress, solver, fitted_euler)
    finally:
        solver.close()
    ik_start = time.perf_counter()
    _full_body(out, body, qpos_kin, reduced, fitted_euler, fps, settings)
    out.qp_failures = (~out.converged).astype(int)
    out.ik_seconds = time.perf_counter() - ik_start
    out.seconds = time.perf_counter() - start_time
    return out


def _full_body(out: TrajoptMotion, body: BodyModel, qpos_kin: np.ndarray, reduced, fitted_euler: np.ndarray,
               fps: float, settings: TrajoptSettings) -> None:
    """out.qpos on the converged frames: the full body (IK, Rempe 3.1) following the optimised COM, orientation
    (its change from fitted_euler (T, 3), the fit stage's) and feet, handed over to qpos_kin (T, nq) within
    BLEND_SECONDS of the frames that keep it."""
    done = out.converged
    if not done.any():
        return
    targets = ik_targets(body, qpos_kin[done], reduced.frames(done), out.com[done], out.euler[done],
                         out.feet[done], settings, fitted_euler[done])
    # Every frame's targets for itself: the frames kept kinematic are fitted to them (then restored exactly, the
    # smoothing term links neighbours only across converged frames' edges), the blend moves towards them.
    own = ik_targets(body, qpos_kin, reduced, reduced.com, reduced.euler, reduced.feet, settings)
    share = _kinematic_share(done, fps)[done]
    own.markers[done] = targets.markers + share[:, None, None] * (own.markers[done] - targets.markers)
    own.weights[done] = targets.weights + share[:, None] * (own.weights[done] - targets.weights)
    start = own.qpos[done]
    start[:, :3] = targets.qpos[:, :3] + share[:, None] * (start[:, :3] - targets.qpos[:, :3])
    turn = np.sign(np.sum(start[:, 3:7] * targets.qpos[:, 3:7], axis=1, keepdims=True) + 1e-12)
    root = targets.qpos[:, 3:7] + share[:, None] * (turn * start[:, 3:7] - targets.qpos[:, 3:7])
    start[:, 3:7] = root / np.linalg.norm(root, axis=1, keepdims=True)
    start[:, 7:] = targets.qpos[:, 7:]
    own.qpos[done] = start
    qpos = solve_ik(body, own, fps, settings)
    out.qpos[done] = qpos[done]


def _kinematic_share(done: np.ndarray, fps: float) -> np.ndarray:
    """(T,) 0..1, how far each frame is handed to the kinematic motion: 1 where not `done` (T,) bool, falling
    linearly to 0 over BLEND_SECONDS on either side (0 everywhere when every frame is done)."""
    frames = np.arange(len(done))
    if done.all():
        return np.zeros(len(done))
    last = np.maximum.accumulate(np.where(done, -len(done), frames))
    following = np.minimum.accumulate(np.where(done, 2 * len(done), frames)[::-1])[::-1]
    distance = np.minimum(frames - last, following - frames)
    return np.clip(1.0 - distance / (BLEND_SECONDS * fps + 1.0), 0.0, 1.0)


def _measure_departure(report: WindowReport, result, red, n: int, limit: float | None) -> None:
    """The converged window's distance from the kinematic motion over its n kept frames (COM, feet, m; mean, and
    the COM's largest) into `report`, departed when the COM's largest is over `limit`: a window can hold its input
    on average and still drop the body half a metre for a third of a second, with five body weights to catch it
    (docs/decisions/trajopt-settings.md); a warning when it departs or is far on average."""
    start, keep = report.start, report.keep
    com = np.linalg.norm(result.com[:n] - red.com[:n], axis=-1)
    report.com_departure, report.com_departure_max = float(com.mean()), float(com.max())
    report.feet_departure = float(np.linalg.norm(result.feet[:n] - red.feet[:n], axis=-1).mean())
    report.departed = limit is not None and report.com_departure_max > limit
    if limit is not None and report.departed:
        log.warning("trajopt: on frames %d-%d the optimised motion departs from the kinematic one by up to %.0f cm "
                    "(COM, at frame %d), more than trajopt.reject_departure (%.0f cm): not used, the kinematic "
                    "motion is kept there.", start, keep - 1, 100 * report.com_departure_max,
                    start + int(com.argmax()), 100 * limit)
    elif report.com_departure > DEPARTURE_COM or report.feet_departure > DEPARTURE_FEET:
        log.warning("trajopt: on frames %d-%d the physical motion departs from the kinematic one by %.0f cm "
                    "(COM) and %.0f cm (feet) on average: the contact labels may be wrong there.", start,
                    keep - 1, 100 * report.com_departure, 100 * report.feet_departure)


@dataclass
class _Task:
    """One window to solve, picklable for a worker process: frames [start, stop] solved, [start, keep) kept;
    `retry` is solved, with what is left of the budget, when `window` does not converge: afresh when `window`
    continues a neighbour's state, else without the input's start velocity; the solved state is wanted at
    `state_times` (s) for the neighbouring windows."""

    start: int
    stop: int
    keep: int
    window: Window
    retry: Window
    state_times: tuple[float, ...] = ()


@dataclass
class _Outcome:
    """A solved task: the result (without its state function, which does not cross processes), whether the retry
    was kept, the states at the task's state_times (empty if not converged), and wall seconds."""

    result: WindowResult
    restarted: bool
    states: list[WindowStart]
    seconds: float


def _solve_task(task: _Task, settings: TrajoptSettings) -> _Outcome:
    t0 = time.perf_counter()
    # Half the budget first, the retry the rest: a window that needs more has wandered (issue 23). A first try
    # that stalls gives way to the retry early; the retry, the window's last chance, runs to the budget.
    result = solve_window(task.window, settings, settings.max_iterations // 2, stop_stalled=True)
    restarted = False
    left = settings.max_iterations - sum(st.iterations for st in result.stages)
    if not result.converged and left > 0:
        # Drop what the first solve could not meet (the neighbours' states, else the input's start velocity), with
        # what is left of the budget: continuity at the junction broken rather than the window lost.
        retry = solve_window(task.retry, settings, left)
        retry.stages = result.stages + [dataclasses.replace(st, name=f"restart {st.name}") for st in retry.stages]
        result, restarted = retry, True
    states = [result.state_at(t) for t in task.state_times] if result.converged else []
    result._state_at = None
    return _Outcome(result, restarted, states, time.perf_counter() - t0)


def _ignore_interrupts() -> None:
    """A worker leaves Ctrl-C to the parent, which stops the workers (problem.interrupts_noted then stays out)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Solver:
    """Solves tasks in this process, or two at a time in forked worker processes where settings.parallel_windows
    is on, this process has at least two cores, can fork (spawned workers would run the caller's script again
    unless it is guarded by `if __name__ == "__main__":`) and is not itself a pool or batch worker
    (`cores.may_use_two_cores`). Where the tasks run does not change their results."""

    def __init__(self, settings: TrajoptSettings):
        self.settings = settings
        forks = "fork" in multiprocessing.get_all_start_methods()
        self.workers = (PARALLEL_WORKERS if settings.parallel_windows and forks and may_use_two_cores()
                        and usable_cores() >= PARALLEL_WORKERS else 1)
        self.pool: concurrent.futures.ProcessPoolExecutor | None = None

    def map(self, tasks: list[_Task]) -> list[_Outcome]:
        if self.workers <= 1 or len(tasks) <= 1:
            return [_solve_task(task, self.settings) for task in tasks]
        if self.pool is None:
            self.pool = concurrent.futures.ProcessPoolExecutor(
                self.workers, multiprocessing.get_context("fork"), initializer=_ignore_interrupts)
        try:
            return list(self.pool.map(_solve_task, tasks, [self.settings] * len(tasks)))
        except BrokenProcessPool:
            log.warning("trajopt: a worker process solving windows two at a time died (killed for memory?); the "
                        "windows are solved one after another.")
            self.close()
            self.workers = 1
            return [_solve_task(task, self.settings) for task in tasks]

    def close(self) -> None:
        """Stops the workers, also on Ctrl-C: a window being solved is not waited for."""
        if self.pool is None:
            return
        processes = list(getattr(self.pool, "_processes", {}).values())  # the executor keeps no public handle
        self.pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        for process in processes:
            process.join()
        self.pool = None


def _record(out: TrajoptMotion, task: _Task, outcome: _Outcome, reduced, settings: TrajoptSettings,
            fitted_euler: np.ndarray) -> bool:
    """A solved window's report and, if converged and near its input, its kept frames into `out` (and its fit
    stage's orientation into fitted_euler); warnings for what went wrong. Returns whether the window's states may
    start or end its neighbours."""
    start, stop, keep, result = task.start, task.stop, task.keep, outcome.result
    linked = task.window.start is not None or task.window.end is not None
    if outcome.restarted and result.converged and linked:
        log.warning("trajopt: frames %d-%d could not continue the neighbouring windows' motion and were solved "
                    "afresh: the motion may jump at frame %d.", start, keep - 1, start)
    elif outcome.restarted and result.converged:
        log.info("trajopt: frames %d-%d were solved again with their start velocity free (the input's estimate "
                 "of it could not be met).", start, keep - 1)
    report = WindowReport(start, stop, keep, result.converged, result.chosen, result.stages, result.variables,
                          result.constraints, result.build_seconds, outcome.seconds, restarted=outcome.restarted)
    out.windows.append(report)
    kept, n = slice(start, keep), keep - start
    if result.converged:
        _measure_departure(report, result, reduced.frames(slice(start, stop + 1)), n, settings.reject_departure)
    if not result.converged:
        statuses = ", ".join(f"{st.name}: {st.status}" for st in result.stages)
        log.warning("trajopt: IPOPT did not converge on frames %d-%d (%s); the kinematic motion is kept there.",
                    start, keep - 1, statuses)
        return False
    if report.departed:  # reported by _measure_departure
        return False
    out.converged[kept] = True
    out.com[kept], out.euler[kept], out.feet[kept] = result.com[:n], result.euler[:n], result.feet[:n]
    fitted_euler[kept] = result.fitted_euler[:n]
    out.com_acceleration[kept] = result.com_acceleration[:n]
    out.grf[kept] = result.forces[:n]
    out.contacts[kept] = result.contacts[:n]
    return True


def _solve_run(out: TrajoptMotion, reduced, flags: np.ndarray, first: int, end: int, fps: float,
               settings: TrajoptSettings, progress, solver: _Solver, fitted_euler: np.ndarray) -> None:
    """The windows of frames [first, end), results into `out`: one after another, each starting where the previous
    one arrived; or, with settings.parallel_windows and three windows or more, two passes: the even windows from
    free starts, then each odd one from its predecessor's state to its successor's start
    (docs/decisions/trajopt-long-clips.md)."""
    T, times = len(flags), reduced.times
    ranges = [(a + first, b + first, c + first) for a, b, c in window_ranges(end - first, fps, settings)]

    def window(start: int, stop: int, keep: int, begin=None, arrive=None, match_velocity=True) -> Window:
        sl = slice(start, stop + 1)
        red = reduced.frames(sl)
        # The clip's first frame matches the input's velocity, and so does a window starting afresh.
        start_velocity = boundary_velocity(reduced.com[start:end], fps, settings.boundary_seconds, end=False)
        return Window(red, [contact_phases(flags[sl, i], red.times) for i in range(4)],
                      start_velocity=start_velocity if match_velocity else None,
                      end_velocity=(boundary_velocity(reduced.com[first:end], fps, settings.boundary_seconds,
                                                      end=True) if stop == end - 1 else None),
                      start=begin, freeze_after=times[keep] if keep < end else np.inf, end=arrive)

    done = 0

    def record(task: _Task, outcome: _Outcome) -> bool:
        nonlocal done
        usable = _record(out, task, outcome, reduced, settings, fitted_euler)
        done += task.keep - task.start
        if progress:
            progress(first + done, T)
        return usable

    if not (settings.parallel_windows and len(ranges) >= 3):
        state = None
        for start, stop, keep in ranges:
            task = _Task(start, stop, keep, window(start, stop, keep, begin=state),
                         retry=window(start, stop, keep, match_velocity=state is not None),
                         state_times=(times[keep],) if keep < end else ())
            outcome = solver.map([task])[0]
            state = outcome.states[0] if record(task, outcome) and outcome.states else None
        return
    _solve_in_two_passes(out, ranges, window, record, times, first, end, solver)


def _solve_in_two_passes(out: TrajoptMotion, ranges: list[tuple[int, int, int]], window, record,
                         times: np.ndarray, first: int, end: int, solver: _Solver) -> None:
    """The windows `ranges` ((start, stop, keep) frames) of the run [first, end) in two passes: the even ones from
    free starts, then each odd one from its predecessor's state to its successor's start; `window` builds a
    Window, `record` files a solved task into `out` (see _solve_run); the reports in window order."""
    reports: dict[int, WindowReport] = {}
    states: dict[int, dict[int, WindowStart]] = {}  # window -> frame -> its solved state there
    even = [k for k in range(len(ranges)) if k % 2 == 0]
    # An even window's states where its odd neighbours begin (its start) and end (its keep), inside the run.
    junctions = {k: [f for f in (ranges[k][0], ranges[k][2]) if first < f < end] for k in even}
    tasks = {k: _Task(*ranges[k], window(*ranges[k]), retry=window(*ranges[k], match_velocity=False),
                      state_times=tuple(times[f] for f in junctions[k]))
             for k in even}
    for k, outcome in zip(even, solver.map(list(tasks.values())), strict=True):
        if record(tasks[k], outcome):
            states[k] = dict(zip(junctions[k], outcome.states, strict=True))
        reports[k] = out.windows.pop()
    odd = [k for k in range(len(ranges)) if k % 2 == 1]
    for k in odd:
        start, stop, keep = ranges[k]
        begin = states.get(k - 1, {}).get(start)
        arrive = states.get(k + 1, {}).get(keep)
        if arrive is not None:  # solved to the next window's start, where it must arrive
            stop = keep
        linked = begin is not None or arrive is not None
        tasks[k] = _Task(start, stop, keep, window(start, stop, keep, begin, arrive),
                         retry=window(*ranges[k], match_velocity=linked))
    for k, outcome in zip(odd, solver.map([tasks[k] for k in odd]), strict=True):
        record(tasks[k], outcome)
        reports[k] = out.windows.pop()
    out.windows.extend(reports[k] for k in range(len(ranges)))
