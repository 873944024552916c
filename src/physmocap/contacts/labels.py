"""Automatic foot-contact and stationary labels from 3D motion (the supervision of the contact networks).

Rule: Rempe et al. 2020, Sec. 3.2, with a larger speed threshold and both sides of the frame. A heel or toe site is
in contact when (i) it moves slower than 1.0 m/s, measured over one 30 fps frame interval (a fixed time, so that
the rule means the same at 12, 30, 60 or 120 fps) before the frame or the one after it, whichever is slower, and
(ii) it is within 5 cm of the known floor. Rempe's own (i) is "moved less than 2 cm" since the previous frame of
30 fps video, 0.6 m/s.

Why either side (`LabelSettings.rest_on_either_side`): a site lands in the frame where it comes to rest, but the
interval before that frame still holds its approach, so Rempe's reading calls every landing frame in the air, a
frame later than a person looking at the video (and than PhysCap's instantaneous speed); take-offs are unaffected,
the last resting frame being still since the one before it. The change adds contact to 1.0 % of the training
subjects' entries at 30 fps, all of them landing frames, and nothing else. Networks trained on it (subjects 1
and 7 held out, 48 variants, 2 epochs, mirrored votes, data seeds 0-2; `scripts/contact_validation.py
--rest-on-either-side`) scored 0.943 / 0.949 / 0.946 on their validation subjects against 0.941 / 0.946 / 0.944
with the backward labels (each against its own labels), and on the hand-labelled real frames 0.948 / 0.945 /
0.946 against 0.931 / 0.934 / 0.929 (causal, data seed 0: 0.936 against 0.923): the networks had been finding
landings a frame or two late (the walk's heel strikes and toe-downs, the landings of the jumping jacks).

Why Rempe's rule and not PhysCap's (Sec. 4.2: speed under 5 cm/s and height under the clip's standing height of
the first ten frames plus 5 cm):
- The floor is known. `load_mocap` puts the floor at z = 0 under the sole sites, so a fixed height above the
  floor needs no assumption about the clip's first frames; PhysCap's reference height assumes both feet are flat
  on the floor in the first ten frames, which is false for clips that start mid-jump, in a cartwheel or on one
  leg (CMU 01_01, 05_06, 02_04 here).
- 5 cm/s is below the noise of differentiated motion capture: 1 mm of marker jitter between 120 fps frames is
  already 12 cm/s, and a planted heel rolls and a planted toe pivots during push-off. On the CMU walk 02_01 the
  PhysCap rule marks 7-17 % of the frames as contact, in scattered single frames, where the feet are planted about
  half of the time; Rempe's rule gives one unbroken contact per step (scripts/plot_contact_labels.py).

Why 1.0 m/s and not Rempe's 0.6 (scripts/contact_label_physics.py, training subjects 1, 2, 5, 7 at 30 fps; measured
with the speed over the interval before each frame only):
- Supporting feet move faster than 0.6 m/s: a foot that lands and slides, a toe that pivots under the body's
  weight during push-off, a heel that rolls. Where no site is labelled in contact the body must be falling, so
  the vertical force the motion's centre of mass implies there (segment-weighted CoM, de Leva fractions) should
  be about zero. It exceeds half the body weight in 31 % of the label-flight frames at 0.6 m/s, 27 % at 0.8,
  24 % at 1.0 and 22 % at 1.5 (the rest of those are next to a take-off or landing, where the acceleration's
  second difference reaches into the contact frames): most of the gain is reached by 1.0.
- Labels near a threshold that the feet's measured speed often crosses cannot be recovered from noisy positions.
  With the measured MediaPipe keypoint errors added to the true 3D sites (scripts/contact_label_ceiling.py) the
  rule reproduces its clean labels in 90.0 % of the entries at 0.6 m/s, 96.8 % at 0.8, 97.6 % at 1.0 and
  98.0 % at 1.5.
- The hand labels of the real videos call a foot that slides or turns on the ground in contact
  (benchmarks/labels/contacts_real.md); so does the rule now for slides up to 1.0 m/s. Swinging feet pass the
  floor faster (1-4 m/s) and stay out of contact.
Rempe's 0.6 m/s remains a setting (`LabelSettings.contact_max_speed`).

The sites and the floor the labels read were checked against the BVH's own joints on both skeletons
(scripts/contact_label_geometry.py; neither has a heel joint, `bvh_reader.sole_sites` derives heel and toe). In
flat stance (heel and toe still and in contact) the derived heel and toe of every held-out clip sit 0.0-1.9 cm
and -0.7-1.3 cm above the clip's floor (training walk 02_01: 1.5 and 0.2 cm). Where a heel is labelled off while
its toe is down, 5-12 cm up and slow (most of them in 131_02, 4.5 s of stances on the ball of the foot), the
BVH's ankle joint is 3.4-7.3 cm (median per foot and clip) above its flat-stance height, 0.66-0.82 times the
heel's rise, as a foot turning about its MTP joint gives; a heel placed too high by a wrong pitch or floor would
leave the ankle where it was. Raw CMU glitches of subject 131 reach the sites only briefly: a left toe site more
than 3 cm under the floor for 0.32 s of 131_01 (t = 2.8-3.7 s, the foot pitched 50-65 degrees down on a still
ankle) and 0.37 s of 131_02 (t = 1.41-1.77 s, down to 7.7 cm), both labelled in contact as the foot is; and at
frame 0 of 131_02 the left foot pitched 8 degrees toes-up, its toe site 7.5 cm above the heel (toe labelled off
for 0.13 s).

Stationary (PhysCap Sec. 4.2): the root (pelvis, the midpoint of the hips) moves slower than a threshold. The paper
gives no value; 0.25 m/s, measured over 0.2 s, separates standing, swaying and fighting on the spot (median root
speed 0.07-0.11 m/s in CMU 02_05, 02_07, 02_10) from walking (5th percentile 0.47 m/s in the slowest walk here,
03_01; 0.8 m/s in the "slow walk" 07_04).

Every function is a pure function of positions (metres, world frame Z up, floor z = 0) and the frame rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..mocap.bvh_reader import JOINT_INDEX

CONTACT_SITES: tuple[str, ...] = ("left_heel", "left_toe", "right_heel", "right_toe")
"""The four contact points, in the project's order; columns of every contact array."""
CONTACT_SITE_INDICES: tuple[int, ...] = tuple(JOINT_INDEX[name] for name in CONTACT_SITES)


