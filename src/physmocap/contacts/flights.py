"""Whole-body flights of the contact labels against the motion: a flight whose centre of mass does not fall is the
labels' error, and a point that stays put holds the body up through it (ours; docs/decisions/trajopt-false-
flights.md). Pure numpy on flags and positions, shared by both offline physics methods (trajopt.stage,
dynamics.stage), with the runs of contact flags and the easing at their edges that planting and retargeting share."""

from __future__ import annotations

import logging

import numpy as np

from ..body.model import CONTACT_POINTS
from ..body.support import STEP_HEIGHT
from ..motion import valid_runs
from .labels import LabelSettings

log = logging.getLogger("physmocap")

# A whole-body flight of the labels (or a target) whose COM needs more than this vertical force on average (body
# weights; 0 in a free fall, 1 standing) is held up, not flying; chosen for trajopt on validation clips of CMU
# subjects 1, 2, 5, 7 (docs/decisions/trajopt-false-flights.md); 0 .. 1
STANDING_SUPPORT = 0.5
EASE_TIME = 0.1  # s: a held point eases onto and off its spot over this (a step's touch-down); planting, retargeting
# m/s: a point moving faster than a contact may (the labels' own definition) holds nothing up through a flight
CONTACT_MAX_SPEED = LabelSettings.contact_max_speed


