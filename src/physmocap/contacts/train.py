"""Train both contact networks on synthetic data from motion capture and export them for numpy inference.

`train_contacts(data_root, out_dir)` rebuilds the shipped weights (physmocap/data/contacts) from
`../shared/data/mocap`, deterministically for a given seed: same seed and data, same weights (one torch thread,
deterministic algorithms, every random draw from seeded generators). Needs torch (requirements.lock), which the
rest of the package does not.

Recipe (Rempe A.2 where it applies): binary cross-entropy on the five outputs of every predicted frame, Adam with
L2 weight decay 1e-4, Gaussian noise (SD 0.005) on the normalised positions, batch normalisation and dropout; the
learning rate starts at 2e-3 and decays on a cosine to zero (Rempe: 1e-4 with early stopping on a validation
set; the larger rate reaches a low loss within the few epochs that a 2-core machine affords, and the fixed
schedule needs no validation subject taken from the few training subjects). Each network is an ensemble of three
seeds whose probabilities are averaged (`CausalNetSpec.members`, `CentredNetSpec.members`): single causal networks
of different seeds differed by up to 0.04 on the hand-labelled real frames, the ensembles by 0.006; the centred
network's members each train on their own draw of synthetic sequences (`member_data_draws`).

The measurements behind the recipe (what was tried, the figures, what was kept) are in
docs/decisions/contact-training.md.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .. import metrics
from ..errors import InputError
from ..io.atomic import atomic_path, write_text
from ..io.finite import json_text
from ..mocap.bvh_reader import MocapClip
from .dataset import (
    TEST_SUBJECTS,
    SyntheticSequence,
    SyntheticSettings,
    held_out_settings,
    iter_sequences,
    load_clips,
    make_sequences,
    mocap_files,
    split_by_subject,
)
from .features import REFERENCE_FPS, VALUES_PER_POINT, WindowSpec, inputs_from_windows, select_keypoints
from .networks import FRAME_CHANNELS, NUM_OUTPUTS, OUTPUT_NAMES, CausalNetSpec, CentredNetSpec, stack_members
from .predict import MIRROR, MODES, Mode, network_probabilities

METADATA_FILE = "training.json"
BATCH_NORM_EPSILON = 1e-5


@dataclass(frozen=True)
class TrainSettings:
    """Optimisation settings (per network).

    epochs: passes over every training frame. batch_size: windows per step.
    learning_rate: Adam's initial rate, decayed on a cosine to 0. weight_decay: L2 (Rempe: 1e-4).
    input_noise: SD of Gaussian noise on the normalised positions (Rempe: 0.005).
    position_dropout: chance that a training window's positions are zeroed, leaving speeds and confidences, so
        that the networks cannot lean on the pose alone.
    positive_weight: loss weight of the positive class (contact, stationary) against 1 for the negative one;
        1 (unweighted) to about 4. 2 trades validation accuracy for recall (module docstring).
    hard_frame_weight: chance of a frame with a raised heel or a skimming foot (`SyntheticSequence.hard`) to be a
        batch's target, against 1 for the other frames; 1 to about 8. Above 1 each epoch draws as many targets as
        there are frames, with replacement, so the number of steps stays. 1 (the plain shuffle): higher weights
        gained on validation subjects whose training lacked that motion and lost on the others and on the real
        frames (module docstring).
    max_steps: stop after this many steps (None: all epochs); for quick tests.
    threads: torch threads (1 keeps training deterministic and leaves the other core free).
    """

    epochs: int = 2
    batch_size: int = 256
    learning_rate: float = 2e-3
    weight_decay: float = 1e-4
    input_noise: float = 0.005
    position_dropout: float = 0.0
    positive_weight: float = 1.0
    hard_frame_weight: float = 1.0
    max_steps: int | None = None
    threads: int = 1


@dataclass(frozen=True)
class ContactTrainingSettings:
    """Everything `train_contacts` needs besides the data: synthetic data, networks, optimisation, split.

    folders: the folders under mocap/ whose clips are used (None: every one, the shipped weights; with
        MediaPipe's foot keypoints the Daz-skeleton clips added for issue 18 gain on the held-out synthetic
        subjects and on the hand-labelled real frames, docs/decisions/contact-training-data.md).
    """

    folders: tuple[str, ...] | None = None
    synthetic: SyntheticSettings = field(default_factory=SyntheticSettings)
    causal: CausalNetSpec = field(default_factory=CausalNetSpec)
    centred: CentredNetSpec = field(default_factory=CentredNetSpec)
    optimisation: TrainSettings = field(default_factory=TrainSettings)
    test_subjects: tuple[str, ...] = TEST_SUBJECTS
    test_variants_per_clip: int = 4


# ---------------------------------------------------------------------------------------------------------------
# Torch modules, with the parameter layout of networks.py after `export`


class TorchCausalNet(nn.Module):
    """networks.CausalNetSpec in torch: input (N, length x 36 + 1) -> logits (N, 5)."""

    def __init__(self, spec: CausalNetSpec) -> None:
        super().__init__()
        self.length = spec.window.length
        layers: list[nn.Module] = []
        channels = FRAME_CHANNELS + 1
        for out in spec.channels:
            layers += [nn.Conv1d(channels, out, spec.kernel), nn.BatchNorm1d(out), nn.ReLU()]
            channels = out
        self.convolutions = nn.Sequential(*layers)
        self.dropout = nn.Dropout(spec.dropout)
        self.fc = nn.Linear(channels, NUM_OUTPUTS)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        frames = inputs[:, :-1].reshape(len(inputs), self.length, FRAME_CHANNELS)
        interval = inputs[:, -1:, None].expand(-1, self.length, 1)
        hidden = self.convolutions(torch.cat([frames, interval], dim=2).transpose(1, 2))
        return self.fc(self.dropout(hidden[:, :, 0]))

    def export(self) -> dict[str, np.ndarray]:
        """Parameters for networks.causal_forward, batch normalisation folded into the convolutions."""
        params = {}
        convolutions = [m for m in self.convolutions if isinstance(m, nn.Conv1d)]
        norms = [m for m in self.convolutions if isinstance(m, nn.BatchNorm1d)]
        for i, (conv, norm) in enumerate(zip(convolutions, norms, strict=True)):
            weight, bias = _fold(conv.weight, conv.bias, norm)
            params[f"conv{i}.weight"] = weight.permute(2, 1, 0).numpy()  # (out, in, k) -> (k, in, out)
            params[f"conv{i}.bias"] = bias.numpy()
        params["fc.weight"] = self.fc.weight.detach().T.numpy()
        params["fc.bias"] = self.fc.bias.detach().numpy()
        return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in params.items()}


class TorchCentredNet(nn.Module):
    """networks.CentredNetSpec in torch: input (N, length x 36 + 1) -> logits (N, outputs x 5)."""

    def __init__(self, spec: CentredNetSpec) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        size = spec.window.input_size
        for i, hidden in enumerate(spec.hidden):
            if i == spec.dropout_before_layer:
                layers.append(nn.Dropout(spec.dropout))
            layers += [nn.Linear(size, hidden), nn.BatchNorm1d(hidden), nn.ReLU()]
            size = hidden
        layers.append(nn.Linear(size, spec.window.outputs * NUM_OUTPUTS))
        self.layers = nn.Sequential(*layers)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return self.layers(inputs)

    def export(self) -> dict[str, np.ndarray]:
        """Parameters for networks.centred_forward, batch normalisation folded into the linear layers."""
        linears = [m for m in self.layers if isinstance(m, nn.Linear)]
        norms = [m for m in self.layers if isinstance(m, nn.BatchNorm1d)]
        params = {}
        for i, linear in enumerate(linears):
            weight, bias = (linear.weight.detach(), linear.bias.detach()) if i == len(norms) else _fold(
                linear.weight, linear.bias, norms[i])
            params[f"linear{i}.weight"] = weight.T.numpy()
            params[f"linear{i}.bias"] = bias.numpy()
        return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in params.items()}


def _fold(weight: torch.Tensor, bias: torch.Tensor | None,
          norm: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight and bias (None: zero) of a layer followed by batch normalisation (evaluation mode), as one layer."""
    if norm.running_mean is None or norm.running_var is None:
        raise ValueError("batch normalisation without running statistics cannot be folded into its layer")
    with torch.no_grad():
        factor = norm.weight / torch.sqrt(norm.running_var + norm.eps)
        shape = (-1,) + (1,) * (weight.dim() - 1)
        offset = -norm.running_mean if bias is None else bias - norm.running_mean
        return weight * factor.reshape(shape), offset * factor + norm.bias