@dataclass(frozen=True)
class LabelSettings:
    """Thresholds of the automatic labels, SI units.

    contact_max_height: m above the floor (z = 0) a site may be and still touch it. Rempe 3.2: 0.05.
        Typical range 0.02-0.08 (sole sites of retargeted mocap sit within 1-2 cm of the floor when planted).
    contact_max_speed: m/s a site may move and still be in contact: 1.0 (see the module docstring). Rempe 3.2:
        2 cm between frames at 30 fps, 0.6 m/s. Range 0.05 (PhysCap's 5 cm/s, needs smoothed motion) to 1.5.
    contact_speed_interval: s over which a site's displacement is measured (one frame at Rempe's 30 fps): 1/30.
        Where frames are further apart, one frame interval is used.
    stationary_max_speed: m/s the root may move for the pose to count as stationary (PhysCap's phi_v, no value
        given). 0.25; range 0.1-0.5.
    stationary_speed_interval: s over which the root's displacement is measured, centred on the frame: 0.2.
    rest_on_either_side: judge the speed over the interval before the frame or the one after it, whichever is
        slower: a site comes to rest in the frame it lands in (the interval before it still holds its approach)
        and leaves after the last one it rests in. False: the interval before only, as Rempe's rule reads.
    min_phase_seconds: contact and no-contact runs shorter than this are merged into their neighbours (ours, the
        papers label frame by frame): a planted foot whose speed crosses the threshold for one frame while it
        rolls, or a swinging toe that grazes the 5 cm band for one frame, flickers, and no detector could follow
        it. Range 0 (off) to 0.2.
    """

    contact_max_height: float = 0.05
    contact_max_speed: float = 1.0
    contact_speed_interval: float = 1.0 / 30.0
    stationary_max_speed: float = 0.25
    stationary_speed_interval: float = 0.2
    rest_on_either_side: bool = True
    min_phase_seconds: float = 0.1

    def check(self) -> None:
        for name in ("contact_max_height", "contact_max_speed", "contact_speed_interval", "stationary_max_speed",
                     "stationary_speed_interval"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise InputError(f"LabelSettings.{name} is {value}, expected a positive number.")
        if not np.isfinite(self.min_phase_seconds) or self.min_phase_seconds < 0:
            raise InputError(f"LabelSettings.min_phase_seconds is {self.min_phase_seconds}, expected 0 or more.")


def point_speed(points: np.ndarray, fps: float, interval: float, centred: bool) -> np.ndarray:
    """Speed of points from their displacement over a time interval, m/s.

    points: (T, ..., 3) metres at `fps` frames per second. interval: seconds, at least one frame.
    centred: measure from t - interval/2 to t + interval/2; otherwise from t - interval to t (the first frames,
        which have no past, use t to t + interval). Positions between frames are interpolated linearly, and the
        interval is shortened at the clip's ends.
    Returns (T, ...) speeds, m/s; zeros for a single frame.
    """
    num_frames = len(points)
    if num_frames < 2:
        return np.zeros(points.shape[:-1])
    frames = max(interval * fps, 1.0)
    times = np.arange(num_frames, dtype=float)
    if centred:
        start, end = times - 0.5 * frames, times + 0.5 * frames
    else:
        start, end = times - frames, times.copy()
        end = np.where(start < 0, frames, end)
    start = np.clip(start, 0.0, num_frames - 1)
    end = np.clip(end, 0.0, num_frames - 1)
    displacement = _interpolate(points, end) - _interpolate(points, start)
    seconds = np.maximum(end - start, 1e-9) / fps
    return np.linalg.norm(displacement, axis=-1) / seconds.reshape((-1,) + (1,) * (points.ndim - 2))


def _interpolate(points: np.ndarray, frame_positions: np.ndarray) -> np.ndarray:
    """points (T, ..., 3) linearly interpolated at fractional frame positions (N,) in [0, T - 1]."""
    lower = np.minimum(np.floor(frame_positions).astype(int), len(points) - 2)
    weight = (frame_positions - lower).reshape((-1,) + (1,) * (points.ndim - 1))
    return (1.0 - weight) * points[lower] + weight * points[lower + 1]


def without_short_phases(flags: np.ndarray, min_frames: int) -> np.ndarray:
    """flags (T, K) bool with runs shorter than min_frames removed along axis 0: short gaps in a contact are filled
    first (morphological closing), then short contacts dropped (opening). The clip's ends count as continuing
    their first and last runs, so a run that only touches an end is kept. Returns a new array."""
    flags = np.asarray(flags, dtype=bool)
    if min_frames < 2 or len(flags) == 0:
        return flags.copy()
    padded = np.pad(flags, ((min_frames, min_frames), (0, 0)), mode="edge")
    run = np.ones((min_frames, 1), dtype=bool)
    padded = ndimage.binary_opening(ndimage.binary_closing(padded, run), run)
    return padded[min_frames:-min_frames]


def contact_labels(sites: np.ndarray, fps: float, settings: LabelSettings = LabelSettings()) -> np.ndarray:
    """Rempe 3.2 contact labels of the four sole sites.

    sites: (T, 4, 3) world positions of left heel, left toe, right heel, right toe, metres, floor z = 0.
    Returns (T, 4) bool, True where the site is within `contact_max_height` of the floor and moved slower than
    `contact_max_speed` over the `contact_speed_interval` before the frame (or, with `rest_on_either_side`, the
    one before or the one after), then without runs shorter than `min_phase_seconds`.
    """
    settings.check()
    sites = np.asarray(sites, dtype=float)
    if sites.ndim != 3 or sites.shape[1:] != (4, 3):
        raise InputError(f"contact_labels: sites has shape {sites.shape}, expected (T, 4, 3).")
    low, slow = _low_and_slow(sites, fps, settings)
    return without_short_phases(low & slow, int(round(settings.min_phase_seconds * fps)))


def _low_and_slow(sites: np.ndarray, fps: float, settings: LabelSettings) -> tuple[np.ndarray, np.ndarray]:
    """The two halves of the contact rule for sites (T, 4, 3): (T, 4) bool below `contact_max_height`, and (T, 4)
    bool slower than `contact_max_speed` (see `contact_labels`)."""
    speed = point_speed(sites, fps, settings.contact_speed_interval, centred=False)
    if settings.rest_on_either_side:
        speed = np.minimum(speed, point_speed(sites[::-1], fps, settings.contact_speed_interval, centred=False)[::-1])
    return sites[..., 2] < settings.contact_max_height, speed < settings.contact_max_speed


def stationary_labels(root: np.ndarray, fps: float, settings: LabelSettings = LabelSettings()) -> np.ndarray:
    """PhysCap 4.2 stationary flag: root (T, 3) metres slower than `stationary_max_speed`. Returns (T,) bool."""
    settings.check()
    root = np.asarray(root, dtype=float)
    if root.ndim != 2 or root.shape[1] != 3:
        raise InputError(f"stationary_labels: root has shape {root.shape}, expected (T, 3).")
    return point_speed(root, fps, settings.stationary_speed_interval, centred=True) < settings.stationary_max_speed


RAISED_HEEL_MAX_HEIGHT = 0.12  # m: a heel up to this high over its planted toe is a stance on the ball of the foot


def hard_frames(
    sites: np.ndarray, fps: float, contacts: np.ndarray, settings: LabelSettings = LabelSettings()
) -> np.ndarray:
    """Frames in the two kinds of motion where the networks err most on held-out subjects (scripts/contact_errors.py).

    sites: (T, 4, 3) as for `contact_labels`; contacts: their (T, 4) labels. A frame is hard when some site is
    - a raised heel: not in contact, above `contact_max_height` and below RAISED_HEEL_MAX_HEIGHT, slower than
      `contact_max_speed`, while the toe of the same foot is in contact; or
    - skimming: not in contact, below `contact_max_height` but at `contact_max_speed` or faster.
    Returns (T,) bool.
    """
    sites = np.asarray(sites, dtype=float)
    low, slow = _low_and_slow(sites, fps, settings)
    skimming = ~contacts & low & ~slow
    heels, toes = [0, 2], [1, 3]
    raised = (~contacts[:, heels] & contacts[:, toes] & ~low[:, heels]
              & (sites[:, heels, 2] < RAISED_HEEL_MAX_HEIGHT) & slow[:, heels])
    return skimming.any(axis=1) | raised.any(axis=1)


def motion_labels(
    positions: np.ndarray, fps: float, settings: LabelSettings = LabelSettings()
) -> tuple[np.ndarray, np.ndarray]:
    """Contact and stationary labels of a motion on the project's joint set.

    positions: (T, 20, 3) world positions in `JOINT_NAMES` order (a `MocapClip.positions`), metres, floor z = 0.
    Returns contacts (T, 4) bool (CONTACT_SITES order) and stationary (T,) bool.
    """
    positions = np.asarray(positions, dtype=float)
    contacts = contact_labels(positions[:, CONTACT_SITE_INDICES], fps, settings)
    stationary = stationary_labels(positions[:, JOINT_INDEX["pelvis"]], fps, settings)
    return contacts, stationary


def seconds_to_label_change(contacts: np.ndarray, fps: float) -> np.ndarray:
    """(T, 4) seconds from each entry of the labels `contacts` (T, 4) to the nearest change of its site's label,
    inf where it never changes; an entry beside a change is half a frame from it."""
    frames = np.arange(len(contacts))
    distance = np.full(contacts.shape, np.inf)
    for site in range(contacts.shape[1]):
        changes = np.flatnonzero(np.diff(contacts[:, site].astype(np.int8))) + 0.5
        if len(changes):
            distance[:, site] = np.abs(frames[:, None] - changes[None]).min(axis=1) / fps
    return distance
