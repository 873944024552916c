"""Foot contacts and the stationary flag of every frame of a video's observations, from the shipped networks."""

from __future__ import annotations

import functools
import math
import os
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import InputError
from ..motion import Observations
from .features import CAUSAL_WINDOW, CENTRED_WINDOW, select_keypoints, window_inputs
from .networks import NUM_OUTPUTS, causal_forward, centred_forward, ensemble_members, sigmoid

Mode = Literal["causal", "centred"]
MODES: tuple[Mode, ...] = ("causal", "centred")
WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "data" / "contacts"
THRESHOLD = 0.5  # probability above which a flag is set (both papers' sigmoid outputs)
BATCH_FRAMES = 4096  # frames per network call: bounds memory on long videos
MIRROR = True  # default of `network_probabilities(mirror=...)`: vote with the left/right-mirrored input too
# (validation subjects, scripts/contact_validation.py: accuracy +0.004 to +0.007 for either network, twice the cost)
MIRRORED_POINTS = (1, 0, 3, 2, 5, 4, 7, 6, 9, 8, 11, 10)  # FEATURE_LANDMARKS come in (left, right) pairs
MIRRORED_OUTPUTS = (2, 3, 0, 1, 4)  # OUTPUT_NAMES of the mirrored person: right heel, right toe, left ..., stationary
# fps: the training videos' lowest rate (dataset.SyntheticSettings.fps_range). A slower video is read at an integer
# multiple of its rate, frames interpolated, so that the networks see the rates they learnt: on the training
# subjects' new draws at 10 fps, centred accuracy 0.930 -> 0.957, causal 0.928 -> 0.944
# (docs/decisions/contact-frame-rate.md).
LOWEST_TRAINED_FPS = 12.0


def weights_path(mode: Mode, weights_dir: str | os.PathLike = WEIGHTS_DIR) -> Path:
    if mode not in MODES:
        raise InputError(f"contact network mode is {mode!r}, expected one of {MODES}.")
    return Path(weights_dir) / f"{mode}.npz"


@functools.lru_cache(maxsize=8)
def _load_cached(path: str, modified: int) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {key: data[key].astype(np.float32) for key in data.files}


def load_weights(mode: Mode, weights_dir: str | os.PathLike = WEIGHTS_DIR) -> dict[str, np.ndarray]:
    """The network parameters of `mode` from weights_dir/<mode>.npz, read once per file version."""
    path = weights_path(mode, weights_dir)
    if not path.is_file():
        raise InputError(f"{path}: no contact network weights; run `physmocap train-contacts` to make them.")
    return _load_cached(str(path), path.stat().st_mtime_ns)


