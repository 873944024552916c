"""Train both contact networks on synthetic data from motion capture and export them for numpy inference.

`train_contacts(data_root, out_dir)` rebuilds the shipped weights (physmocap/data/contacts) from
`../shared/data/mocap`, deterministically for a given seed: same seed and data, same weights (one torch thread,
deterministic algorithms, every random draw from seeded generators). Needs torch (requirements.lock), which the
rest of the package does not.

Recipe (Rempe A.2 where it applies): binary cross-entropy on the five outputs of every predicted frame, Adam with
L2 weight decay 1e-4, Gaussian noise (SD 0.005) on the normalised positions, batch normalisation and dropout; the
learning rate starts at 2e-3 and decays on a cosine to zero (Rempe: 1e-4 with early stopping on a validation
set; the larger rate reaches a low loss within the few epochs that a 2-core machine affords, and the fixed
schedule needs no validation subject taken from the few training subjects).

Every figure below was measured with labels judged over the interval before each frame only (before
`LabelSettings.rest_on_either_side`, which labels landing frames in contact; see labels.py) and every "real" one
against the first hand labels, before sports2d_box was relabelled (session 7: its in-jumps had been labelled as
contact; benchmarks/labels/contacts_real.md). Comparisons between them stand; the weights of that recipe scored
0.927 on the relabelled real frames, not 0.901.

The recipe's sizes were chosen with CMU subjects 1 and 7 held out of training as validation (never the test
subjects; scripts/contact_validation.py). Variety of the synthetic data mattered most: at the same number of
steps, 48, 96 and 192 variants per clip scored 0.943 (labels without merged short runs), 0.947 and 0.951 on them,
and 48 variants seen for 2 epochs instead of 4 lost 0.012. A causal network twice as wide (256 channels) scored
0.928 against 0.925 (real 0.890 against 0.887), within the noise, so it keeps 128. Hence 256
variants per clip (1.26 million frames), each seen twice (9,800 steps per network). Within 0.006 either way on
validation and on the hand-labelled real frames, so left out: training noise scaled per sequence by 0.25-2x
(0.935 against 0.931; real 0.878 against 0.882) and a minimum phase length on the predictions; decision
thresholds of 0.4 or 0.6 trade validation against real accuracy (0.942 / 0.899 and 0.950 / 0.869 against 0.948 /
0.886). The labels' merging of short runs (`LabelSettings.min_phase_seconds`) changed neither (0.931 both).

With the labels' 1.0 m/s and the mirrored votes of `predict.network_probabilities` (validation accuracy
without / with them; 2 epochs; "real": the hand-labelled frames, looked at only after the choice):
- learning rate 2e-3 instead of 1e-3: centred 0.924 / 0.931 -> 0.930 / 0.936 at 32 variants per clip, causal
  0.908 / 0.914 -> 0.922 / 0.928; with the centred dropout 0.1 as well, at 96 variants, 0.946 / 0.950 ->
  0.950 / 0.953 (real 0.907 -> 0.919).
- centred dropout 0.1 instead of Rempe's 0.3 (32 variants, 1e-3): 0.0 0.929 / 0.935, 0.1 0.928 / 0.934,
  0.3 0.924 / 0.931, 0.5 0.913 / 0.920. The causal network's 0.2 against 0: 0.914 against 0.916, kept.
- not kept: training motion played at 0.7-1.6 times its speed instead of 0.8-1.25
  (`SyntheticSettings.playback_speed_range`; validation and test sequences stay at 0.8-1.25,
  `dataset.held_out_settings`), 48 variants, seeds 0-2: centred 0.941 -> 0.946, causal 0.935 -> 0.936 (means;
  real 0.908 -> 0.909 and 0.909 -> 0.908); with subjects 2 and 5 held out instead (seed 0), centred 0.902 ->
  0.904, real 0.887 -> 0.893. Retrained in full it scored the same on the test subjects and its contacts hurt
  trajopt (see the field's comment).
- not kept: the contact class weighted twice in the loss (`TrainSettings.positive_weight` 2): 0.924 -> 0.903
  (real 0.901 -> 0.920, the trade of a lower decision threshold); a second network of another seed whose votes
  join the first's: 0.931 -> 0.931 with the mirrored votes; people on a stage 0.7 m below to 1.5 m above the
  camera's ground (wider camera elevations): 0.931 -> 0.932 (real 0.902 -> 0.898).

The held-out gap is one of unseen motion, not of fitting: on the training subjects' own clips under new draws of
camera, body, rate and noise (Rempe et al.'s protocol, whose test motions may be training motions on another
character; bench_contacts.py, "seen motions") the shipped networks score 0.981 (centred) and 0.972 (causal),
against 0.885 and 0.852 on the held-out subjects. Trained with the same recipe and seed but with no subject held
out, the test subjects' clips joining training under training's draws (benchmarks/bench_contacts_data_gap.py), the
networks score 0.965 / F1 0.974 (centred) and 0.945 / 0.959 (causal) on the held-out test sequences: labels, input and networks reach the
issue's 0.95 / 0.96 once a motion is known, and what the four training subjects in ../shared/data lack is the
motion itself (stances on the ball of the foot, a sideways dribble's skimming feet).

The held-out test errors (centred 0.888) are not label errors: the labels' heel and toe sites and floor agree with
the BVH's own joints on both skeletons (scripts/contact_label_geometry.py; see labels.py). Most are in test subject
131, the only held-out body on the raw CMU skeleton (55 % of the entries, accuracy 0.862, heels 0.815, against
0.919 on subject 6's CC3 avatar, which every training CC3 clip shares), in stances on the ball of the foot with
the heel 5-12 cm up (8.2 % of the test subjects' foot-time, 2.3 % of the training subjects'; accuracy 0.461, 24 %
of the errors) and in feet that skim the floor faster than 1 m/s (006_08's sideways dribble; 0.730, 23 %)
(scripts/contact_errors.py). Tried for them, with subjects 1 and 7 held out (48 variants, 2 epochs, centred,
mirrored votes, training seeds 0-2 unless said; `scripts/contact_validation.py`), none kept:
- each training foot's heel and toe moved along the heel -> toe line by a random factor of 0.9-1.25 (foot length
  against the leg: 0.22 on the CC3 avatar, 0.23 on raw subject 2, 0.25 on raw subject 131; a flat foot keeps its
  heights): 0.946 against 0.946 on the same training sequences (a placebo draw of the factor; real 0.906 against
  0.907), causal (seed 0) 0.934 against 0.936, with subjects 2 and 5 held out (their raw clips 02_01 and 05_06 in
  validation; seed 0) 0.907 against 0.906; with the ankle's height above the heel -> toe line scaled by 0.75-1.5
  as well, 0.944 (real 0.910).
- a 13-frame centred window (5 outputs) instead of Rempe's 9: 0.942 against 0.941 on data seed 0, and 0.943 /
  0.942 against 0.946 / 0.944 on data seeds 1 and 2, though the real frames gained in all five pairs (0.916
  against 0.908 on average).
- frames with a raised heel or a skimming foot (`labels.hard_frames`; 30 % of the training subjects' synthetic
  frames, 12-54 % per subject, 46 % of the test subjects') drawn as batch targets `TrainSettings.hard_frame_weight`
  times as often as the others, with as many steps. Data seeds 0-5, means; weights 1 / 2 / 4 / 8: with 1 and 7 held
  out 0.944 / 0.947 / 0.949 / 0.950 (every seed gained; their hard frames 0.924 -> 0.934; real 0.908 / 0.912 /
  0.905 / 0.900), with 2 and 5 held out 0.901 / 0.900 / 0.898 / 0.895 (hard frames 0.845 -> 0.854, the others
  0.916 -> 0.905; real 0.886 / 0.885 / 0.876 / 0.877). It helps where the validation subjects have more of that
  motion than the training ones (1 and 7: 13 and 54 % hard frames; 2 and 5: 12 and 36 %) and costs where they have
  less. Raised heels alone at weight 4: 0.946 and 0.902 (their frames, seed 0: 0.812 -> 0.841 and 0.740 -> 0.749),
  real 0.902 and 0.880.
- label entries within 0.02 or 0.05 s of a change of their label (at least the frames either side, where a site
  crosses the thresholds) left out of the loss (`TrainSettings.label_change_margin` of commit 1eed517), data seeds
  0-5: 0.944 -> 0.944 / 0.941 with 1 and 7 held out, 0.901 -> 0.898 / 0.894 with 2 and 5 (real +0.000 / +0.004 and
  +0.001 / +0.003).
- the training bodies' legs varied (`SyntheticSettings.thigh_share_scale_range` and `hip_width_scale_range` of
  commit 74eb76c, each drawn from its own generator, so every other draw of a data seed stayed): the thigh's share
  of the leg (0.489 on the CC3 avatar and raw subject 2, 0.513 on raw subject 131) scaled by 0.94-1.06, the knee
  moved in the leg's plane with hip, ankle and leg length kept; the hips' horizontal separation (0.199 of the leg
  on the CC3 avatar, 0.161 on raw subject 2, 0.171 on raw subject 131) scaled by 0.8-1.1, the legs moved rigidly
  sideways. Data seeds 0-5, means, against 0.901 (2 and 5 held out) and 0.944 (1 and 7): knee 0.901 and 0.945,
  hips 0.901 and 0.944, both 0.902 and 0.945; every paired difference within +-0.002. Real frames: both +0.007
  with 2 and 5 held out (every seed +0.003 to +0.012), +0.001 with 1 and 7. The 2,5 split cannot show a
  raw-skeleton effect: its only usable raw clip, 02_01, has 3 % of its entries and scores 0.967 against 0.902 for
  the CC3 clips and 0.956 for the same walk on the CC3 avatar (002_01; data seed 1, with or without the knees),
  so its gap against 1 and 7 is not a body gap.
- stances on the ball of the foot synthesised from the training subjects' flat ones (`raise_heels` of commit
  afa270a: a flat stance of at least 0.3 s raised with probability p, the foot turned about its toe site until the
  heel is 4-12 cm up, rising and lowering over 0.1 s, the knee bent by two-link IK; its own generator, so every
  other draw stayed). Data seeds 0-2, means, p = 0 / 0.15 / 0.3: with 1 and 7 held out 0.946 / 0.945 / 0.942
  (hard frames 0.925 / 0.926 / 0.924), with 2 and 5 held out 0.901 / 0.893 / 0.892 (hard frames 0.848 / 0.857 /
  0.860), and the hand-labelled real frames fell 0.946 / 0.877 / 0.812 and 0.930 / 0.839 / 0.816 (taiji, basketball
  and pose2sim's standing walker: flat feet called raised). Made-up raised heels teach a cue that real flat feet
  show too.
Those runs also show that the draw of training sequences moves validation accuracy more than the weights' seed
does: the shipped recipe on training sequences of data seeds 0, 1 and 2 (`--data-seed`, weights' seed 0) scored
0.941, 0.946 and 0.944 (real 0.908, 0.911, 0.905), against 0.941 / 0.942 / 0.940 for weights' seeds 0-2 on data
seed 0. A change that adds a random draw to the synthesis shifts every later draw (cameras, rates, noise), so
compare it against a placebo draw or over several data seeds.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from torch import nn

from .. import metrics
from ..errors import InputError
from ..io.atomic import atomic_path, write_text
from .dataset import (
    TEST_SUBJECTS, SyntheticSequence, SyntheticSettings, held_out_settings, iter_sequences, load_clips, make_sequences,
    mocap_files, split_by_subject,
)
from .features import REFERENCE_FPS, VALUES_PER_POINT, WindowSpec, inputs_from_windows, select_keypoints
from .networks import FRAME_CHANNELS, NUM_OUTPUTS, OUTPUT_NAMES, CausalNetSpec, CentredNetSpec
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
    """Everything `train_contacts` needs besides the data: synthetic data, networks, optimisation, split."""

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
        for i, (conv, norm) in enumerate(zip(convolutions, norms)):
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


def _fold(weight: torch.Tensor, bias: torch.Tensor, norm: nn.BatchNorm1d) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight and bias of a layer followed by batch normalisation (evaluation mode), as one layer."""
    with torch.no_grad():
        factor = norm.weight / torch.sqrt(norm.running_var + norm.eps)
        shape = (-1,) + (1,) * (weight.dim() - 1)
        return weight * factor.reshape(shape), (bias - norm.running_mean) * factor + norm.bias


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
    def from_sequences(cls, sequences: Iterable[SyntheticSequence]) -> "FrameTable":
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
        local = np.clip((frames - self.sequence_start[frames])[:, None] + offsets, 0, self.sequence_length[frames][:, None] - 1)
        indices = start + local
        noise = input_noise * rng.standard_normal((len(frames), window.length + 1, self.points.shape[1], 2))
        inputs = inputs_from_windows(self.points[indices], window.reference, self.interval[frames], noise.astype(np.float32))
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
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    steps_per_epoch = int(np.ceil(len(table) / settings.batch_size))
    total_steps = settings.epochs * steps_per_epoch
    if settings.max_steps is not None:
        total_steps = min(total_steps, settings.max_steps)
    optimiser = torch.optim.Adam(model.parameters(), lr=settings.learning_rate, weight_decay=settings.weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda step: 0.5 * (1.0 + np.cos(np.pi * step / total_steps)))
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
    settings: see ContactTrainingSettings; the defaults made the shipped weights.
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
    train_files, test_files = split_by_subject(mocap_files(data_root), settings.test_subjects)
    if max_clips is not None:
        train_files, test_files = train_files[:max_clips], test_files[:max_clips]
    train_clips, test_clips = load_clips(train_files), load_clips(test_files)
    table = FrameTable.from_sequences(iter_sequences(train_clips, seed, settings.synthetic))
    test_sequences = make_sequences(test_clips, seed + 1, held_out_settings(settings.synthetic),
                                    variants=settings.test_variants_per_clip)
    data_seconds = time.perf_counter() - started
    log(f"synthetic data: {len(train_clips) * settings.synthetic.variants_per_clip} training sequences "
        f"({len(table)} frames) from {len(train_clips)} "
        f"clips, {len(test_sequences)} test sequences, {data_seconds:.1f} s")

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    results: dict[str, object] = {}
    for index, mode in enumerate(MODES):
        if mode not in modes:
            continue
        torch.manual_seed(seed + index)  # the initial weights
        model, window = ((TorchCausalNet(settings.causal), settings.causal.window) if mode == "causal"
                         else (TorchCentredNet(settings.centred), settings.centred.window))
        mode_started = time.perf_counter()
        log(f"training the {mode} network ({sum(p.numel() for p in model.parameters())} parameters)")
        training = train_network(model, table, window, settings.optimisation, seed + 10 * (index + 1), log)
        params = {key: value.astype(np.float16) for key, value in model.export().items()}
        with atomic_path(out_dir / f"{mode}.npz") as partial, open(partial, "wb") as file:
            np.savez(file, **params)  # uncompressed: the same weights give the same bytes
        params = {key: value.astype(np.float32) for key, value in params.items()}  # as predict_contacts loads them
        held_out = evaluate(params, mode, test_sequences) if test_sequences else {}
        results[mode] = {**training, "seconds": time.perf_counter() - mode_started, "held_out_synthetic": held_out}
        log(f"  {mode}: {results[mode]}")
    metadata = {
        "seed": seed,
        "outputs": list(OUTPUT_NAMES),
        "train_subjects": sorted({c.subject for c in train_clips}, key=int),
        "test_subjects": sorted({c.subject for c in test_clips}, key=int),
        "train_clips": [c.name for c in train_clips],
        "test_clips": [c.name for c in test_clips],
        "train_frames": len(table),
        "test_frames": int(sum(s.num_frames for s in test_sequences)),
        "data_seconds": data_seconds,
        "total_seconds": time.perf_counter() - started,
        "torch": torch.__version__,
        "settings": asdict(settings),
        **results,
    }
    write_text(out_dir / METADATA_FILE, json.dumps(metadata, indent=1, default=str))
    return metadata
