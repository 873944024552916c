"""Peak resident memory and CPU seconds of the whole-clip kinematic fit and of the B.4 refinement against the clip's
length (issue 23, "Bounded memory").

Long observations are made by looping a real observations file forwards and backwards (the motion stays
continuous at the joins) to 300, 1,800, 5,400 and 18,000 frames (10 s to 10 minutes at 30 fps). Each stage runs
in a child process of its own, so that its ru_maxrss is the stage's peak and nothing else's: `fit` is
kinematics.stage.fit_motion with the default settings (offline); `refine` is kinematics.refine.refine_kinematics
on that fit's motion with the centred contact network's contacts. `--before-src DIR` runs the same children on
another checkout's source (e.g. main's) for the "before" rows; the fitted poses of both are compared.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_memory.py --observations RUN/cache/observations.npz \
        --before-src /path/to/main/src [--frames 1800 --codes after --stages fit]

(RUN/cache/observations.npz: `physmocap capture /work/shared/data/videos/sports2d_demo.mp4 -o RUN --physics none
--no-overlay`.) Prints a markdown table; rows in benchmarks/results/memory.json, merged with the rows already
there (a re-run of some sizes replaces just those).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import physmocap  # noqa: F401 - first: single-threaded BLAS, as the command line runs

# isort: split

import numpy as np

BENCHMARKS = Path(__file__).resolve().parent
REPO = BENCHMARKS.parent
RESULTS = REPO / "benchmarks" / "results" / "memory.json"
FRAMES = (300, 1800, 5400, 18000)
STAGES = ("fit", "refine")


def looped(obs, frames: int):
    """The observations played forwards, backwards, forwards ... to `frames` frames."""
    T = obs.num_frames
    period = np.concatenate([np.arange(T), np.arange(T - 2, 0, -1)]) if T > 2 else np.arange(T)
    index = np.resize(period, frames)
    return dataclasses.replace(obs.select(index), source=f"{obs.source} looped to {frames} frames")


def resident_mb() -> float:
    """The process's resident memory now, MB (from /proc/self/statm)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def child(stage: str, observations: Path, frames: int, motion_file: Path) -> dict:
    """Run one stage on the looped observations in this process; its peak and CPU seconds."""
    from physmocap.config import Settings
    from physmocap.kinematics.stage import KinematicMotion, fit_motion
    from physmocap.motion import Observations

    obs = looped(Observations.load(observations), frames)
    settings = Settings()
    if stage == "fit":
        start_mb, cpu, wall = resident_mb(), cpu_seconds(), time.perf_counter()
        motion = fit_motion(obs, settings)
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
        np.savez(motion_file, **motion.to_arrays())
    else:
        from physmocap.contacts.predict import predict_contacts
        from physmocap.kinematics.refine import refine_kinematics

        with np.load(motion_file) as arrays:
            motion = KinematicMotion.from_arrays(arrays)
        contacts = predict_contacts(obs, "centred")[0]
        start_mb, cpu, wall = resident_mb(), cpu_seconds(), time.perf_counter()
        refine_kinematics(obs, motion, contacts, settings.fit, settings.trajopt)
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return dict(peak_mb=round(peak_mb, 1), start_mb=round(start_mb, 1), cpu_s=round(cpu, 2), wall_s=round(wall, 2))


def count_passes(observations: Path, frames: int) -> dict[str, float]:
    """Passes over the clip of each whole-clip fit (this checkout's code, in this process), from the progress
    counts: 1 + accepted steps + 2 per rejected step (the rejected step's pass and the system assembled again)."""
    from physmocap.config import Settings
    from physmocap.contacts.predict import predict_contacts
    from physmocap.kinematics.refine import refine_kinematics
    from physmocap.kinematics.stage import fit_motion
    from physmocap.motion import Observations

    obs = looped(Observations.load(observations), frames)
    done: dict[str, int] = {}

    def factory(name, total, unit="frames"):
        def update(count, total_now):
            done[name] = count
        return update if unit == "frame passes" else (lambda count, total_now: None)

    settings = Settings()
    motion = fit_motion(obs, settings, factory)
    refine_kinematics(obs, motion, predict_contacts(obs, "centred")[0], settings.fit, settings.trajopt,
                      progress=factory)
    return {name: count / frames for name, count in done.items()}