def network_probabilities(
    keypoints_2d: np.ndarray, valid: np.ndarray, fps: float, params: dict[str, np.ndarray], mode: Mode,
    mirror: bool = MIRROR,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame probabilities and flags of the five outputs, for given parameters.

    keypoints_2d: (T, 33, 3) pixels + confidence; valid: (T,) bool; fps: frames per second.
    causal: each frame's window is it and the 6 frames before (PhysCap), so a frame's flags never depend on later
        frames; one prediction per frame.
    centred: every frame is a target of a 9-frame window whose network predicts the 5 central frames (Rempe); each
        frame collects up to 5 overlapping predictions.
    mirror: also predict on the left/right-mirrored keypoints (x negated about the hips, left and right points
        swapped) and count those predictions, their left and right columns swapped back, as further votes.
    A frame's flag is the majority vote of its predictions (ties, as with one causal prediction and its mirror, or
    at a clip's ends, go to the mean probability) and its probability their mean; a vote is a probability > 0.5.
    Invalid frames get probability 0 and no flag, and cast no votes. Below LOWEST_TRAINED_FPS the frames are
    interpolated to the smallest integer multiple of fps at or above it, and each frame gets the prediction of its
    own (not interpolated) frame; causal stays causal (an interpolated frame lies between two earlier frames).
    Returns probabilities (T, 5) float and flags (T, 5) bool, columns l heel, l toe, r heel, r toe, stationary.
    """
    if mode not in MODES:
        raise InputError(f"contact network mode is {mode!r}, expected one of {MODES}.")
    valid = np.asarray(valid, dtype=bool)
    factor = math.ceil(LOWEST_TRAINED_FPS / fps) if 0.0 < fps < LOWEST_TRAINED_FPS else 1
    if factor > 1 and len(valid):
        dense, dense_valid = interpolated_frames(np.asarray(keypoints_2d, dtype=float), valid, factor)
        probabilities, flags = network_probabilities(dense, dense_valid, fps * factor, params, mode, mirror)
        return probabilities[::factor], flags[::factor]
    points = select_keypoints(keypoints_2d, valid)
    votes = _votes(points, valid, fps, params, mode)
    if mirror:
        mirrored = points[:, MIRRORED_POINTS].copy()
        mirrored[..., 0] *= -1.0
        votes = np.concatenate([votes, _votes(mirrored, valid, fps, params, mode)[..., MIRRORED_OUTPUTS]], axis=1)
    votes[~valid] = np.nan
    cast = np.isfinite(votes)
    yes = (votes > THRESHOLD).sum(axis=1)
    no = (cast & (votes <= THRESHOLD)).sum(axis=1)
    with np.errstate(invalid="ignore"):
        mean = np.where(cast.any(axis=1), np.nansum(votes, axis=1) / np.maximum(cast.sum(axis=1), 1), 0.0)
    flags = (yes > no) | ((yes == no) & (mean > THRESHOLD))
    flags[~valid] = False
    mean[~valid] = 0.0
    return mean, flags


def causal_window_start(index: int) -> int:
    """The first frame whose keypoints the causal network reads for frame `index` on its own (live capture): the
    frame's window and the frame before it, whose step gives the window's first velocity. On those frames alone it
    gives what it gives on the whole clip."""
    return max(0, index - CAUSAL_WINDOW.length)


def interpolated_frames(keypoints_2d: np.ndarray, valid: np.ndarray, factor: int) -> tuple[np.ndarray, np.ndarray]:
    """keypoints_2d (T, 33, C) and valid (T,) with factor - 1 frames put linearly between each pair of frames:
    ((T - 1) factor + 1, 33, C), valid where both frames around are (an original frame: where it is); frame t
    lands at t factor."""
    spot = np.arange((len(valid) - 1) * factor + 1) / factor
    before = np.floor(spot).astype(int)
    after = np.minimum(before + 1, len(valid) - 1)
    share = spot - before
    dense_valid = valid[before] & (valid[after] | (share == 0.0))
    return keypoints_2d[before] * (1.0 - share[:, None, None]) + keypoints_2d[after] * share[:, None, None], dense_valid


def _votes(points: np.ndarray, valid: np.ndarray, fps: float, params: dict[str, np.ndarray], mode: Mode) -> np.ndarray:
    """(T, predictions per frame, 5) probabilities of every valid frame's predictions, NaN where none was made.

    points: (T, 12, 3) `select_keypoints` rows. causal: one prediction per frame; centred: up to 5, one from each
    window whose 5 predicted frames include it. An ensemble's prediction is the mean of its members'."""
    members = ensemble_members(params)
    num_frames = len(points)
    targets = np.flatnonzero(valid)
    spec = CAUSAL_WINDOW if mode == "causal" else CENTRED_WINDOW
    half = spec.outputs // 2
    votes = np.full((num_frames, spec.outputs, NUM_OUTPUTS), np.nan)
    for start in range(0, len(targets), BATCH_FRAMES):
        batch = targets[start : start + BATCH_FRAMES]
        inputs = window_inputs(points, fps, batch, spec)
        if mode == "causal":
            votes[batch, 0] = np.mean([sigmoid(causal_forward(member, inputs)) for member in members], axis=0)
            continue
        predicted = np.mean([sigmoid(centred_forward(member, inputs)) for member in members], axis=0)
        for offset in range(-half, half + 1):
            frames = batch + offset
            inside = (frames >= 0) & (frames < num_frames)
            votes[frames[inside], offset + half] = predicted[inside, offset + half]
    return votes


def predict_contacts(
    obs: Observations, mode: Mode = "causal", weights_dir: str | os.PathLike = WEIGHTS_DIR
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Foot contacts and the stationary flag of every frame, from 2D keypoints, with the shipped networks.

    obs: the detector's observations; only keypoints_2d (T, 33, 3) (pixels + confidence), valid (T,) and fps
        are read. Any resolution and frame rate (trained on 12-60 fps, 720p and 1080x1920 portrait; slower videos
        are read at a multiple of their rate, `network_probabilities`).
    mode: "causal" for live/online use (PhysCap: a frame's flags use it and the 6 frames before it only, so they
        are final as soon as the frame arrives); "centred" for offline use (Rempe: 9-frame windows, 5 predicted
        frames each, majority vote; a frame's flags use up to 6 frames on either side). Both also vote with the
        left/right-mirrored keypoints (`network_probabilities`).
    weights_dir: folder with causal.npz and centred.npz; default the weights shipped in physmocap/data/contacts
        (made by `contacts.train.train_contacts`). Loaded once per file and kept.
    Returns:
        contacts: (T, 4) bool, columns left heel, left toe, right heel, right toe; True = touching the floor.
        stationary: (T,) bool, True where the person is not moving about (root slower than 0.25 m/s; see
            `labels.LabelSettings`).
        probabilities: (T, 5) float in [0, 1], the same five columns (contacts then stationary): the mean of a
            frame's predictions (the mirrored input's and, centred, the overlapping windows').
    Invalid frames (obs.valid False) get no contact, not stationary and probability 0: the caller flags them.
    Neighbours of invalid frames use the nearest valid frame's keypoints with confidence 0 in their windows.
    Cost: about 0.6 ms (causal, an ensemble of three networks) and 0.17 ms (centred) per frame on one core of a
        busy 2-core machine, mirrored votes included (benchmarks/bench_contacts.py).
    Raises InputError for an unknown mode or missing weights.
    """
    if obs.num_frames == 0:
        return np.zeros((0, 4), bool), np.zeros(0, bool), np.zeros((0, NUM_OUTPUTS))
    weights = load_weights(mode, weights_dir)
    probabilities, flags = network_probabilities(obs.keypoints_2d, obs.valid, obs.fps, weights, mode)
    return flags[:, :4], flags[:, 4], probabilities
