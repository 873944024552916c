"""The staged solve of one window (Rempe et al. 2020, 3.1 "Optimization Algorithm" and C.3):

1. fit: the polynomials to the input, contact phases fixed, no dynamics (forces held);
2. dynamics: everything, from the fit, forces started at the weight shared among the points in contact;
3. durations (optional): the phase boundaries free too; kept only if IPOPT converges and the objective (which
   now also pays for changed durations) is lower than after stage 2.

A window converges when stage 2 converges; otherwise its result must not be used (the caller keeps the
kinematic motion there and says so). The stages share the window's budget of IPOPT iterations
(settings.max_iterations), stage 1 at most half of it: its point only starts stage 2, converged or not.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..config import TrajoptSettings
from .formulation import DurationVariables, Window, WindowProblem, WindowStart, build_window_problem
from .phases import Phase, flags_from_phases
from .problem import STALLED_STATUS, Program, Solution


@dataclass
class StageReport:
    """One IPOPT run: the stage's name, IPOPT's status, whether it converged, iterations, seconds, objective
    and the largest constraint violation at the returned point."""

    name: str
    status: str
    converged: bool
    iterations: int
    seconds: float
    objective: float
    max_violation: float
    costs: dict[str, float] = field(default_factory=dict)


@dataclass
class WindowResult:
    """The optimised reduced motion at the window's frames. com, euler: (n, 3); fitted_euler: (n, 3) the
    orientation of the fit stage (the input smoothed as the dynamics stage smooths it, without the dynamics);
    feet: (n, 4, 3) m;
    forces: (n, 4, 3) N in the world; com_acceleration: (n, 3) m/s^2; contacts: (n, 4) the phases finally
    used; converged: stage 2 converged; chosen: the stage whose solution this is; stages: every IPOPT run;
    variables/constraints: program size; build_seconds: time to assemble the programs."""

    converged: bool
    chosen: str
    com: np.ndarray
    com_acceleration: np.ndarray
    euler: np.ndarray
    fitted_euler: np.ndarray
    feet: np.ndarray
    forces: np.ndarray
    contacts: np.ndarray
    phases: list[list[Phase]]
    stages: list[StageReport]
    variables: int
    constraints: int
    build_seconds: float
    _state_at: Callable[[float], WindowStart] | None = None

    def state_at(self, t: float) -> WindowStart:
        """The optimised state at time t (s), for the next window to start from."""
        if self._state_at is None:
            raise RuntimeError("this window result has no solved state (it was never solved)")
        return self._state_at(t)


def ipopt_options(settings: TrajoptSettings) -> dict:
    return {
        "tol": settings.tolerance,
        "acceptable_tol": max(10 * settings.tolerance, 1e-3),
        # Stop after 5 acceptable iterates in a row (IPOPT: 15): on an ill-conditioned window the dual
        # infeasibility wanders about acceptable_tol with tiny steps, and 15 in a row came by chance or never;
        # chosen on the looped dance, CMU subject 5 (docs/decisions/trajopt-build-cost.md, sixth pass).
        "acceptable_iter": 5,
        "max_iter": settings.max_iterations,
        "max_cpu_time": settings.max_seconds,  # CPU, not wall: a loaded machine must not change the result
        "linear_solver": "mumps",
        "hessian_approximation": "exact",
        "mu_strategy": "adaptive",
        # Iterative refinement only where a solve's residual asks for it (IPOPT still checks every one): at
        # least one refinement pass per solve was about a quarter of IPOPT's time, the optimum the same.
        "min_refinement_steps": 0,
    }


def _program(problem: WindowProblem, settings: TrajoptSettings) -> Program:
    return Program(problem.x, problem.variable_sets, list(problem.constraints.values()),
                   list(problem.costs.values()), ipopt_options(settings))


def _report(name: str, sol: Solution) -> StageReport:
    return StageReport(name, sol.status, sol.converged, sol.iterations, sol.seconds, sol.objective,
                       sol.max_violation, sol.costs)


def _force_guess(problem: WindowProblem, program: Program, x: np.ndarray) -> np.ndarray:
    """x with every free force node set to the net force the fitted COM motion needs (r''/g + z, body
    weights), shared among the points in contact at the node's time and clipped into the friction pyramid."""
    red, s = problem.window.reduced, problem.settings
    times = red.times
    need = problem.values(problem.com.position, times, x, 2).T / s.gravity + np.array([0.0, 0.0, 1.0])  # (n, 3)
    count = np.maximum(problem.contacts().sum(axis=1), 1)
    x = x.copy()
    fmax = s.max_force / (red.mass * s.gravity)
    for force in problem.forces:
        lower, upper = force.set.lower, force.set.upper
        base = program.var_slices[force.set.name].start
        for t, a in zip(force.node_times, force.value_index, strict=True):
            local = a - base
            if lower[local + 2] == upper[local + 2]:  # held: zero where the phase meets a flight, or a start
                continue
            f = np.array([np.interp(t, times, need[:, k]) for k in range(3)]) / np.interp(t, times, count)
            f[2] = np.clip(f[2], 0.0, fmax)
            f[:2] = np.clip(f[:2], -s.friction * f[2], s.friction * f[2])
            x[a:a + 3] = f
            x[a + 3:a + 6] = 0.0
    return x


