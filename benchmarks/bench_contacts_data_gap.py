"""Is the contact networks' held-out gap one of training motion? Each network is trained twice with the shipped
recipe, once on the training subjects alone (as shipped) and once with the test subjects' clips added under other
draws of camera, body, frame rate, playback speed and noise (data seed + 100), and both are scored on
bench_contacts.py's held-out test sequences (test subjects, seed 1, 4 per clip, `held_out_settings`, mirrored
votes).

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

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor

from common import MOCAP, RESULTS, git_revision, machine_description
from physmocap.contacts import train
from physmocap.contacts.dataset import (
    SyntheticSettings, held_out_settings, load_clips, make_sequences, mocap_files, split_by_subject,
)
from physmocap.io.atomic import write_text

TEST_SEED = 1  # bench_contacts.py's held-out draws
OTHER_DRAWS = 100  # added to the data seed for the test subjects' training sequences
WEIGHTS_SEED = 0  # train_contacts' seed: initial weights seed + index, batches seed + 10 (index + 1)
MODES = ("causal", "centred")


def trained_and_scored(mode: str, with_test_motion: bool, variants: int, data_seed: int) -> dict[str, object]:
    """Train one network (`train_contacts`' recipe, seeds and sizes but `variants`) and score it on the held-out
    test sequences."""
    import torch

    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    started = time.perf_counter()
    train_files, test_files = split_by_subject(mocap_files(MOCAP))
    train_clips, test_clips = load_clips(train_files), load_clips(test_files)
    synthetic = SyntheticSettings(variants_per_clip=variants)
    sequences = make_sequences(train_clips, data_seed, synthetic)
    if with_test_motion:
        sequences += make_sequences(test_clips, data_seed + OTHER_DRAWS, synthetic)
    table = train.FrameTable.from_sequences(sequences)
    del sequences
    index = MODES.index(mode)
    torch.manual_seed(WEIGHTS_SEED + index)
    spec = train.CausalNetSpec() if mode == "causal" else train.CentredNetSpec()
    model = train.TorchCausalNet(spec) if mode == "causal" else train.TorchCentredNet(spec)
    train.train_network(model, table, spec.window, train.TrainSettings(), WEIGHTS_SEED + 10 * (index + 1),
                        log=lambda _: None)
    test = make_sequences(test_clips, TEST_SEED, held_out_settings(), variants=4)
    scores = train.evaluate(model.export(), mode, test)
    return dict(mode=mode, test_motion_in_training=with_test_motion, training_frames=len(table),
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
        "Each network trained with `train_contacts`' recipe and seeds, once on subjects 1, 2, 5, 7 alone (as "
        "shipped) and once with subjects 6 and 131's clips added under other draws of camera, body, rate and "
        "noise; both scored on the held-out test sequences above. The second has seen the test motions (not a "
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
    parser.add_argument("--data-seed", type=int, default=WEIGHTS_SEED, help="seed of the training sequences")
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
    tasks = [(mode, with_test, args.variants, args.data_seed) for mode in args.modes for with_test in (False, True)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        rows = list(pool.map(trained_and_scored, *zip(*tasks)))
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
