"""The centre of mass's vertical path through the frame interval that starts a flight of the contact labels.

Between two frames the tracker aims at the chord of their poses. Across a take-off that chord is far slower than the
jump: at 10 fps a standing jump's chord rises at 2.4 m/s where the flight needs 3.5 m/s at the switch of contacts, so
the character left the floor too slowly and its apex was 13 cm low (docs/decisions/physics-frame-rate.md). With the
whole clip known, the interval before a flight's first frame is a push at constant acceleration from the last
contact frame's height and velocity onto the flight's parabola, which gravity and the flight's frames fix. Meeting
the parabola in height and in velocity gives both the push and the instant the contacts switch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..motion import valid_runs


@dataclass(frozen=True)
class TakeOffPath:
    """The centre of mass's height through a frame interval of `interval` s that ends at a flight's first frame:
    from the contact frame's `height` (m) and vertical `velocity` (m/s), at the constant acceleration `push`
    (m/s^2) until `switch` (the share of the interval, 0-1, at which the contacts let go), then on the flight's
    parabola under `gravity` (m/s^2) through the flight frame's `flight_height` (m) at `flight_velocity` (m/s)."""

    switch: float
    height: float
    velocity: float
    push: float
    flight_height: float
    flight_velocity: float
    interval: float
    gravity: float

    def offsets(self, share: float) -> tuple[float, float, float]:
        """At `share` (0-1) of the interval: the path's height minus the chord's between the two frames (m), its
        vertical velocity minus the chord's (m/s), and its acceleration (m/s^2)."""
        if share < self.switch:
            s, z, v, a = share * self.interval, self.height, self.velocity, self.push
        else:
            s, z, v, a = (share - 1.0) * self.interval, self.flight_height, self.flight_velocity, -self.gravity
        rise = self.flight_height - self.height
        return z + v * s + 0.5 * a * s * s - (self.height + share * rise), v + a * s - rise / self.interval, a


def flight_velocity(heights: np.ndarray, interval: float, gravity: float) -> float:
    """m/s: the vertical velocity at the first of a flight's frame heights (F,) m (F >= 2, `interval` s apart) of
    the parabola under gravity (m/s^2) through that first height that fits the others best (least squares)."""
    s = np.arange(1, len(heights)) * interval
    return float(s @ (heights[1:] - heights[0] + 0.5 * gravity * s * s) / (s @ s))


def push_onto_parabola(height: float, velocity: float, arc_height: float, arc_velocity: float, interval: float,
                       gravity: float, max_push: float = np.inf) -> tuple[float, float] | None:
    """A constant-acceleration push from a contact frame's height (m) and vertical velocity (m/s) onto a flight's
    parabola under gravity (m/s^2), given by its height and velocity extrapolated to the contact frame's instant
    (m, m/s). Returns (its duration s, within (0, interval), and its acceleration m/s^2), or None where the
    parabola cannot be met within the interval, or only by a push that does not bear on the floor or accelerates
    the body faster than max_push m/s^2 (the labels and the motion disagree: the chord is kept). Meeting it at s
    in height and velocity, height + s (velocity + v_arc(s)) / 2 = z_arc(s) with z_arc(s) = arc_height +
    arc_velocity s - g s^2 / 2, is linear in s."""
    if arc_velocity <= velocity:
        return None
    duration = 2.0 * (height - arc_height) / (arc_velocity - velocity)
    if not 0.0 < duration < interval:
        return None
    push = (arc_velocity - gravity * duration - velocity) / duration
    return (duration, push) if -gravity < push <= max_push else None


def path_onto_parabola(height: float, velocity: float, flight_height: float, flight_velocity: float, interval: float,
                       gravity: float, max_push: float = np.inf) -> TakeOffPath | None:
    """The TakeOffPath from a contact frame's centre of mass `height` (m) rising at `velocity` (m/s) onto the
    parabola through the next frame's `flight_height` (m) at `flight_velocity` (m/s), `interval` s later; None
    where no push meets it (push_onto_parabola)."""
    arc_height = flight_height - flight_velocity * interval - 0.5 * gravity * interval * interval
    push = push_onto_parabola(height, velocity, arc_height, flight_velocity + gravity * interval, interval, gravity,
                              max_push)
    return None if push is None else TakeOffPath(push[0] / interval, height, velocity, push[1], flight_height,
                                                 flight_velocity, interval, gravity)


def take_off_paths(heights: np.ndarray, contacts: np.ndarray, usable: np.ndarray, fps: float,
                   gravity: float, max_force: float = np.inf) -> dict[int, TakeOffPath]:
    """The TakeOffPath of each flight's take-off interval, keyed by the flight's first frame. heights (T,) m: the
    targets' centre of mass; contacts (T, 4) bool: the labels the tracker takes (a flight: frames with none); usable
    (T,) bool: the frames the character tracks. A flight gets a path where it lasts at least two frames (its
    parabola's velocity, fitted under gravity m/s^2, needs two) and its last two contact frames are usable (the
    velocity at the last, a centred difference: a backward one lags the push by half a frame), and where the push
    needs no more than max_force body weights (the bound the physics holds every force to)."""
    interval, paths = 1.0 / fps, {}
    airborne = ~np.asarray(contacts, bool).any(axis=1) & usable
    for first, stop in valid_runs(airborne):
        before = first - 1  # the last contact frame
        if stop - first < 2 or before < 1 or not usable[before - 1:first].all():
            continue
        velocity = float(heights[first] - heights[before - 1]) / (2.0 * interval)
        path = path_onto_parabola(float(heights[before]), velocity, float(heights[first]),
                                  flight_velocity(heights[first:stop], interval, gravity), interval, gravity,
                                  (max_force - 1.0) * gravity)
        if path is not None:
            paths[first] = path
    return paths
