"""How eq. (4)'s tracker alone passes its input's jitter on (issue 17, real videos: jitter below the input).

The PD of eq. (4), x'' = f a_t + kp (x_t - x) + kd (v_t - v), follows its target's velocity v_t and so lags no ramp.
Its response to a target moving as sin(w t) is T(jw) = (kp + jw kd - f w^2) / (kp - w^2 + jw kd): with f = 0,
|T| > 1 for every w below sqrt(2 kp), so any motion slower than that is passed on slightly larger (at most 15% for
a critically damped pair). At 10 fps all the frequencies that second differences see lie below 5 Hz.

Part 1 prints, per group of degrees of freedom, that peak and the frequency below which |T| > 1 (default settings).
Part 2 reads run folders of `bench_physics_videos.py --runs DIR` and compares the root's horizontal path over the
feet-only frames (that bench's jitter): the kinematic input, the physics (result.npz qpos), and the linear
tracker alone on the input's path, with the tracker's gains, feed-forward and steps (no contacts, no velocity
smoothing, starting at rest on the first frame).

    .venv/bin/python benchmarks/bench_tracker_response.py --runs DIR

Writes benchmarks/results/tracker_response.json.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import RESULTS  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.config import PhysicsSettings  # noqa: E402
from physmocap.dynamics.physcap import feedforward_shares, integration_steps, tracking_gains  # noqa: E402

GROUPS = {"root horizontal": 0, "root height": 2, "root rotation": 3, "joints": 6}  # a DOF index of each group


def response_peak(kp: float, kd: float) -> dict:
    """The largest |T(jw)| of the PD without feed-forward, its frequency (Hz) and the frequency (Hz) below which
    |T| > 1, sqrt(2 kp) / (2 pi)."""
    w = np.linspace(1e-3, 4 * np.sqrt(kp) + 10, 200_000)  # rad/s
    gain = np.sqrt((kp ** 2 + (kd * w) ** 2) / ((kp - w ** 2) ** 2 + (kd * w) ** 2))
    top = int(np.argmax(gain))
    return dict(kp=kp, kd=kd, peak=float(gain[top]), peak_hz=float(w[top] / (2 * np.pi)),
                amplified_below_hz=float(np.sqrt(2 * kp) / (2 * np.pi)))


def linear_tracker(path: np.ndarray, fps: float, settings: PhysicsSettings) -> np.ndarray:
    """(T, 2) m: eq. (4) on the root's horizontal DOFs alone, tracking `path` (T, 2) m as the tracker does: the
    target moves along the chord between frames at the chord's velocity, the backward-difference acceleration
    fed forward at `feedforward_shares`, semi-implicit Euler steps of `integration_steps`."""
    kp_all, kd_all = tracking_gains(settings, 7)
    kp, kd = float(kp_all[0]), float(kd_all[0])
    steps, h = integration_steps(settings, fps)
    feedforward = float(feedforward_shares(settings, kd_all, fps)[0])
    position, velocity, chord_before = path[0].copy(), np.zeros(2), np.zeros(2)
    out = [position.copy()]
    for k in range(1, len(path)):
        chord = (path[k] - path[k - 1]) * fps
        acceleration, chord_before = (chord - chord_before) * fps, chord
        for step in range(1, steps + 1):
            target = path[k - 1] + (path[k] - path[k - 1]) * step / steps
            velocity = velocity + h * (feedforward * acceleration + kp * (target - position) + kd * (chord - velocity))
            position = position + h * velocity
        out.append(position.copy())
    return np.array(out)


def root_paths(result_path: Path) -> dict:
    """Feet-only jitter (m/s^2) of the root's horizontal path: input, physics, and the linear tracker alone."""
    result = dict(np.load(result_path, allow_pickle=False))
    fps = float(result["fps"])
    explained = result["valid"].astype(bool) & ~result["physics_unexplained"].astype(bool)
    kinematic, physics = result["qpos_kinematic"][:, :2], result["qpos"][:, :2]
    model = linear_tracker(kinematic, fps, PhysicsSettings())

    def jitter(path: np.ndarray) -> float:
        return metrics.explained_acceleration(path[:, None, :], fps, explained)

    return dict(video=result_path.parent.name, fps=fps, input=jitter(kinematic), physics=jitter(physics),
                linear_tracker=jitter(model))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=Path, help="run folders of bench_physics_videos.py --runs DIR")
    args = parser.parse_args(argv)
    settings = PhysicsSettings()
    kp, kd = tracking_gains(settings, 7)
    peaks = {name: response_peak(float(kp[i]), float(kd[i])) for name, i in GROUPS.items()}
    for name, p in peaks.items():
        print(f"{name}: kp {p['kp']:g}, kd {p['kd']:g}: |T| peaks at {p['peak']:.3f} ({p['peak_hz']:.1f} Hz), "
              f"above 1 below {p['amplified_below_hz']:.1f} Hz")
    rows = []
    if args.runs:
        print("| video (fps) | root horizontal jitter m/s²: input | linear tracker alone | physics |\n|---|---|---|---|")
        for result_path in sorted(args.runs.glob("*/result.npz")):
            row = root_paths(result_path)
            rows.append(row)
            print(f"| {row['video']} ({row['fps']:g}) | {row['input']:.3f} | {row['linear_tracker']:.3f} "
                  f"({100 * (row['linear_tracker'] / row['input'] - 1):+.1f}%) | {row['physics']:.3f} "
                  f"({100 * (row['physics'] / row['input'] - 1):+.1f}%) |")
    results = dict(peaks=peaks, videos=rows)
    (RESULTS / "tracker_response.json").write_text(json.dumps(results, indent=1) + "\n")
    return results


if __name__ == "__main__":
    main()
