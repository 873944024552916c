"""How far the automatic contact labels can be recovered from positions as noisy as the detector's.

The contact networks see 2D keypoints only; this asks an easier question as a reference: apply the label rule
(`labels.contact_labels`, the shipped settings) to the true 3D sole sites after adding the measured MediaPipe
keypoint errors (`noise.MEDIAPIPE_NOISE`: drift and white jitter, in person heights, times 1.7 m, on all three
coordinates), at Rempe's 30 fps, raw and after a centred moving average, and count how often the labels agree with
the clean ones. Where even this agrees less, the labels sit closer to their thresholds (slow feet near the floor,
short phases) and a 2D classifier has less margin. Four noise draws per clip, training and held-out subjects apart.

    .venv/bin/python scripts/contact_label_ceiling.py [MOCAP_DIR]
"""

from __future__ import annotations

import sys
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.signal import lfilter

from physmocap.contacts.dataset import load_clips, mocap_files, split_by_subject
from physmocap.contacts.labels import CONTACT_SITE_INDICES, contact_labels
from physmocap.contacts.noise import MEDIAPIPE_NOISE

STATURE = 1.7  # m: turns the noise model's person heights into metres
LABEL_FPS = 30.0
DRAWS = 4
SMOOTHING_FRAMES = (1, 5, 9)  # moving-average lengths at 30 fps (1: none)


def drift(rng: np.random.Generator, shape: tuple[int, ...], sd: float, seconds: float, fps: float) -> np.ndarray:
    """Stationary AR(1) noise along axis 0 with SD `sd` and correlation time `seconds` (the NoiseModel's drift)."""
    decay = np.exp(-1.0 / (seconds * fps))
    start = sd * rng.standard_normal(shape[1:])
    innovations = sd * np.sqrt(1.0 - decay**2) * rng.standard_normal(shape)
    return lfilter([1.0], [1.0, -decay], innovations, axis=0, zi=decay * start[None])[0]


def agreement(clips, rng: np.random.Generator) -> dict[int, float]:
    """Fraction of (frame, site) labels of noisy, smoothed sites that equal the clean labels, per smoothing."""
    agree: dict[int, list[np.ndarray]] = {frames: [] for frames in SMOOTHING_FRAMES}
    for clip in clips:
        step = max(int(round(clip.fps / LABEL_FPS)), 1)
        fps = clip.fps / step
        sites = clip.positions[::step][:, CONTACT_SITE_INDICES]
        clean = contact_labels(sites, fps)
        for _ in range(DRAWS):
            noise = STATURE * (drift(rng, sites.shape, MEDIAPIPE_NOISE.keypoint_drift_sd,
                                     MEDIAPIPE_NOISE.keypoint_drift_seconds, fps)
                               + MEDIAPIPE_NOISE.keypoint_sd * rng.standard_normal(sites.shape))
            for frames in SMOOTHING_FRAMES:
                noisy = uniform_filter1d(sites + noise, frames, axis=0, mode="nearest")
                agree[frames].append(contact_labels(noisy, fps) == clean)
    return {frames: float(np.concatenate(values).mean()) for frames, values in agree.items()}


def main() -> None:
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap"
    train_files, test_files = split_by_subject(mocap_files(root))
    rng = np.random.default_rng(0)
    for name, files in (("training subjects", train_files), ("held-out subjects", test_files)):
        scores = agreement(load_clips(files), rng)
        print(f"{name}: " + ", ".join(f"{'raw' if frames == 1 else f'{frames}-frame average'} {score:.3f}"
                                      for frames, score in scores.items()))


if __name__ == "__main__":
    main()
