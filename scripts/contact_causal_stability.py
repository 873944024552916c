"""How much the causal contact network moves between training seeds, alone, weight-averaged, and as an ensemble.

For each recipe seed S (`--seeds`), trains `--members` causal networks on the synthetic data of data seed S (the
training subjects minus `--val`, every folder, MediaPipe's foot keypoints), member m with initial weights and
batches of seed S + 100 m (member 0 is `contact_validation.py --seed S --data-seed S`), each also kept as an
exponential moving average of its weights (`--ema-decay`, batch statistics included). Prints one JSON line per
seed with the validation scores (mirrored votes) of every member alone, of member 0's average, and of the
ensembles of the first 2, 3, ... members (their probabilities averaged, `networks.ensemble_members`), and writes
every member's parameters under `--out`. `--load` scores the saved parameters again instead of training; `--real`
scores them on the hand-labelled real frames (a test set: look only after choosing on validation). For example

    nice -n 10 .venv/bin/python scripts/contact_causal_stability.py --seeds 0,1,2 --members 3 --out /tmp/stability

(about 3 minutes per member on one core, 1 GB).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import numpy as np
import torch
from contact_validation import real_accuracy
from torch import nn
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from physmocap.contacts import train
from physmocap.contacts.dataset import (
    SyntheticSettings,
    held_out_settings,
    load_clips,
    make_sequences,
    mocap_files,
    split_by_subject,
)
from physmocap.contacts.networks import stack_members
from physmocap.mocap.bvh_reader import cmu_subject

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"


class AveragedWhileTraining(nn.Module):
    """A network that keeps an exponential moving average of its own weights: each training forward pass first
    folds in the weights the previous step left; `finish` folds in the last step's."""

    def __init__(self, model: nn.Module, decay: float) -> None:
        super().__init__()
        self.model = model
        self._average = [AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True)]

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        if self.training:
            self._average[0].update_parameters(self.model)
        return self.model(inputs)

    def finish(self) -> nn.Module:
        self._average[0].update_parameters(self.model)
        return self._average[0].module.eval()


def save(path: Path, params: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **params)


def load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated recipe seeds")
    parser.add_argument("--members", type=int, default=3, help="networks trained per recipe seed")
    parser.add_argument("--val", default="1,7", help="comma-separated CMU subjects held out of training")
    parser.add_argument("--variants", type=int, default=16, help="synthetic sequences per training clip")
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--ema-decay", type=float, default=0.999, help="weight of the average per step, 0-1")
    parser.add_argument("--out", type=Path, required=True, help="folder of the members' parameters")
    parser.add_argument("--load", action="store_true", help="score the saved parameters instead of training")
    parser.add_argument("--real", action="store_true", help="score the saved parameters on the real frames")
    args = parser.parse_args()
    started = time.perf_counter()
    torch.set_num_threads(1)
    seeds = [int(s) for s in args.seeds.split(",")]
    synthetic = SyntheticSettings(variants_per_clip=args.variants, foot_keypoints="mediapipe")
    held_out = tuple(args.val.split(","))
    train_files, _ = split_by_subject(mocap_files(SHARED / "mocap"))
    fit_files = [f for f in train_files if cmu_subject(f) not in held_out]
    validation = [] if args.real else make_sequences(
        load_clips([f for f in train_files if cmu_subject(f) in held_out]), 1, held_out_settings(synthetic), variants=4)
    spec = train.CausalNetSpec()
    for seed in seeds:
        folder = args.out / f"seed{seed}"
        if not (args.load or args.real):
            table = train.FrameTable.from_sequences(make_sequences(load_clips(fit_files), seed, synthetic))
            for member in range(args.members):
                torch.manual_seed(1 + seed + 100 * member)
                model = AveragedWhileTraining(train.TorchCausalNet(spec), args.ema_decay)
                train.train_network(model, table, spec.window, train.TrainSettings(epochs=args.epochs),
                                    20 + seed + 100 * member, log=lambda _: None)
                save(folder / f"member{member}.npz", model.model.export())
                save(folder / f"member{member}_average.npz", model.finish().export())
        members = [load(folder / f"member{m}.npz") for m in range(args.members)]
        candidates = {**{f"member{m}": params for m, params in enumerate(members)},
                      "member0_average": load(folder / "member0_average.npz"),
                      **{f"ensemble{n}": stack_members(members[:n]) for n in range(2, args.members + 1)}}
        scores = {}
        for name, params in candidates.items():
            if args.real:
                real, per_video, stationary = real_accuracy(params, "causal", mirror=True)
                scores[name] = {"real": round(real, 3), "real_stationary": round(stationary, 3),
                                "real_per_video": per_video}
            else:
                scores[name] = {k: round(v, 4) for k, v in train.evaluate(params, "causal", validation).items()}
        print(json.dumps({"seed": seed, "scores": scores, "seconds": round(time.perf_counter() - started)}), flush=True)


if __name__ == "__main__":
    main()
