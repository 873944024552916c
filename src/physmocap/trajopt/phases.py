"""Contact phases from per-frame contact flags (Rempe et al. 2020, 3.1 "Optimization Variables"): each heel and
toe alternates between contact and flight; the optimiser keeps the type of every phase and (optionally) changes
their durations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Phase:
    """One phase of one contact point: in contact or in flight from `start` to `end` (seconds). A phase boundary
    lies halfway between the last frame of one phase and the first of the next; the first phase starts at the
    first frame's time, the last ends at the last frame's time."""

    contact: bool
    start: float
    end: float

    @property
    def duration(self) -> float:
        return self.end - self.start


def clean_flags(flags: np.ndarray, min_frames: int) -> np.ndarray:
    """(T,) bool flags with every run shorter than `min_frames` frames merged into its neighbours (shortest run
    first), so that a single flickering frame does not make a phase of its own. A clip shorter than
    `min_frames` keeps its majority."""
    flags = np.asarray(flags, bool).copy()
    if min_frames <= 1 or len(flags) == 0:
        return flags
    if len(flags) < min_frames:
        return np.full(len(flags), flags.mean() >= 0.5)
    while True:
        starts, lengths = runs(flags)
        if len(starts) <= 1:
            return flags
        k = int(np.argmin(lengths))
        if lengths[k] >= min_frames:
            return flags
        flags[starts[k]:starts[k] + lengths[k]] = ~flags[starts[k]]


def runs(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start indices and lengths of the runs of equal values in a (T,) array."""
    flags = np.asarray(flags)
    if len(flags) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    change = np.flatnonzero(flags[1:] != flags[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(flags)]])
    return starts, ends - starts


def contact_phases(flags: np.ndarray, times: np.ndarray) -> list[Phase]:
    """(T,) bool flags of one contact point at frame times (T,) seconds -> its phases, in time order."""
    starts, lengths = runs(flags)
    phases = []
    for s, n in zip(starts, lengths):
        last = s + n - 1
        start = times[0] if s == 0 else 0.5 * (times[s - 1] + times[s])
        end = times[-1] if last == len(times) - 1 else 0.5 * (times[last] + times[last + 1])
        phases.append(Phase(bool(flags[s]), float(start), float(end)))
    return phases


def flags_from_phases(phases: list[Phase], times: np.ndarray) -> np.ndarray:
    """(T,) bool: the contact flag of each frame time under the phases (the inverse of `contact_phases`)."""
    out = np.zeros(len(times), bool)
    for p in phases:
        if p.contact:
            out[(times >= p.start - 1e-9) & (times <= p.end + 1e-9)] = True
    # A frame exactly on a boundary belongs to the later phase.
    for p in phases:
        on_start = np.abs(times - p.start) < 1e-9
        out[on_start] = p.contact
    return out


def segment_count(duration: float, minimum: int, per_seconds: float, longest: float = np.inf) -> int:
    """Polynomials of a phase (Rempe C.1): at least `minimum`, more in proportion for phases longer than
    `per_seconds`, and none longer than `longest` seconds."""
    count = max(minimum, int(np.ceil(minimum * duration / per_seconds - 1e-9)))
    if np.isfinite(longest) and longest > 0:
        count = max(count, int(np.ceil(duration / longest - 1e-9)))
    return count
