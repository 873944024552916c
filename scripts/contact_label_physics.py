"""Whether the automatic contact labels agree with the forces the motion implies: where no sole site is labelled
in contact the body is in flight, so the force its centre of mass implies there should be about zero.

For each label speed threshold (`LabelSettings.contact_max_speed`), over the usable clips of the training and of
the held-out subjects resampled to 30 fps: the number of label-flight frames (no site in contact) and, in them,
the implied net force (`metrics.implied_grf`) in % of body weight, as
- the median and the share over 50 % of its vertical component, with a segment-weighted centre of mass (de Leva
  mass fractions at the segment midpoints of the 20 joints; the trunk from pelvis to neck, the feet from heel to
  toe), and
- the median of its magnitude with the mean of the 20 joints standing in for the centre of mass, the measure of
  the 'ballistic GRF' metric as benchmarks/bench_trajopt.py applies it to the true motion. Noise in a second
  difference has a positive magnitude, and limbs swinging in flight move the joint mean, so this measure stays
  well above zero even for real flights.

    .venv/bin/python scripts/contact_label_physics.py [MOCAP_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np

from physmocap import metrics
from physmocap.body.anthropometry import DE_LEVA_MALE
from physmocap.contacts.dataset import load_clips, mocap_files, split_by_subject
from physmocap.contacts.labels import CONTACT_SITE_INDICES, LabelSettings, contact_labels
from physmocap.mocap.bvh_reader import JOINT_INDEX
from physmocap.mocap.synthetic import resample

FPS = 30.0
SPEEDS = (0.6, 0.8, 1.0, 1.5)  # m/s
SUPPORT_SHARE = 50.0  # % of body weight that a label-flight frame should not carry

# (mass fraction, proximal joint, distal joint): each segment's mass at the midpoint of its two joints.
_TRUNK = DE_LEVA_MALE["upper_trunk"].mass_fraction + DE_LEVA_MALE["middle_trunk"].mass_fraction + \
    DE_LEVA_MALE["lower_trunk"].mass_fraction
SEGMENTS: tuple[tuple[float, str, str], ...] = (
    (_TRUNK, "pelvis", "neck"), (DE_LEVA_MALE["head"].mass_fraction, "neck", "head"),
) + tuple(
    (DE_LEVA_MALE[segment].mass_fraction, f"{side}_{proximal}", f"{side}_{distal}")
    for side in ("left", "right")
    for segment, proximal, distal in (("upper_arm", "shoulder", "elbow"), ("forearm", "elbow", "wrist"),
                                      ("thigh", "hip", "knee"), ("shank", "knee", "ankle"), ("foot", "heel", "toe"))
)


def centre_of_mass(positions: np.ndarray) -> np.ndarray:
    """(T, 3) segment-weighted centre of mass of (T, 20, 3) joint positions (the hands go with the forearms)."""
    total = sum(fraction for fraction, _, _ in SEGMENTS)
    return sum(fraction * 0.5 * (positions[:, JOINT_INDEX[a]] + positions[:, JOINT_INDEX[b]])
               for fraction, a, b in SEGMENTS) / total


def flight_forces(clips, settings: LabelSettings) -> dict[str, float]:
    """Label-flight frames of the clips at FPS and the forces implied there (module docstring)."""
    vertical, magnitude = [], []
    for clip in clips:
        positions = resample(clip, FPS).positions
        flight = ~contact_labels(positions[:, CONTACT_SITE_INDICES], FPS, settings).any(axis=1)
        weight = 9.81  # N: the weight of the unit mass whose forces implied_grf gives
        vertical.append(100.0 * metrics.implied_grf(centre_of_mass(positions), 1.0, FPS)[flight, 2] / weight)
        mean_joint = metrics.implied_grf(positions.mean(axis=1), 1.0, FPS)[flight]
        magnitude.append(100.0 * np.linalg.norm(mean_joint, axis=1) / weight)
    vertical, magnitude = np.concatenate(vertical), np.concatenate(magnitude)
    if len(vertical) == 0:
        return {"frames": 0}
    return {"frames": len(vertical), "vertical_median": float(np.median(vertical)),
            "vertical_over_half": float(np.mean(vertical > SUPPORT_SHARE)),
            "joint_mean_magnitude_median": float(np.median(magnitude))}


def main() -> None:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap"
    train_files, test_files = split_by_subject(mocap_files(root))
    groups = {"training subjects": load_clips(train_files), "held-out subjects": load_clips(test_files)}
    print("| speed m/s | subjects | label-flight frames | vertical GRF median % BW | share over 50 % BW | "
          "joint-mean magnitude median % BW |")
    print("|---|---|---|---|---|---|")
    for speed in SPEEDS:
        for name, clips in groups.items():
            f = flight_forces(clips, LabelSettings(contact_max_speed=speed))
            print(f"| {speed} | {name} | {f['frames']} | {f.get('vertical_median', np.nan):.0f} | "
                  f"{f.get('vertical_over_half', np.nan):.2f} | {f.get('joint_mean_magnitude_median', np.nan):.0f} |")


if __name__ == "__main__":
    main()
