"""Determinism through the cache: the largest joint distance between a fresh capture, a capture from the cached
detections (the fit run again), and a capture from `--observations OUT/cache/observations.npz`.

    python benchmarks/bench_determinism.py [VIDEO ...] [--physics none|physcap|trajopt] [--online]

Default video: the shipped demo clip. Prints one line per video and comparison: metres, and frames beyond 5 cm."""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "src"))

import physmocap  # noqa: E402, F401 - single-threaded BLAS before numpy work
from physmocap.config import Settings  # noqa: E402
from physmocap.pipeline import run_capture  # noqa: E402
from physmocap.result import load_result  # noqa: E402


def compare(video: Path, settings: Settings, work: Path) -> dict[str, np.ndarray]:
    """{comparison: (T,) largest joint distance per frame, metres} against the fresh run."""
    fresh, cached, observed = work / "fresh", work / "cached", work / "observed"
    run_capture(fresh, settings, video=video, overlay=False)
    shutil.copytree(fresh / "cache", cached / "cache")
    for entry in (cached / "cache").iterdir():
        if entry.stem != "observations":
            entry.unlink()
    run_capture(cached, settings, video=video, overlay=False)
    run_capture(observed, settings, observations=fresh / "cache" / "observations.npz", overlay=False)
    expected = load_result(fresh / "result.npz")["joints_world"]
    return {name: np.linalg.norm(load_result(folder / "result.npz")["joints_world"] - expected, axis=-1).max(axis=1)
            for name, folder in (("cached detections", cached), ("--observations", observed))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("videos", nargs="*", type=Path,
                        default=[REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"])
    parser.add_argument("--physics", default="none")
    parser.add_argument("--online", action="store_true")
    args = parser.parse_args()
    settings = Settings(online=args.online).replace("physics", method=args.physics).check()
    for video in args.videos:
        with tempfile.TemporaryDirectory() as tmp:
            for name, gap in compare(video, settings, Path(tmp)).items():
                print(f"{video.name} ({args.physics}{', online' if args.online else ''}), {name}: largest joint "
                      f"difference {gap.max():.3g} m, {int((gap > 0.05).sum())} of {len(gap)} frames beyond 5 cm")


if __name__ == "__main__":
    main()
