"""Try a contact-network recipe on validation subjects taken out of the training subjects (never the test ones).

Trains one network (`--mode causal|centred`) on the synthetic data of the training subjects minus `--val`, then
prints two JSON lines, without and with the mirrored input's votes (`predict.network_probabilities`): accuracy,
precision, recall, F1 and stationary accuracy on the validation subjects (4 variants per clip, seed 1, the
measured noise, labelled with the given label settings), their accuracy at frames with a raised heel or a skimming
foot and at the others (`labels.hard_frames`), and contact and stationary accuracy on the hand-labelled real
frames. The figures in the docstrings of `contacts/train.py` and `SyntheticSettings.variants_per_clip` came from
it, for example

    .venv/bin/python scripts/contact_validation.py --val 1,7 --variants 96 --epochs 2

(subjects 2 and 5 train; about 5 minutes on one busy core). Settings not given keep the shipped recipe's values
apart from --variants (8) and --epochs (4), which default small for quick trials. `--save` keeps the trained
parameters, `--load` evaluates saved ones instead of training.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np
import torch

from physmocap.contacts import train
from physmocap.contacts.dataset import (
    SyntheticSettings, held_out_settings, load_clips, make_sequences, mocap_files, split_by_subject,
)
from physmocap.contacts.labels import LabelSettings
from physmocap.contacts.predict import network_probabilities
from physmocap.contacts.real_videos import REAL_VIDEOS, cached_detection, load_real_labels
from physmocap.mocap.bvh_reader import cmu_subject
from physmocap.mocap.synthetic import FOOT_KEYPOINTS

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
REAL_LABELS = REPO / "benchmarks" / "labels" / "contacts_real.toml"
DETECTIONS = REPO / "runs" / "contacts" / "detections"


def real_accuracy(params: dict[str, np.ndarray], mode: str, mirror: bool) -> tuple[float, dict[str, float], float]:
    """Accuracy over the judged contact entries of the hand-labelled real frames, overall and per video, and the
    stationary accuracy over their judged frames."""
    videos = {video.name: video for video in REAL_VIDEOS}
    right, per_video, stationary_right = [], {}, []
    for name, labels in load_real_labels(REAL_LABELS).items():
        obs = cached_detection(videos[name], SHARED / "videos", DETECTIONS)
        _, flags = network_probabilities(obs.keypoints_2d, obs.valid, obs.fps, params, mode, mirror)
        judged = labels.contacts >= 0
        correct = flags[labels.frames, :4][judged] == (labels.contacts[judged] == 1)
        right.append(correct)
        per_video[name] = round(float(correct.mean()), 3)
        judged = labels.stationary >= 0
        stationary_right.append(flags[labels.frames[judged], 4] == (labels.stationary[judged] == 1))
    return float(np.concatenate(right).mean()), per_video, float(np.concatenate(stationary_right).mean())


def hard_frame_accuracy(params: dict[str, np.ndarray], mode: str, sequences: list, mirror: bool) -> dict[str, float]:
    """Validation accuracy of the contact entries at frames with a raised heel or a skimming foot
    (`SyntheticSequence.hard`) and at the others."""
    right = {"hard": [], "other": []}
    for sequence in sequences:
        _, flags = network_probabilities(sequence.keypoints_2d, sequence.valid, sequence.fps, params, mode, mirror)
        correct = flags[:, :4] == sequence.contacts
        right["hard"].append(correct[sequence.hard])
        right["other"].append(correct[~sequence.hard])
    return {name: float(np.concatenate(parts).mean()) for name, parts in right.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", choices=("causal", "centred"), default="centred")
    parser.add_argument("--val", default="1,7", help="comma-separated CMU subjects held out of training")
    parser.add_argument("--folders", help="comma-separated folders of ../shared/data/mocap to train on (default: all; "
                                          "cmu_iclone_cc3_retarget,cmu_raw_cgspeed are the shipped weights' clips); "
                                          "the validation clips stay those of every folder")
    parser.add_argument("--variants", type=int, default=8, help="synthetic sequences per training clip")
    parser.add_argument("--epochs", type=int, default=4)
    parser.add_argument("--min-phase-seconds", type=float, default=LabelSettings().min_phase_seconds)
    parser.add_argument("--channels", default="128,128,128", help="causal network's convolution channels")
    parser.add_argument("--max-speed", type=float, default=LabelSettings().contact_max_speed,
                        help="labels' contact_max_speed, m/s")
    parser.add_argument("--max-height", type=float, default=LabelSettings().contact_max_height,
                        help="labels' contact_max_height, m")
    parser.add_argument("--rest-on-either-side", action=argparse.BooleanOptionalAction,
                        default=LabelSettings().rest_on_either_side, help="labels' rest_on_either_side")
    parser.add_argument("--save", type=Path, help="write the trained parameters to this .npz file")
    parser.add_argument("--load", type=Path, help="evaluate these parameters (.npz) instead of training")
    parser.add_argument("--seed", type=int, default=0, help="seed of the initial weights and the batches")
    parser.add_argument("--data-seed", type=int, default=0,
                        help="seed of the training sequences (cameras, rates, bodies, noise); the validation set stays")
    parser.add_argument("--learning-rate", type=float, default=train.TrainSettings().learning_rate)
    parser.add_argument("--dropout", type=float, help="the network's dropout (default: its spec's)")
    parser.add_argument("--playback", default=",".join(map(str, SyntheticSettings().playback_speed_range)),
                        help="playback speed range of the synthetic motion, 'low,high'")
    parser.add_argument("--positive-weight", type=float, default=1.0, help="loss weight of the contact class")
    parser.add_argument("--hard-frame-weight", type=float, default=train.TrainSettings().hard_frame_weight,
                        help="sampling weight of raised-heel and skimming frames (TrainSettings.hard_frame_weight)")
    parser.add_argument("--foot-keypoints", choices=FOOT_KEYPOINTS, default=SyntheticSettings().foot_keypoints,
                        help="heel and foot_index keypoints of the training and validation sequences "
                             "(SyntheticSettings.foot_keypoints)")
    args = parser.parse_args()
    started = time.perf_counter()
    torch.set_num_threads(1)
    synthetic = SyntheticSettings(variants_per_clip=args.variants, foot_keypoints=args.foot_keypoints,
                                  playback_speed_range=tuple(float(v) for v in args.playback.split(",")),
                                  labels=LabelSettings(min_phase_seconds=args.min_phase_seconds,
                                                        contact_max_speed=args.max_speed,
                                                        contact_max_height=args.max_height,
                                                        rest_on_either_side=args.rest_on_either_side))
    held_out = tuple(args.val.split(","))
    train_files, _ = split_by_subject(mocap_files(SHARED / "mocap"))
    fit_files = [f for f in train_files if cmu_subject(f) not in held_out
                 and (args.folders is None or f.parent.name in args.folders.split(","))]
    val_files = [f for f in train_files if cmu_subject(f) in held_out]
    validation = make_sequences(load_clips(val_files), 1, held_out_settings(synthetic), variants=4)
    if args.load is not None:
        with np.load(args.load) as data:
            params = {key: data[key] for key in data.files}
    else:
        table = train.FrameTable.from_sequences(make_sequences(load_clips(fit_files), args.data_seed, synthetic))
        torch.manual_seed(1 + args.seed)
        if args.mode == "causal":
            spec = train.CausalNetSpec(channels=tuple(int(c) for c in args.channels.split(",")))
            spec = spec if args.dropout is None else replace(spec, dropout=args.dropout)
            model, window = train.TorchCausalNet(spec), spec.window
        else:
            spec = train.CentredNetSpec() if args.dropout is None else train.CentredNetSpec(dropout=args.dropout)
            model, window = train.TorchCentredNet(spec), spec.window
        train.train_network(model, table, window, train.TrainSettings(epochs=args.epochs, learning_rate=args.learning_rate,
                                                                          positive_weight=args.positive_weight,
                                                                          hard_frame_weight=args.hard_frame_weight),
                            20 + args.seed, log=lambda _: None)
        params = model.export()
        if args.save is not None:
            np.savez(args.save, **params)
    for mirror in (False, True):
        scores = {**train.evaluate(params, args.mode, validation, mirror),
                  **{f"{name}_frames_accuracy": value
                     for name, value in hard_frame_accuracy(params, args.mode, validation, mirror).items()}}
        real, per_video, real_stationary = real_accuracy(params, args.mode, mirror)
        print(json.dumps(dict(settings=vars(args), mirror=mirror,
                              validation={k: round(v, 3) for k, v in scores.items()}, real=round(real, 3),
                              real_stationary=round(real_stationary, 3),
                              real_per_video=per_video, seconds=round(time.perf_counter() - started)), default=str))


if __name__ == "__main__":
    main()
