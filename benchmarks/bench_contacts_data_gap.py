"""Is the contact networks' held-out gap one of training motion? Each network is trained twice by `train_contacts`
with the shipped recipe and seed, once as shipped (test subjects held out) and once with no subject held out, so
that the test subjects' clips join training under that seed's draws of camera, body, frame rate, playback speed and
noise; both are scored on bench_contacts.py's held-out test sequences (test subjects, seed 1, 4 per clip,
`held_out_settings`, mirrored votes), which are other draws of those clips.

The second network has seen the test motions, so its score is not a held-out one. It measures what the labels,
the input representation and the network allow once a motion is known (Rempe et al.'s protocol, whose test motions
may be training motions on another character), against what the training subjects' motion alone allows. Writes
benchmarks/results/contacts_data_gap.{json,md}; run_all.py's page includes the table.

    .venv/bin/python benchmarks/bench_contacts_data_gap.py [--variants 256] [--jobs 2]

The shipped recipe (256 variants per clip, 2 epochs) takes about 10 minutes per training on one core; --variants
48 about 1.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import os
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

from common import MOCAP, RESULTS, git_revision, machine_description
from physmocap.contacts import train
from physmocap.contacts.dataset import (
    TEST_SUBJECTS,
    SyntheticSettings,
    held_out_settings,
    load_clips,
    make_sequences,
    mocap_files,
    split_by_subject,
)
from physmocap.contacts.predict import MODES, load_weights
from physmocap.contacts.train import ContactTrainingSettings, train_contacts
from physmocap.io.atomic import write_text

TEST_SEED = 1  # bench_contacts.py's held-out draws


def trained_and_scored(mode: str, with_test_motion: bool, variants: int, seed: int) -> dict[str, object]:
    """Train one network with `train_contacts` (the shipped recipe but `variants`; no subject held out when
    with_test_motion) and score it on the held-out test sequences."""
    started = time.perf_counter()
    settings = ContactTrainingSettings(synthetic=SyntheticSettings(variants_per_clip=variants),
                                       test_subjects=() if with_test_motion else TEST_SUBJECTS)
    with tempfile.TemporaryDirectory() as out_dir:
        metadata = train_contacts(MOCAP, out_dir, seed=seed, settings=settings, modes=(mode,), log=lambda _: None)
        params = load_weights(mode, out_dir)
    _, test_files = split_by_subject(mocap_files(MOCAP))
    test = make_sequences(load_clips(test_files), TEST_SEED, held_out_settings(), variants=4)
    scores = train.evaluate(params, mode, test)
    return dict(mode=mode, test_motion_in_training=with_test_motion, training_frames=metadata["train_frames"],
                scores={key: round(value, 3) for key, value in scores.items()},
                seconds=round(time.perf_counter() - started))


def reproduces_shipped(rows: list[dict]) -> bool:
    """Whether every row trained without the test motion scores what bench_contacts.py measured for the shipped
    network (the same recipe and seeds give the same weights)."""
    path = RESULTS / "contacts.json"
    if not path.is_file():
        return False
    shipped = json.loads(path.read_text())["synthetic"]
    return all(round(shipped[f"{row['mode']} network"][key], 3) == value
               for row in rows if not row["test_motion_in_training"] for key, value in row["scores"].items())


def markdown(rows: list[dict], settings: dict, header: str) -> list[str]:
    same = (" The rows without it repeat the shipped networks' training (same recipe and seeds) and score what they "
            "score above, to the third decimal." if reproduces_shipped(rows) else "")
    lines = [
        "### Held-out synthetic accuracy with and without the test subjects' motion in training",
        "",
        f"`.venv/bin/python benchmarks/bench_contacts_data_gap.py --variants {settings['variants']}`. {header}",
        "",
        "Each network trained by `train_contacts` with the shipped recipe and seed, once on subjects 1, 2, 5, 7 "
        "alone (as shipped) and once with subjects 6 and 131's clips added (training's draws of camera, body, rate "
        "and noise, not the test sequences'); both scored on the held-out test sequences above. The second has seen the test motions (not a "
        "held-out score): it shows what labels, input and network reach once a motion is known." + same,
        "",
        "| network | test subjects' motion in training | training frames | accuracy | precision | recall | F1 | "
        "stationary accuracy | minutes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        s = row["scores"]
        lines.append(f"| {row['mode']} | {'yes' if row['test_motion_in_training'] else 'no'} | "
                     f"{row['training_frames']} | {s['accuracy']:.3f} | {s['precision']:.3f} | {s['recall']:.3f} | "
                     f"{s['f1']:.3f} | {s['stationary_accuracy']:.3f} | {row['seconds'] / 60:.1f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", type=int, default=SyntheticSettings().variants_per_clip,
                        help="synthetic sequences per training clip")
    parser.add_argument("--seed", type=int, default=0, help="train_contacts' seed (the shipped weights': 0)")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="trainings run at once")
    parser.add_argument("--compose-only", action="store_true", help="rewrite the .md from the stored .json")
    args = parser.parse_args()
    if args.compose_only:
        stored = json.loads((RESULTS / "contacts_data_gap.json").read_text())
        write(stored["rows"], stored["settings"], stored["header"])
        return
    header = (f"Git {git_revision()}; {machine_description()}; load average {os.getloadavg()[0]:.1f} at the start; "
              f"{args.jobs} trainings at once.")
    tasks = [(mode, with_test, args.variants, args.seed) for mode in args.modes for with_test in (False, True)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(trained_and_scored, *zip(*tasks, strict=True)))
    for row in rows:
        print(json.dumps(row))
    write(rows, vars(args), header)


def write(rows: list[dict], settings: dict, header: str) -> None:
    """benchmarks/results/contacts_data_gap.json and .md, each replaced whole."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    for suffix, text in (("json", json.dumps(dict(settings=settings, header=header, rows=rows), indent=1)),
                         ("md", "\n".join(markdown(rows, settings, header)) + "\n")):
        write_text(RESULTS / f"contacts_data_gap.{suffix}", text)


if __name__ == "__main__":
    main()