def _outputs(problem: WindowProblem):
    """Functions of the solution x: the trajectories at the frames, and the state at one time."""
    times = problem.window.reduced.times

    def frames(x: np.ndarray) -> tuple[np.ndarray, ...]:
        return (problem.values(problem.com.position, times, x), problem.values(problem.com.position, times, x, 2),
                problem.values(problem.com.orientation, times, x),
                np.vstack([problem.values(f.trajectory, times, x) for f in problem.feet]),
                np.vstack([problem.values(f.trajectory, times, x) for f in problem.forces]))

    def state(x: np.ndarray, t: float) -> WindowStart:
        parts = [problem.values(problem.com.position, [t], x, 0), problem.values(problem.com.position, [t], x, 1),
                 problem.values(problem.com.orientation, [t], x, 0), problem.values(problem.com.orientation, [t], x, 1)]
        parts += [problem.values(f.trajectory, [t], x, k) for k in (0, 1) for f in problem.feet]
        parts += [problem.values(f.trajectory, [t], x, k) for k in (0, 1) for f in problem.forces]
        v = np.concatenate(parts, axis=1).T
        return WindowStart(v[0], v[1], v[2], v[3], v[4:8], v[8:12], v[12:16], v[16:20])

    return frames, state


def _schedule_from(window_phases: list[list[Phase]], durations: DurationVariables,
                   x_durations: np.ndarray) -> list[list[Phase]]:
    """The phases with the optimised boundary times."""
    out = []
    for i, phases in enumerate(window_phases):
        row = durations.index[i]
        bounds = [phases[0].start] + [p.start if k is None else float(x_durations[k])
                                      for p, k in zip(phases[1:], row, strict=True)]
        bounds.append(phases[-1].end)
        out.append([Phase(p.contact, bounds[j], bounds[j + 1]) for j, p in enumerate(phases)])
    return out


def solve_window(window: Window, settings: TrajoptSettings, budget: int | None = None,
                 stop_stalled: bool = False) -> WindowResult:
    """Stages 1-3 on one window, within `budget` IPOPT iterations in all (None: settings.max_iterations); with
    stop_stalled, a stage whose constraint violation stalls stops (problem.IterationWatch)."""
    start = time.perf_counter()
    budget = settings.max_iterations if budget is None else budget
    problem = build_window_problem(window, settings)
    program = _program(problem, settings)
    # The force limits read only the forces, held in the fit: constant rows, left out with the dynamics.
    fit_relaxed = ("dynamics", "force_limits")
    program.prepare(fit_relaxed)
    build = time.perf_counter() - start
    stages = []
    # Half the budget at most: a fit cut short starts the dynamics worse (docs/decisions/trajopt-long-clips.md).
    fit = program.solve(program.initial(), fixed=problem.force_set_names, relaxed=fit_relaxed,
                        max_iterations=max(1, budget // 2), stop_stalled=stop_stalled)
    stages.append(_report("fit", fit))
    fitted_euler = problem.values(problem.com.orientation, window.reduced.times, fit.x).T
    if fit.status == STALLED_STATUS:
        # The fit's constraints are the dynamics stage's on the same variables (the forces enter only the relaxed
        # sets): where they stall, so would the dynamics stage. Not run; the window is not solved.
        return _result(window, problem, program, fit.x, window.phases, "fit", False, stages, build, settings,
                       fitted_euler)
    x0 = _force_guess(problem, program, fit.x)
    dyn = program.solve(x0, max_iterations=max(1, budget - fit.iterations), stop_stalled=stop_stalled)
    stages.append(_report("dynamics", dyn))
    chosen, chosen_problem, x = "dynamics", problem, dyn.x
    phases = window.phases
    left = budget - fit.iterations - dyn.iterations
    if dyn.converged and settings.optimize_durations and left > 0:
        t = time.perf_counter()
        dproblem = build_window_problem(window, settings, durations=True)
        durations = dproblem.durations  # set: built with durations=True
        if durations is not None and durations.set.size:
            dprogram = _program(dproblem, settings)
            build += time.perf_counter() - t
            dur = dprogram.solve(np.concatenate([dyn.x, durations.set.initial]), max_iterations=left,
                                 stop_stalled=stop_stalled)
            stages.append(_report("durations", dur))
            if dur.converged and dur.objective < dyn.objective:
                chosen, chosen_problem, x = "durations", dproblem, dur.x
                phases = _schedule_from(dproblem.window.phases, durations, dur.values["durations"])
    return _result(window, chosen_problem, program, x, phases, chosen, dyn.converged, stages, build, settings,
                   fitted_euler)


def _result(window: Window, problem: WindowProblem, program: Program, x: np.ndarray, phases: list[list[Phase]],
            chosen: str, converged: bool, stages: list[StageReport], build: float,
            settings: TrajoptSettings, fitted_euler: np.ndarray) -> WindowResult:
    """The window's motion at its frames from the solution x of `problem` (the stage `chosen`)."""
    frames_fn, state_fn = _outputs(problem)
    com, acc, euler, feet, forces = frames_fn(x)
    n = window.reduced.num_frames
    weight = window.reduced.mass * settings.gravity
    contacts = np.stack([flags_from_phases(p, window.reduced.times) for p in phases], axis=1)
    return WindowResult(
        converged=converged, chosen=chosen, com=com.T, com_acceleration=acc.T, euler=euler.T,
        fitted_euler=fitted_euler, feet=feet.reshape(4, 3, n).transpose(2, 0, 1),
        forces=weight * forces.reshape(4, 3, n).transpose(2, 0, 1), contacts=contacts, phases=phases,
        stages=stages, variables=program.num_variables, constraints=program.num_constraints, build_seconds=build,
        _state_at=lambda t: state_fn(x, t))