def measure(code: str, src: Path, stage: str, observations: Path, frames: int, motion_file: Path) -> dict:
    load_before = os.getloadavg()[0]
    env = dict(os.environ, PYTHONPATH=str(src))
    done = subprocess.run([sys.executable, __file__, "--child", stage, "--observations", str(observations),
                           "--frames", str(frames), "--motion-file", str(motion_file)],
                          env=env, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"{code} {stage} at {frames} frames failed:\n{done.stderr[-3000:]}")
    row = json.loads(done.stdout.strip().splitlines()[-1])
    return dict(code=code, stage=stage, frames=frames, **row,
                load_average=[round(load_before, 1), round(os.getloadavg()[0], 1)])


def table(rows: list[dict]) -> str:
    lines = ["| stage | frames | before: peak MB | after: peak MB | after: at start MB | before: CPU s | "
             "after: CPU s | after: CPU ms / frame | max pose difference | load average (after) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    by_key = {(r["code"], r["stage"], r["frames"]): r for r in rows}
    for stage in STAGES:
        for frames in sorted({r["frames"] for r in rows}):
            before, after = by_key.get(("before", stage, frames)), by_key.get(("after", stage, frames))
            if not (before or after):
                continue
            cell = lambda row, key, fmt="{:.0f}": fmt.format(row[key]) if row else "-"  # noqa: E731
            difference = after.get("max_pose_difference") if after else None
            lines.append(
                f"| {stage} | {frames} | {cell(before, 'peak_mb')} | {cell(after, 'peak_mb')} | "
                f"{cell(after, 'start_mb')} | {cell(before, 'cpu_s', '{:.1f}')} | {cell(after, 'cpu_s', '{:.1f}')} | "
                f"{'-' if not after else '{:.2f}'.format(1000 * after['cpu_s'] / frames)} | "
                f"{'-' if difference is None else f'{difference:.1e}'} | "
                f"{'-' if not after else '{} / {}'.format(*after['load_average'])} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--observations", type=Path, required=True, help="an observations .npz to loop")
    parser.add_argument("--frames", type=int, nargs="+", default=list(FRAMES))
    parser.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES))
    parser.add_argument("--codes", nargs="+", choices=("after", "before"), default=["after", "before"])
    parser.add_argument("--before-src", type=Path, help="another checkout's src folder: the 'before' rows")
    parser.add_argument("--after-src", type=Path, default=REPO / "src", help="the 'after' rows' source")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "physmocap_bench_memory",
                        help="where the fitted motions are kept (the refinement starts from them)")
    parser.add_argument("--count-passes", action="store_true",
                        help="only count each whole-clip fit's passes (rejected steps) at the first --frames")
    parser.add_argument("--child", choices=STAGES, help=argparse.SUPPRESS)
    parser.add_argument("--motion-file", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.observations, args.frames[0], args.motion_file)))
        return 0
    if args.count_passes:
        print(json.dumps(count_passes(args.observations, args.frames[0])))
        return 0

    sources = {"after": args.after_src, "before": args.before_src}
    if "before" in args.codes and args.before_src is None:
        parser.error("the 'before' rows need --before-src")
    rows = json.loads(RESULTS.read_text())["rows"] if RESULTS.exists() else []
    args.work.mkdir(parents=True, exist_ok=True)
    for frames in args.frames:
        for code in args.codes:
            motion_file = args.work / f"{code}_{frames}.npz"  # the fit's motion, which the refinement starts from
            for stage in args.stages:
                row = measure(code, sources[code], stage, args.observations, frames, motion_file)
                print(json.dumps(row), flush=True)
                rows = [r for r in rows if (r["code"], r["stage"], r["frames"]) != (code, stage, frames)] + [row]
        fits = [args.work / f"{code}_{frames}.npz" for code in ("after", "before")]
        if all(f.exists() for f in fits):  # the same fit to numerical noise
            with np.load(fits[0]) as after, np.load(fits[1]) as before:
                difference = float(np.abs(after["qpos"] - before["qpos"]).max())
            for r in rows:
                if (r["code"], r["stage"], r["frames"]) == ("after", "fit", frames):
                    r["max_pose_difference"] = difference
        RESULTS.write_text(json.dumps(dict(observations=str(args.observations), rows=rows), indent=1) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
