"""Where the contact networks' held-out synthetic errors are: per clip, per skeleton (raw CMU, subject 131, or
the CC3 retarget, subject 6) and contact point, by the detector's confidence, by the length of the label run an
entry lies in, by the true site's distance to the label thresholds (r = max(height / 5 cm, speed / 1.0 m/s), in
contact below 1 before short runs merge), in two kinds of motion (a raised heel: heel not in contact, 5-12 cm up
and slower than 1.0 m/s, while the toe of the same foot is; a site within 5 cm of the floor but faster than
1.0 m/s), and, for false contacts and missed ones, how far the true 3D site was from the label thresholds.

The held-out sequences are benchmarks/bench_contacts.py's (test subjects, seed 1, 4 per clip,
`held_out_settings`); the 3D sites are those the labels were computed from (the played motion, at the frame each
resampled frame's label came from, mirrored columns swapped back).

    .venv/bin/python scripts/contact_errors.py [--weights DIR]
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np

from physmocap.contacts import dataset
from physmocap.contacts.labels import CONTACT_SITE_INDICES, CONTACT_SITES, point_speed
from physmocap.contacts.predict import MODES, WEIGHTS_DIR, load_weights, network_probabilities

MOCAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap"
RAW_CMU_SUBJECTS = ("131",)  # held-out subjects on the raw CMU skeleton; subject 6 is on the CC3 retarget
CONFIDENCE_COLUMNS = (29, 31, 30, 32)  # MediaPipe heel / foot index of l heel, l toe, r heel, r toe


def held_out_with_sites() -> list[tuple[dataset.SyntheticSequence, np.ndarray, np.ndarray]]:
    """(sequence, true site heights (T, 4) m, true site speeds (T, 4) m/s) of the held-out sequences."""
    played = []
    labels = dataset.motion_labels

    def recording(positions, fps, settings):  # the played motion that synthesise labels
        played.append((positions.copy(), fps, settings))
        return labels(positions, fps, settings)

    dataset.motion_labels = recording
    try:
        _, test_files = dataset.split_by_subject(dataset.mocap_files(MOCAP))
        clips = dataset.load_clips(test_files)
        played.clear()
        sequences = dataset.make_sequences(clips, 1, dataset.held_out_settings(), variants=4)
    finally:
        dataset.motion_labels = labels
    result = []
    for sequence, (positions, fps, settings) in zip(sequences, played):
        sites = positions[:, CONTACT_SITE_INDICES]
        speed = point_speed(sites, fps, settings.contact_speed_interval, centred=False)
        source = np.minimum(np.rint(np.arange(sequence.num_frames) * fps / sequence.fps).astype(int), len(positions) - 1)
        height, speed = sites[source, :, 2], speed[source]
        if not np.array_equal(labels(positions, fps, settings)[0][source], sequence.contacts):  # mirrored
            height, speed = height[:, dataset.MIRRORED_CONTACT_COLUMNS], speed[:, dataset.MIRRORED_CONTACT_COLUMNS]
        result.append((sequence, height, speed))
    return result


def run_lengths(flags: np.ndarray, fps: float) -> np.ndarray:
    """(T, K) seconds of the run of equal flags each entry lies in."""
    lengths = np.zeros(flags.shape)
    for k in range(flags.shape[1]):
        bounds = np.r_[0, np.flatnonzero(np.diff(flags[:, k].astype(np.int8))) + 1, len(flags)]
        for start, end in zip(bounds[:-1], bounds[1:]):
            lengths[start:end, k] = (end - start) / fps
    return lengths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--weights", type=Path, default=WEIGHTS_DIR)
    args = parser.parse_args()
    cases = held_out_with_sites()
    for mode in MODES:
        params = load_weights(mode, args.weights)
        wrong, truth, said, confidence, run, height, speed, raw = [], [], [], [], [], [], [], []
        per_clip = defaultdict(lambda: np.zeros(4))
        for sequence, site_height, site_speed in cases:
            _, flags = network_probabilities(sequence.keypoints_2d, sequence.valid, sequence.fps, params, mode)
            error = flags[:, :4] != sequence.contacts
            clip = per_clip[sequence.name.split("#")[0]]
            clip += (error.sum(), error.size, (error & flags[:, :4]).sum(), (error & ~flags[:, :4]).sum())
            wrong.append(error), truth.append(sequence.contacts), said.append(flags[:, :4])
            confidence.append(sequence.keypoints_2d[:, CONFIDENCE_COLUMNS, 2])
            run.append(run_lengths(sequence.contacts, sequence.fps))
            height.append(site_height), speed.append(site_speed)
            raw.append(np.full(error.shape, sequence.subject in RAW_CMU_SUBJECTS))
        wrong, truth, said, confidence, run, height, speed, raw = map(
            np.concatenate, (wrong, truth, said, confidence, run, height, speed, raw))
        errors = wrong.sum()
        print(f"## {mode} network: accuracy {1 - wrong.mean():.3f}, {errors} errors "
              f"({(wrong & said).sum()} false contacts, {(wrong & ~said).sum()} missed)")
        print("per clip: entries, accuracy, share of errors, false contacts, missed")
        for name, (e, n, fp, fn) in sorted(per_clip.items()):
            print(f"  {name}: {int(n)}, {1 - e / n:.3f}, {e / errors:.2f}, {int(fp)}, {int(fn)}")
        print("per site accuracy: " + ", ".join(f"{site} {1 - wrong[:, k].mean():.3f}" for k, site in enumerate(CONTACT_SITES)))
        print("per skeleton: share of entries, accuracy, heel accuracy, toe accuracy, share of errors")
        for name, inside in (("raw CMU", raw), ("CC3", ~raw)):
            print(f"  {name}: {inside.mean():.2f}, {1 - wrong[inside].mean():.3f}, "
                  f"{1 - wrong[:, [0, 2]][inside[:, [0, 2]]].mean():.3f}, "
                  f"{1 - wrong[:, [1, 3]][inside[:, [1, 3]]].mean():.3f}, {wrong[inside].sum() / errors:.2f}")
        ratio = np.maximum(height / 0.05, speed / 1.0)
        print("by r = max(height / 5 cm, speed / 1 m/s): range, share of entries, accuracy, share of errors, "
              "share labelled contact")
        for low, high in zip((0, 0.5, 0.8, 1.0, 1.25, 2.0), (0.5, 0.8, 1.0, 1.25, 2.0, np.inf)):
            inside = (ratio >= low) & (ratio < high)
            print(f"  {low}-{high}: {inside.mean():.3f}, {1 - wrong[inside].mean():.3f}, "
                  f"{wrong[inside].sum() / errors:.2f}, {truth[inside].mean():.2f}")
        raised = np.zeros_like(wrong)
        for heel, toe in ((0, 1), (2, 3)):
            raised[:, heel] = (~truth[:, heel] & truth[:, toe] & (height[:, heel] > 0.05) & (height[:, heel] < 0.12)
                               & (speed[:, heel] < 1.0))
        skimming = ~truth & (height < 0.05) & (speed >= 1.0) & ~raised
        for name, inside in (("raised heel", raised), ("low and fast", skimming)):
            print(f"{name}: {inside.sum()} entries, accuracy {1 - wrong[inside].mean():.3f}, "
                  f"share of errors {wrong[inside].sum() / errors:.2f}")
        for name, values, bins in (("detector confidence", confidence, (0, 0.5, 0.8, 0.95, 1.01)),
                                   ("label run, s", run, (0, 0.1, 0.2, 0.4, 1.0, np.inf))):
            print(f"by {name}: range, share of entries, accuracy, share of errors")
            for low, high in zip(bins[:-1], bins[1:]):
                inside = (values >= low) & (values < high)
                print(f"  {low}-{high}: {inside.mean():.3f}, {1 - wrong[inside].mean():.3f}, {wrong[inside].sum() / errors:.2f}")
        false, missed = wrong & said, wrong & ~said
        high, fast = height >= 0.05, speed >= 1.0
        print("false contacts (label no) where the site was: "
              f"too high only {(false & high & ~fast).sum()} (5-8 cm: {(false & (height < 0.08) & high & ~fast).sum()}), "
              f"too fast only {(false & fast & ~high).sum()} (1-1.5 m/s: {(false & ~high & fast & (speed < 1.5)).sum()}), "
              f"both {(false & high & fast).sum()}, neither (short runs merged) {(false & ~high & ~fast).sum()}")
        print(f"missed contacts (label yes) with the site at 3-5 cm: {(missed & (height > 0.03)).sum()}, "
              f"moving 0.6-1.0 m/s: {(missed & (speed > 0.6)).sum()}, either: "
              f"{(missed & ((height > 0.03) | (speed > 0.6))).sum()}")
        print()


if __name__ == "__main__":
    main()