# ---------------------------------------------------------------------------------------------------------------
# Training data as frames; windows are cut per batch


@dataclass
class FrameTable:
    """All frames of a list of sequences, concatenated.

    points: (F, 12, 3) `select_keypoints` rows. interval: (F,) REFERENCE_FPS / fps. labels: (F, 5) float
    (4 contacts, stationary). sequence_start, sequence_length: (F,) where each frame's sequence lies in the table.
    hard: (F,) bool, `SyntheticSequence.hard`.
    """

    points: np.ndarray
    interval: np.ndarray
    labels: np.ndarray
    sequence_start: np.ndarray
    sequence_length: np.ndarray
    hard: np.ndarray

    @classmethod
    def from_sequences(cls, sequences: Iterable[SyntheticSequence]) -> FrameTable:
        """The table of `sequences`, consumed one at a time (only its rows of each are kept)."""
        points, interval, labels, hard, lengths = [], [], [], [], []
        for s in sequences:
            points.append(select_keypoints(s.keypoints_2d, s.valid))
            interval.append(np.full(s.num_frames, REFERENCE_FPS / s.fps, np.float32))
            labels.append(np.column_stack([s.contacts, s.stationary]).astype(np.float32))
            hard.append(s.hard)
            lengths.append(s.num_frames)
        sizes = np.array(lengths)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        return cls(points=np.concatenate(points), interval=np.concatenate(interval), labels=np.concatenate(labels),
                   sequence_start=np.repeat(starts, sizes), sequence_length=np.repeat(sizes, sizes),
                   hard=np.concatenate(hard))

    def __len__(self) -> int:
        return len(self.points)

    def batch(self, frames: np.ndarray, window: WindowSpec, rng: np.random.Generator, input_noise: float,
              position_dropout: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
        """Inputs (B, input_size) and labels (B, outputs x 5) of the windows whose targets are `frames` (B,)."""
        start = self.sequence_start[frames][:, None]
        offsets = np.arange(-1, window.length) - window.reference  # one frame early, for the first velocity
        last = self.sequence_length[frames][:, None] - 1
        local = np.clip((frames - self.sequence_start[frames])[:, None] + offsets, 0, last)
        indices = start + local
        noise = input_noise * rng.standard_normal((len(frames), window.length + 1, self.points.shape[1], 2))
        inputs = inputs_from_windows(self.points[indices], window.reference, self.interval[frames],
                                     noise.astype(np.float32))
        if position_dropout > 0:
            dropped = rng.random(len(frames)) < position_dropout
            is_position = np.zeros(inputs.shape[1], dtype=bool)
            is_position[:-1] = (np.arange(inputs.shape[1] - 1) % VALUES_PER_POINT) < 2
            inputs[np.ix_(dropped, is_position)] = 0.0
        half = window.outputs // 2
        output_frames = indices[:, 1 + window.reference - half : 1 + window.reference + half + 1]
        labels = self.labels[output_frames].reshape(len(frames), -1)
        return torch.from_numpy(inputs), torch.from_numpy(labels)


def train_network(
    model: nn.Module, table: FrameTable, window: WindowSpec, settings: TrainSettings, seed: int,
    log: Callable[[str], None] = print,
) -> dict[str, float]:
    """Train `model` in place on every frame of `table` as a target. Returns the final mean training loss."""
    # As the cosine schedule takes the rate to zero, weights that weight decay holds near zero become subnormal
    # floats, on which MKL's matrix products run many times slower: the centred network's second epoch took over
    # 30 minutes instead of 5. Flushed to zero they cost nothing (a process-wide CPU flag; inference is numpy).
    torch.set_flush_denormal(True)
    try:
        return _train_steps(model, table, window, settings, seed, log)
    finally:
        torch.set_flush_denormal(False)  # the flag is process-wide: leave the process as it was


def _train_steps(
    model: nn.Module, table: FrameTable, window: WindowSpec, settings: TrainSettings, seed: int,
    log: Callable[[str], None] = print,
) -> dict[str, float]:
    """`train_network`'s loop, with subnormal floats flushed."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    steps_per_epoch = int(np.ceil(len(table) / settings.batch_size))
    total_steps = settings.epochs * steps_per_epoch
    if settings.max_steps is not None:
        total_steps = min(total_steps, settings.max_steps)
    optimiser = torch.optim.Adam(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)

    def cosine_decay(step: int) -> float:
        return 0.5 * (1.0 + np.cos(np.pi * step / total_steps))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, cosine_decay)
    loss_function = nn.BCEWithLogitsLoss(pos_weight=torch.tensor(settings.positive_weight))
    chance = np.where(table.hard, settings.hard_frame_weight, 1.0)
    chance /= chance.sum()
    model.train()
    step, epoch_loss = 0, float("nan")
    while step < total_steps:
        order = (rng.permutation(len(table)) if settings.hard_frame_weight == 1.0
                 else rng.choice(len(table), size=len(table), p=chance))
        losses = []
        for first in range(0, len(order), settings.batch_size):
            if step >= total_steps:
                break
            inputs, labels = table.batch(order[first : first + settings.batch_size], window, rng, settings.input_noise,
                                         settings.position_dropout)
            if len(inputs) < 2:  # batch normalisation needs two samples
                continue
            loss = loss_function(model(inputs), labels)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            losses.append(loss.item())
            step += 1
        epoch_loss = float(np.mean(losses)) if losses else epoch_loss
        log(f"  step {step}/{total_steps}: mean loss {epoch_loss:.4f}")
    model.eval()
    return {"final_epoch_loss": epoch_loss, "steps": step}


def evaluate(params: dict[str, np.ndarray], mode: Mode, sequences: list[SyntheticSequence],
             mirror: bool = MIRROR) -> dict[str, float]:
    """Accuracy, precision, recall and F1 of the four contacts pooled, and stationary accuracy, on sequences
    (`network_probabilities`, with the mirrored input's votes when `mirror`)."""
    predicted, truth, moving, moving_truth = [], [], [], []
    for s in sequences:
        _, flags = network_probabilities(s.keypoints_2d, s.valid, s.fps, params, mode, mirror)
        predicted.append(flags[:, :4])
        truth.append(s.contacts)
        moving.append(flags[:, 4])
        moving_truth.append(s.stationary)
    scores = metrics.contact_scores(np.concatenate(predicted), np.concatenate(truth))
    stationary = metrics.contact_scores(np.concatenate(moving), np.concatenate(moving_truth))
    return {"accuracy": scores["accuracy"], "precision": scores["precision"], "recall": scores["recall"],
            "f1": scores["f1"], "stationary_accuracy": stationary["accuracy"]}


def data_digest(files: list[Path], root: Path) -> str:
    """sha256 over the files' paths relative to root and their bytes: which data made the weights."""
    digest = hashlib.sha256()
    for path in sorted(files):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def git_revision() -> str:
    """The source tree's git commit (with "+changes" when it has uncommitted ones), or "unknown" outside git."""
    here = Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "-C", str(here), "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + ("+changes" if dirty else "")


def train_contacts(
    data_root: str | os.PathLike,
    out_dir: str | os.PathLike,
    seed: int = 0,
    settings: ContactTrainingSettings = ContactTrainingSettings(),
    max_clips: int | None = None,
    log: Callable[[str], None] = print,
    modes: tuple[str, ...] = MODES,
) -> dict[str, object]:
    """Make synthetic data from the motion capture under data_root, train both networks, write their weights.

    data_root: the shared data folder (holding mocap/, searched recursively for .bvh) or the mocap folder itself.
    out_dir: written: causal.npz and centred.npz (numpy parameters, see networks.py, stored as float16: 0.2 and
        2.1 MB; float32 would double that, and changes 0.02-0.04 % of the held-out flags) and training.json (seed,
        settings, split, data sizes, losses, seconds, held-out synthetic scores). Created if missing.
    seed: every random choice (synthetic data, initialisation, batches, noise) follows from it.
    settings: see ContactTrainingSettings; the defaults made the shipped weights (842 CPU seconds, 15 minutes on
        one core of the 2-core Intel Xeon at load 1-2, peak 1.1 GB).
    max_clips: use only the first N training and N test clips (sorted by file name), for quick tests.
    modes: the networks to train (default both); each gets the same weights as when both are trained, so the two
        can be trained in separate processes (training.json then holds the given ones).
    Subjects in settings.test_subjects never enter training; they are synthesised with seed + 1,
    settings.test_variants_per_clip variants and `held_out_settings` for the held-out scores.
    Returns the metadata written to training.json.
    """
    if not modes or set(modes) - set(MODES):
        raise InputError(f"train_contacts: modes {modes}, expected some of {MODES}.")
    started = time.perf_counter()
    torch.set_num_threads(settings.optimisation.threads)
    torch.use_deterministic_algorithms(True)
    data_root = Path(data_root)
    data = _TrainingData.make(data_root, seed, settings, max_clips)
    data_seconds = time.perf_counter() - started
    log(f"synthetic data: {len(data.train_clips) * settings.synthetic.variants_per_clip} training sequences "
        f"({len(data.table)} frames) from {len(data.train_clips)} "
        f"clips, {len(data.test_sequences)} test sequences, {data_seconds:.1f} s")

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict[str, object]] = {mode: _train_one(mode, index, data, seed, settings, out_dir, log)
               for index, mode in enumerate(MODES) if mode in modes}
    metadata: dict[str, object] = {
        "seed": seed,
        "outputs": list(OUTPUT_NAMES),
        **data.description(),
        "data_seconds": data_seconds,
        "total_seconds": time.perf_counter() - started,
        "torch": torch.__version__,
        "data_sha256": data_digest(data.files, data_root),
        "git_revision": git_revision(),
        "settings": asdict(settings),
        **results,
    }
    write_text(out_dir / METADATA_FILE, json_text(metadata, indent=1))
    return metadata


@dataclass
class _TrainingData:
    """The synthetic training frames and held-out sequences of `train_contacts`, and what they came from."""

    files: list[Path]
    train_clips: list[MocapClip]
    test_clips: list[MocapClip]
    table: FrameTable
    test_sequences: list[SyntheticSequence]

    @classmethod
    def make(cls, data_root: Path, seed: int, settings: ContactTrainingSettings,
             max_clips: int | None) -> _TrainingData:
        files = [f for f in mocap_files(data_root) if settings.folders is None or f.parent.name in settings.folders]
        if not files:
            raise InputError(f"{data_root}: no .bvh files in the folders {', '.join(settings.folders or ())}.")
        train_files, test_files = split_by_subject(files, settings.test_subjects)
        if max_clips is not None:
            train_files, test_files = train_files[:max_clips], test_files[:max_clips]
        train_clips, test_clips = load_clips(train_files), load_clips(test_files)
        table = FrameTable.from_sequences(iter_sequences(train_clips, seed, settings.synthetic))
        test_sequences = make_sequences(test_clips, seed + 1, held_out_settings(settings.synthetic),
                                        variants=settings.test_variants_per_clip)
        return cls(train_files + test_files, train_clips, test_clips, table, test_sequences)

    def description(self) -> dict[str, object]:
        """The subjects, clips and frame counts, for training.json."""
        return {
            "train_subjects": sorted({c.subject for c in self.train_clips}, key=int),
            "test_subjects": sorted({c.subject for c in self.test_clips}, key=int),
            "train_clips": [c.name for c in self.train_clips],
            "test_clips": [c.name for c in self.test_clips],
            "train_frames": len(self.table),
            "test_frames": int(sum(s.num_frames for s in self.test_sequences)),
        }


MEMBER_SEED_STRIDE = 100  # member m of an ensemble trains with the seeds of member 0 plus 100 m


def _train_one(mode: Mode, index: int, data: _TrainingData, seed: int, settings: ContactTrainingSettings,
               out_dir: Path, log: Callable[[str], None]) -> dict[str, object]:
    """Train the `mode` network (the index-th of MODES; every member of its ensemble), write its weights; its
    training record."""
    spec = settings.causal if mode == "causal" else settings.centred
    mode_started = time.perf_counter()
    members, records = [], []
    for member in range(spec.members):
        shift = MEMBER_SEED_STRIDE * member
        table = data.table
        if member and spec.member_data_draws:
            table = FrameTable.from_sequences(iter_sequences(data.train_clips, seed + shift, settings.synthetic))
        torch.manual_seed(seed + index + shift)  # the initial weights
        model = TorchCausalNet(settings.causal) if mode == "causal" else TorchCentredNet(settings.centred)
        log(f"training the {mode} network, member {member + 1} of {spec.members} "
            f"({sum(p.numel() for p in model.parameters())} parameters, {len(table)} frames)")
        records.append(train_network(model, table, spec.window, settings.optimisation,
                                     seed + 10 * (index + 1) + shift, log))
        del table  # an own draw's frames go before the next one is made
        members.append({key: value.astype(np.float16) for key, value in model.export().items()})
    params = stack_members(members)
    with atomic_path(out_dir / f"{mode}.npz") as partial, open(partial, "wb") as file:
        np.savez(file, **params)  # uncompressed: the same weights give the same bytes
    params = {key: value.astype(np.float32) for key, value in params.items()}  # as predict_contacts loads them
    held_out = evaluate(params, mode, data.test_sequences) if data.test_sequences else {}
    record = {"members": records, "seconds": time.perf_counter() - mode_started, "held_out_synthetic": held_out}
    log(f"  {mode}: {record}")
    return record
