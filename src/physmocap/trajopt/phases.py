"""Contact phases from per-frame contact flags (Rempe et al. 2020, 3.1 "Optimization Variables"): each heel and
toe alternates between contact and flight; the optimiser keeps the type of every phase and (optionally) changes
their durations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..contacts.flights import runs


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


def split_drifting(flags: np.ndarray, points: np.ndarray, limit: float, gap: int) -> np.ndarray:
    """(T, P) contact flags with every contact run whose point drifts along the floor split in two by `gap` frames
    of flight, again in each part, until no part's point (T, P, 2 floor coordinates of the input motion) lies
    farther than `limit` from the part's median position. A contact phase holds its point still (no slip), so a
    foot that shuffles or pivots while labelled in contact (the motion capture of CMU subject 131: a toe 25 cm
    in 3 s) needs a new phase, not one position for all. The gap goes where the two parts' positions scatter
    least about their means, among the frames in which another point stays in contact, from the frame before to
    the frame after (the body keeps a support: a whole-body flight the input does not fly would launch it); runs
    with no such place stay whole. The parts keep at least `gap` frames. limit 0: flags unchanged."""
    flags = np.asarray(flags, bool).copy()
    if limit <= 0:
        return flags
    gap = max(1, gap)

    def split(i: int, a: int, b: int) -> None:
        p = points[a:b, i]
        if b - a < 3 * gap or np.linalg.norm(p - np.median(p, axis=0), axis=1).max() <= limit:
            return
        first = np.concatenate([np.zeros((1, 2)), np.cumsum(p, axis=0)])
        second = np.concatenate([[0.0], np.cumsum((p ** 2).sum(axis=1))])

        def scatter(lo, hi):  # sum of squared distances from the mean over p[lo:hi]
            return second[hi] - second[lo] - ((first[hi] - first[lo]) ** 2).sum(axis=-1) / (hi - lo)

        lo = np.arange(gap, b - a - 2 * gap + 1)
        others = np.delete(flags[a:b], i, axis=1).any(axis=1)
        # Supported from the frame before the gap to the frame after: a support whose own phase began or ended
        # at the gap would carry no force there (forces fade to zero where a phase meets a flight).
        supported = np.array([others[k - 1:k + gap + 1].all() for k in lo], bool)
        if not supported.any():
            return
        cost = np.where(supported, [scatter(0, k) + scatter(k + gap, b - a) for k in lo], np.inf)
        k = a + int(lo[np.argmin(cost)])
        flags[k:k + gap, i] = False
        split(i, a, k)
        split(i, k + gap, b)

    for i in range(flags.shape[1]):
        starts, lengths = runs(flags[:, i])
        for s, n in zip(starts, lengths, strict=True):
            if flags[s, i]:
                split(i, int(s), int(s + n))
    return flags


def contact_phases(flags: np.ndarray, times: np.ndarray) -> list[Phase]:
    """(T,) bool flags of one contact point at frame times (T,) seconds -> its phases, in time order."""
    starts, lengths = runs(flags)
    phases = []
    for s, n in zip(starts, lengths, strict=True):
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


def segment_count(duration: float, minimum: int, per_seconds: float, longest: float = np.inf,
                  shortest: float = 0.0) -> int:
    """Polynomials of a phase (Rempe C.1): at least `minimum`, more in proportion for phases longer than
    `per_seconds`, none shorter than `shortest` seconds (one for a shorter phase) and none longer than `longest`
    (which wins where the two disagree)."""
    count = max(minimum, int(np.ceil(minimum * duration / per_seconds - 1e-9)))
    if shortest > 0:
        count = min(count, max(1, int(np.floor(duration / shortest + 1e-9))))
    if np.isfinite(longest) and longest > 0:
        count = max(count, int(np.ceil(duration / longest - 1e-9)))
    return count
