"""The video's clock against gravity: a body in flight falls at g, so the jumps of a fitted motion show whether its
frames are as far apart in time as the file says. A slow-motion video, or a file that states 10 fps for footage
filmed at 25, makes every jump fall at g times (stated rate / true rate)^2, and physics then explains none of it
(docs/decisions/video-clock.md). Pure numpy on heights and contact flags."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..contacts.flights import flight_parabola, runs
from ..metrics import FLOATING_THRESHOLD, GRAVITY
from ..motion import valid_runs

MIN_FLIGHT_FRAMES = 3  # a parabola is fitted to these and the take-off and landing frames around them; stances too
MIN_RISE = 0.03  # m: the arc's top above both its ends (a fitted centre of mass is steady to about 1 cm)
# A flight is a parabola to within the fitted centre of mass's noise (rms 0.1-0.8 cm on the measured arcs) plus this
# share of its rise; a pull-up's smooth rise, hold and lowering is not (rms 3-5 cm on 0.5 m: video-clock.md)
PARABOLA_NOISE, PARABOLA_SHARE = 0.01, 0.02  # m, 1
CLOCK_TOLERANCE = 2.0  # jumps falling slower than g / this or faster than g * this: the clock is wrong (rate x1.4)


@dataclass(frozen=True)
class FlightArc:
    """One whole-body flight that rises and falls: frames [start, stop), its fall in m/s^2 (the parabola's
    downward curvature, g on a true clock) and its rise, m (the parabola's top above the higher of its ends)."""

    start: int
    stop: int
    fall: float
    rise: float


def airborne(sole_heights: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """(T,) bool: frames with no sole point labelled in contact, or every sole point more than FLOATING_THRESHOLD
    above the floor (Rempe et al.'s 3 cm: off the ground), which touches nothing whatever the labels say: those of a
    slowed video call the top of a jump or a running stride a contact. sole_heights (T, 4) m above the floor,
    contacts (T, 4) bool."""
    return ~np.asarray(contacts, bool).any(axis=1) | (np.asarray(sole_heights) > FLOATING_THRESHOLD).all(axis=1)


def flight_arcs(com_height: np.ndarray, air: np.ndarray, valid: np.ndarray, fps: float) -> list[FlightArc]:
    """The flights of `air` (T,) bool, within runs of `valid` (T,) frames, of at least MIN_FLIGHT_FRAMES between
    stances of as many frames, whose centre-of-mass height (T,) m at `fps` frames/s follows a parabola with its top
    inside the flight and MIN_RISE above both its ends, to within PARABOLA_NOISE + PARABOLA_SHARE x rise (rms). A
    standing body the labels call airborne does not rise; a supported descent has no top; a pull-up is no parabola;
    a person walking into the picture, whom the fit raises out of the floor, has no stance before
    (docs/decisions/video-clock.md)."""
    arcs, times = [], np.arange(len(com_height)) / fps
    for first, end in valid_runs(np.asarray(valid, bool)):
        starts, lengths = runs(air[first:end])
        for k, (s, n) in enumerate(zip(starts.tolist(), lengths.tolist(), strict=True)):
            if not air[first + s] or n < MIN_FLIGHT_FRAMES or k == 0 or k == len(starts) - 1:
                continue
            if min(lengths[k - 1], lengths[k + 1]) < MIN_FLIGHT_FRAMES:  # a jump leaves a stance and lands on one
                continue
            start, stop = first + s, first + s + n  # a stance on either side: the window is the flight and both
            if not np.isfinite(com_height[start - 1:stop + 1]).all():
                continue
            parabola = flight_parabola(com_height, times, start, stop)
            assert parabola is not None, "at least MIN_FLIGHT_FRAMES + 2 frames"
            (a, b, c), t, window = parabola
            if a >= 0:
                continue
            heights = com_height[window]
            top = -b / (2 * a)
            rise = c - b * b / (4 * a) - max(heights[0], heights[-1])
            misfit = float(np.sqrt(np.mean((np.polyval((a, b, c), t) - heights) ** 2)))
            if t[0] < top < t[-1] and rise >= MIN_RISE and misfit <= PARABOLA_NOISE + PARABOLA_SHARE * rise:
                arcs.append(FlightArc(start, stop, float(-2 * a), float(rise)))
    return arcs


@dataclass(frozen=True)
class ClockCheck:
    """What the jumps say of the video's clock: arcs found, the fastest fall among them in m/s^2 (nan without one;
    supported phases only fall slower), the frame rate at which it would be g (nan without arcs), and a warning
    sentence when that is off by more than CLOCK_TOLERANCE in fall ("" otherwise)."""

    arcs: int
    fall: float
    consistent_fps: float
    warning: str

    def to_dict(self) -> dict:
        return asdict(self)


def check_clock(com_height: np.ndarray, sole_heights: np.ndarray, contacts: np.ndarray, valid: np.ndarray,
                fps: float, source: str) -> ClockCheck:
    """The video's clock judged by the jumps (see the module docstring): com_height (T,) and sole_heights (T, 4) m
    above the floor, contacts (T, 4) bool, valid (T,) bool, fps the frame rate the motion was fitted at, source the
    input's name for the warning. A fall scales with the square of the
    rate, so the rate that makes the fastest fall g is fps * sqrt(g / fall)."""
    arcs = flight_arcs(com_height, airborne(sole_heights, contacts), valid, fps)
    if not arcs:
        return ClockCheck(0, float("nan"), float("nan"), "")
    fall = max(arc.fall for arc in arcs)
    consistent = fps * float(np.sqrt(GRAVITY / fall))
    warning = ""
    if not GRAVITY / CLOCK_TOLERANCE <= fall <= GRAVITY * CLOCK_TOLERANCE:
        pace = "slower" if fall < GRAVITY else "faster"
        warning = (f"{source}: its jumps fall at {fall:.1f} m/s^2, not {GRAVITY:.1f}: the video plays {pace} than "
                   f"it was filmed (slow motion, or a wrong frame rate in the file), and physics cannot explain "
                   f"its motion at {fps:g} fps; if it was filmed at about {consistent:.0f} fps, give "
                   f"--fps {consistent:.0f}.")
    return ClockCheck(len(arcs), fall, consistent, warning)