def runs(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and lengths of the runs of equal values in a (T,) array."""
    flags = np.asarray(flags)
    if len(flags) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    change = np.flatnonzero(flags[1:] != flags[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(flags)]])
    return starts, ends - starts


def ease_frames(fps: float) -> int:
    """EASE_TIME in whole frames at `fps` (frames/s), at least one."""
    return max(1, round(EASE_TIME * fps))


def edge_easing(held: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """How a point eases onto and off its held contacts over EASE_TIME: for flags held (T, K) bool at `fps`
    (frames/s), the weights (T, K) in 0..1 (1 while held, 1 - d / (n + 1) at d <= n = `ease_frames(fps)` frames
    beside a contact, 0 elsewhere) and the frame (T, K) int whose held value each frame takes that share of (itself
    while held; beside a contact, its nearer edge, the earlier one on a tie, so that weight and value come from one
    contact; -1 elsewhere)."""
    held = np.asarray(held, bool)
    frames = ease_frames(fps)
    weights, edges = held.astype(float), np.where(held, np.arange(len(held))[:, None], -1)
    for k in range(held.shape[1]):
        for start, end in valid_runs(held[:, k]):
            for d in range(1, min(frames, len(held)) + 1):  # no frame lies further away
                weight = 1.0 - d / (frames + 1)
                for t, edge in ((start - d, start), (end - 1 + d, end - 1)):
                    if 0 <= t < len(held) and not held[t, k] and weight > weights[t, k]:
                        weights[t, k], edges[t, k] = weight, edge
    return weights, edges


def flight_parabola(com_height: np.ndarray, times: np.ndarray, start: int,
                    stop: int) -> tuple[np.ndarray, np.ndarray, slice] | None:
    """The parabola fitted to a COM height path (T,) m at `times` (T,) s over the flight of frames [start, stop) and
    the frame on either side where the clip has it (its take-off and landing): its coefficients (a, b, c) of
    a t^2 + b t + c, the window's times t from its first frame, and the window; None for fewer than 3 frames."""
    window = slice(max(start - 1, 0), min(stop + 1, len(com_height)))
    if window.stop - window.start < 3:
        return None
    t = times[window] - times[window.start]
    return np.polyfit(t, com_height[window], 2), t, window


def flight_support(com_height: np.ndarray, times: np.ndarray, start: int, stop: int, gravity: float) -> float:
    """The mean vertical force, in body weights, that a COM height path (T,) m at `times` (T,) s needs over the
    flight of frames [start, stop): 1 + z''/g, z'' the curvature of `flight_parabola`. A free fall needs 0; a body
    held up, 1. nan for fewer than 3 frames."""
    parabola = flight_parabola(com_height, times, start, stop)
    return float("nan") if parabola is None else 1.0 + 2.0 * float(parabola[0][0]) / gravity


def flight_speeds(points: np.ndarray, times: np.ndarray, start: int, stop: int) -> np.ndarray:
    """The median speed (P,) m/s of each of points (T, P, 3) at `times` (T,) s over the intervals between the
    frames of the flight [start, stop); zeros for a flight of fewer than three frames, too short to tell a point's
    speed from one noisy step (the intervals to its take-off and landing are the stance's)."""
    if stop - start < 3:
        return np.zeros(points.shape[1])
    steps = np.linalg.norm(np.diff(points[start:stop], axis=0), axis=-1) / np.diff(times[start:stop])[:, None]
    return np.median(steps, axis=0)


def _bridge(flags: np.ndarray, a: int, b: int) -> tuple[int, int]:
    """[a, b) widened to the point's own contacts (flags (T,)) before and after when they resume within the
    flight's length (b - a): a hand-over from one point to another with no frame of both would again leave the
    body a moment without force (each force fades to zero where its phase meets a flight)."""
    n = b - a
    before = np.flatnonzero(flags[max(0, a - n):a])
    after = np.flatnonzero(flags[b:b + n])
    return (max(0, a - n) + int(before[-1]) + 1 if len(before) else a), (b + int(after[0]) if len(after) else b)


def support_held_flights(flags: np.ndarray, com: np.ndarray, points: np.ndarray, times: np.ndarray,
                         gravity: float, max_support: float, drift: np.ndarray | float = np.inf,
                         max_speed: float = np.inf) -> tuple[np.ndarray, list[tuple], list[tuple]]:
    """(T, P) contact flags in which every whole-body flight (no point in contact; one at the clip's first or
    last frame too, judged by its own frames) that the input motion does not fall through is given back a
    support: a flight whose COM (T, 3) needs more than `max_support` body weights (`flight_support`) is the
    labels' error (the body is held up), and physics would have to launch and land it with forces the motion
    never shows. The support is the point, of those in contact on the frame before or after the flight, nearest
    below the COM on average (points (T, P, 3), world on the floor z = 0; a support far to one side would turn the
    body) whose input stays within `drift` m (a number, or one per point (P,)) of its median position along the
    floor over the flight (a held contact does not travel; 0: no limit), within STEP_HEIGHT of the floor (a toe
    climbing a ladder's rungs held nothing on the floor) and whose median speed over the flight is at most
    `max_speed` m/s (`flight_speeds`: a toe swinging off at a run's take-off travels too, though a short flight
    leaves it no time to leave its foot's length); its contact continues through the flight. Returns the flags,
    (start, stop, point, support) of each relabelled flight, [start, stop) the frames put in contact, and
    (start, stop, support) of each flight that no point could hold up (every candidate travels): the contact
    model cannot explain it."""
    flags = np.asarray(flags, bool).copy()
    changed, unsupported = [], []
    starts, lengths = runs(flags.any(axis=1))
    none = np.zeros(flags.shape[1], bool)
    for s, n in zip(starts, lengths, strict=True):
        if flags[s].any():
            continue
        # At either end of the clip only the take-off or the landing is in it: the flight's own frames still
        # show whether the COM falls (nan, left alone, for fewer than 3 frames in all).
        support = flight_support(com[:, 2], times, int(s), int(s + n), gravity)
        if not support > max_support:
            continue
        candidates = (flags[s - 1] if s > 0 else none) | (flags[s + n] if s + n < len(flags) else none)
        if not candidates.any():
            continue
        slow = flight_speeds(points, times, int(s), int(s + n)) <= max_speed
        reach = np.linalg.norm(points[s:s + n, :, :2] - com[s:s + n, None, :2], axis=-1).mean(axis=0)
        for point in np.argsort(np.where(candidates, reach, np.inf))[:int(candidates.sum())]:
            if not slow[point]:
                continue
            a, b = _bridge(flags[:, point], int(s), int(s + n))
            p = points[a:b, point, :2]
            limit = np.broadcast_to(drift, (flags.shape[1],))[point]
            if limit > 0 and np.linalg.norm(p - np.median(p, axis=0), axis=1).max() > limit:
                continue
            if np.abs(points[a:b, point, 2]).max() > STEP_HEIGHT:
                continue
            flags[a:b, point] = True
            changed.append((a, b, int(point), support))
            break
        else:
            unsupported.append((int(s), int(s + n), support))
    return flags, changed, unsupported


def held_flights_in_runs(flags: np.ndarray, valid: np.ndarray, com: np.ndarray, points: np.ndarray,
                         times: np.ndarray, gravity: float, drift: np.ndarray | float,
                         method: str) -> tuple[np.ndarray, np.ndarray]:
    """support_held_flights (max_support STANDING_SUPPORT, max_speed CONTACT_MAX_SPEED) within each run of valid
    frames (T,) of flags (T, 4), com (T, 3), points (T, 4, 3) (CONTACT_POINTS) at times (T,) s; each point put in
    contact, and each flight that no point can hold up, logged as `method`'s ("physics", "trajopt"). Returns the
    flags and (T,) bool the frames of the flights no point can hold: the contact model cannot explain them, and
    both methods keep the kinematic motion there."""
    flags, unheld = np.asarray(flags, bool).copy(), np.zeros(len(flags), bool)
    for first, end in valid_runs(valid):
        flags[first:end], changed, unsupported = support_held_flights(
            flags[first:end], com[first:end], points[first:end], times[first:end], gravity, STANDING_SUPPORT, drift,
            CONTACT_MAX_SPEED)
        for start, stop, point, support in changed:
            log.warning("%s: around frames %d-%d the labels give a flight, but the motion's centre of mass needs "
                        "%.0f%% of body weight there: the %s is kept in contact over these frames.", method,
                        first + start, first + stop - 1, 100 * support, CONTACT_POINTS[point].replace("_", " "))
        for start, stop, support in unsupported:
            unheld[first + start:first + stop] = True
            log.warning("%s: on frames %d-%d the labels give a flight, the motion's centre of mass needs %.0f%% "
                        "of body weight there, and every foot that could hold it up moves: the kinematic motion is "
                        "kept there.", method, first + start, first + stop - 1, 100 * support)
    return flags, unheld
