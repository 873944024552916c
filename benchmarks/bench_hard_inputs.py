"""Hard inputs made from the shared videos (issue 17: "no input produces a traceback", every number finite, every
force within its bound, unexplained frames flagged): each variant below is written once with PyAV (H.264) from a
shared clip, then captured as a user would (`bench_physics_videos.run_video`: `physmocap capture VIDEO --physics
METHOD --no-overlay`; METHOD online: `--online --physics physcap`) and scored like the real videos (exit code, frames flagged, largest contact force in body
weights, finiteness, feet-only jitter and aligned error against the physics' own kinematic input).

Variants (name: what it stresses):
  feet_cropped        sports2d, the bottom 38% of every picture cut off (feet at or past the lower edge)
  upper_body_only     taiji, only the top half of the picture (legs unseen)
  juggling_8fps       sam2 juggling, every third frame (8 fps)
  taiji_120fps_dup    taiji, each frame shown 5 times at 120 fps (a frame-rate conversion by repetition)
  taiji_pulldown30    taiji 24 -> 30 fps, every fourth frame shown twice (whole-frame pulldown)
  sports2d_doubled60  sports2d 30 -> 60 fps, every frame twice
  mirrored            sports2d mirrored left to right
  tiny_160            sports2d at 160 x 90 pixels
  dark_noisy          taiji at 18% brightness with Gaussian noise (sigma 6 grey levels)
  two_frames, three_frames, one_frame   the first frames of taiji alone
  person_leaves       sports2d with 2 s of an empty grey picture in the middle
  upside_down         taiji turned 180 degrees in the pixels (no rotation metadata)
  sideways            taiji turned 90 degrees in the pixels (a camera on its side, no rotation metadata)
  taiji_5fps          taiji, every fifth frame (4.8 fps, below issue 17's 8-120 fps)
  still_frame         taiji's first frame repeated for 3 s
  odd_size            sports2d scaled to 641 x 361 (odd sizes; the encoder keeps 640 x 360)
  no_person           2 s of an empty grey picture (expected: a one-sentence refusal, exit 2)
  zoom_jump_cut       sports2d, its second half cropped to the central quarter and scaled up (a cut to a zoom)

    .venv/bin/python benchmarks/bench_hard_inputs.py [--physics physcap trajopt online] [--runs FOLDER] [--only NAME ...]

Writes benchmarks/results/hard_inputs.json and .md. About 9 minutes per method on the 2-core machine at load 4.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_physics_videos import run_video  # noqa: E402
from common import RESULTS, Pictures, read_clip, write_clip  # noqa: E402


def variants() -> dict[str, Callable[[], tuple[Pictures, float]]]:
    """name -> a function making the variant's pictures and frame rate (see the module's docstring)."""
    def sports(seconds: float = 6.0) -> tuple[Pictures, float]:
        return read_clip("sports2d_demo.mp4", seconds)

    def taiji(seconds: float = 8.0) -> tuple[Pictures, float]:
        return read_clip("hybrik_taiji.mp4", seconds)

    def blank(like: np.ndarray, count: int) -> Pictures:
        return [np.full_like(like, 90)] * count

    def pulldown(p: Pictures, fps: float) -> tuple[Pictures, float]:
        return [shown for i, picture in enumerate(p) for shown in [picture] * (2 if i % 4 == 3 else 1)], fps * 1.25

    def zoom_cut(p: Pictures, fps: float) -> tuple[Pictures, float]:
        h, w = p[0].shape[:2]
        zoomed = [cv2.resize(q[h // 4: 3 * h // 4, w // 4: 3 * w // 4], (w, h)) for q in p[75:150]]
        return p[:75] + zoomed, fps

    def dark(p: Pictures, fps: float) -> tuple[Pictures, float]:
        rng = np.random.default_rng(0)
        return [np.clip(q * 0.18 + rng.normal(0, 6, q.shape), 0, 255).astype(np.uint8) for q in p], fps

    def juggling() -> tuple[Pictures, float]:
        p, fps = read_clip("sam2_soccer_juggling.mp4", 6.0)
        return p[::3], fps / 3

    def leaves() -> tuple[Pictures, float]:
        p, fps = sports()
        return p[:60] + blank(p[0], 60) + p[60:150], fps

    def empty() -> tuple[Pictures, float]:
        p, fps = sports(0.1)
        return blank(p[0], 60), fps

    def head(count: int) -> tuple[Pictures, float]:
        p, fps = taiji(0.5)
        return p[:count], fps

    def each(f: Callable[[np.ndarray], np.ndarray], clip: Callable[[], tuple[Pictures, float]]):
        def made() -> tuple[Pictures, float]:
            pictures, fps = clip()
            return [f(q) for q in pictures], fps
        return made

    def repeated(p: Pictures, fps: float, times: int) -> tuple[Pictures, float]:
        return [q for q in p for _ in range(times)], fps * times

    def still() -> tuple[Pictures, float]:
        p, fps = taiji(0.1)
        return [p[0]] * 72, fps

    return {
        "feet_cropped": each(lambda q: q[: int(q.shape[0] * 0.62)], sports),
        "upper_body_only": each(lambda q: q[: q.shape[0] // 2], taiji),
        "juggling_8fps": juggling,
        "taiji_120fps_dup": lambda: repeated(*taiji(), 5),
        "taiji_pulldown30": lambda: pulldown(*taiji(17.0)),
        "sports2d_doubled60": lambda: repeated(*sports(8.0), 2),
        "mirrored": each(lambda q: q[:, ::-1], sports),
        "tiny_160": each(lambda q: cv2.resize(q, (160, 90), interpolation=cv2.INTER_AREA), sports),
        "dark_noisy": lambda: dark(*taiji()),
        "one_frame": lambda: head(1),
        "two_frames": lambda: head(2),
        "three_frames": lambda: head(3),
        "person_leaves": leaves,
        "upside_down": each(lambda q: q[::-1, ::-1], lambda: taiji(5.0)),
        "sideways": each(lambda q: np.ascontiguousarray(np.rot90(q, -1)), lambda: taiji(5.0)),
        "taiji_5fps": lambda: (lambda p, fps: (p[::5], fps / 5))(*taiji(10.0)),
        "still_frame": still,
        "odd_size": each(lambda q: cv2.resize(q, (641, 361)), sports),
        "no_person": empty,
        "zoom_jump_cut": lambda: zoom_cut(*sports()),
    }


def table(rows: list[dict]) -> list[str]:
    lines = ["| variant | physics | exit | frames (valid) | flagged | largest contact force BW | all finite | "
             "feet-only jitter m/s² (input) | feet-only aligned mm (input) | message |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [r["variant"], r["physics"], str(r["exit_code"])]
        if "frames" in r:
            cells += [f"{r['frames']} ({r['valid_frames']})", str(r["flagged_frames"]),
                      f"{r['largest_contact_force_bw']:.2f}", str(r["all_finite"]),
                      f"{r['feet_only_jitter']:.1f} ({r['feet_only_kinematic_jitter']:.1f})",
                      f"{r['feet_only_aligned_mm']:.1f} ({r['feet_only_kinematic_aligned_mm']:.1f})", ""]
        else:
            cells += [""] * 6 + [(r["stderr_tail"].splitlines() or [""])[-1]]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--physics", nargs="+", default=["physcap", "trajopt"], choices=["physcap", "trajopt", "online"],
                        help="capture methods; online: `--online` with PhysCap")
    parser.add_argument("--only", nargs="*", default=None, help="variant names (default: all)")
    parser.add_argument("--runs", default=None, help="keep the videos and run folders here (default: temporary)")
    parser.add_argument("--json", default=str(RESULTS / "hard_inputs.json"))
    args = parser.parse_args(argv)
    makers = variants()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        work = Path(args.runs or folder)
        work.mkdir(parents=True, exist_ok=True)
        for name in args.only or list(makers):
            video = work / f"{name}.mp4"
            if not video.exists():
                write_clip(video, *makers[name]())
            for method in args.physics:
                row = dict(variant=name, physics=method, **run_video(video, work / f"{name}-{method}",
                                                                     "physcap" if method == "online" else method,
                                                                     online=method == "online"))
                row.pop("video")
                rows.append(row)
                print(json.dumps(row), flush=True)
    out = dict(rows=rows)
    Path(args.json).write_text(json.dumps(out, indent=1))
    lines = table(rows)
    Path(args.json).with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return out


if __name__ == "__main__":
    main()
