"""Foot contacts on videos slower than the training rates (issue 17's 10 fps parkour videos, issue 18's networks):
both networks on synthetic sequences filmed at 8 and 10 fps, read as they are and read at a multiple of their rate
with frames interpolated (`contacts.predict.LOWEST_TRAINED_FPS`, the shipped behaviour).

    .venv/bin/python benchmarks/bench_contacts_slow_videos.py [--subjects test|validation] [--clips N]

test: the held-out subjects of bench_contacts.py (seed 1, 2 sequences per clip); validation: N clips of the
training subjects under new draws (seed 7), where the rule was chosen. Writes
benchmarks/results/contacts_slow_videos_SUBJECTS.json and .md.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import bench_contacts  # noqa: E402
from common import MOCAP, RESULTS, git_revision, machine_description  # noqa: E402
from physmocap.contacts import dataset, predict  # noqa: E402

RATES = (8.0, 10.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--subjects", choices=("test", "validation"), default="test")
    parser.add_argument("--clips", type=int, default=40, help="validation: clips drawn from the training subjects")
    args = parser.parse_args()
    train_files, test_files = dataset.split_by_subject(dataset.mocap_files(MOCAP))
    if args.subjects == "test":
        files, seed = test_files, 1
    else:
        pick = np.random.default_rng(0).choice(len(train_files), min(args.clips, len(train_files)), replace=False)
        files, seed = [train_files[i] for i in sorted(pick)], 7
    clips = dataset.load_clips(files)
    rows = []
    for fps in RATES:
        settings = dataclasses.replace(dataset.held_out_settings(dataset.SyntheticSettings()), fps_range=(fps, fps))
        sequences = dataset.make_sequences(clips, seed, settings, variants=2)
        for reading, lowest in (("as filmed", 0.0), ("interpolated", predict.LOWEST_TRAINED_FPS)):
            shipped, predict.LOWEST_TRAINED_FPS = predict.LOWEST_TRAINED_FPS, lowest
            try:
                for mode in predict.MODES:
                    flags, truth, still, still_truth = [], [], [], []
                    for sequence in sequences:
                        contacts, stationary, _ = predict.predict_contacts(bench_contacts.as_observations(sequence),
                                                                           mode)
                        flags.append(contacts)
                        truth.append(sequence.contacts)
                        still.append(stationary)
                        still_truth.append(sequence.stationary)
                    score = bench_contacts.scores(np.concatenate(flags), np.concatenate(truth))
                    rows.append(dict(fps=fps, reading=reading, network=mode, accuracy=score["accuracy"],
                                     f1=score["f1"], entries=score["entries"],
                                     stationary_accuracy=float(np.mean(np.concatenate(still)
                                                                       == np.concatenate(still_truth)))))
                    print(rows[-1], flush=True)
            finally:
                predict.LOWEST_TRAINED_FPS = shipped
    name = f"contacts_slow_videos_{args.subjects}"
    (RESULTS / f"{name}.json").write_text(json.dumps(dict(subjects=args.subjects, clips=len(clips), rows=rows),
                                                     indent=1))
    lines = [f"**Contacts on slow videos** ({args.subjects} subjects, {len(clips)} clips x 2 sequences per rate; "
             f"`benchmarks/bench_contacts_slow_videos.py --subjects {args.subjects}`; git {git_revision()}; "
             f"{machine_description()})", "",
             "| fps | network | accuracy as filmed | interpolated | F1 as filmed | interpolated | stationary as filmed "
             "| interpolated |", "|---|---|---|---|---|---|---|---|"]
    for fps in RATES:
        for mode in predict.MODES:
            plain, read = (next(r for r in rows if r["fps"] == fps and r["network"] == mode and r["reading"] == how)
                           for how in ("as filmed", "interpolated"))
            lines.append(f"| {fps:g} | {mode} | {plain['accuracy']:.3f} | **{read['accuracy']:.3f}** | "
                         f"{plain['f1']:.3f} | {read['f1']:.3f} | {plain['stationary_accuracy']:.3f} | "
                         f"{read['stationary_accuracy']:.3f} |")
    (RESULTS / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
