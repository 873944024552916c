"""Shared helpers of the benchmark scripts: data locations, machine description, timing."""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import dataclasses
import json
import os
import platform
import statistics
import subprocess
import time
import tomllib
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from physmocap.body import kinematics as kin
from physmocap.config import PhysicsSettings, Settings
from physmocap.errors import InputError, SettingsError
from physmocap.evaluation import score_against_truth, to_truth_world
from physmocap.mocap.synthetic import NoiseModel
from physmocap.settings_fields import from_table, nearest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PHYSMOCAP_SHARED", REPO.parent / "shared"))
VIDEOS = SHARED / "data" / "videos"
MOCAP = SHARED / "data" / "mocap"
RESULTS = REPO / "benchmarks" / "results"
# Observations exactly as the synthetic camera sees the truth: what a method costs with a perfect detector.
NOISE_FREE = NoiseModel(keypoint_sd=0.0, keypoint_drift_sd=0.0, landmark_sd=0.0, landmark_drift_sd=0.0,
                        depth_scale_sd=0.0, confidence_sd=0.0, dropout_per_second=0.0, foot_swaps_per_second=0.0)
Pictures = list[np.ndarray]  # BGR (H, W, 3) uint8 pictures


def read_clip(name: str, seconds: float | None = None, every: int = 1) -> tuple[Pictures, float]:
    """A shared video's pictures (its first `seconds`, default all), BGR, every `every`-th one, and their frame rate
    (the video's / every: the true rate of that subsampling)."""
    with av.open(str(VIDEOS / name)) as container:
        stream = container.streams.video[0]
        fps = float(stream.average_rate)
        pictures = []
        for index, frame in enumerate(container.decode(stream)):
            if seconds is not None and index >= round(seconds * fps):
                break
            if index % every == 0:
                pictures.append(frame.to_ndarray(format="bgr24"))
    return pictures, fps / every


def write_clip(path: Path, pictures: Pictures, fps: float, crf: int | None = None) -> None:
    """H.264 at `fps`, the pictures cut to even sizes (yuv420p); crf: libx264's constant rate factor (0-51, lower is
    better; None: its default, 23). The same pictures give the same bytes: one encoder thread, and the colour
    conversion by OpenCV. With several threads, or with PyAV's own conversion, sports2d's pictures (1768 x 994)
    came out as other bytes on most calls, and their detections and ratios moved with them."""
    height, width = (size - size % 2 for size in pictures[0].shape[:2])
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"threads": "1"} | ({} if crf is None else {"crf": str(crf)})
        for picture in pictures:
            planes = cv2.cvtColor(np.ascontiguousarray(picture[:height, :width]), cv2.COLOR_BGR2YUV_I420)
            container.mux(stream.encode(av.VideoFrame.from_ndarray(planes, format="yuv420p")))
        container.mux(stream.encode())


def truth_scores(motion, qpos: np.ndarray, truth: dict, grf=None, residual=None) -> dict:
    """The synthetic table's metrics (evaluation.score_against_truth) of qpos (T, nq) in `motion`'s world and
    camera, against a synthetic case's `truth`; grf (T, 4, 3) and residual (T, 6) for the force figures."""
    pose = kin.forward_kinematics(motion.body, qpos)
    points = to_truth_world(pose.points, motion.camera.R, motion.camera.t, truth)
    com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
    return score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass, grf, residual)


def machine_description() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def git_revision() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=REPO).stdout.strip()
    except OSError:
        return "unknown"


def median_time(fn, repeats: int = 3) -> tuple[float, object]:
    """Median wall time of `repeats` calls, and the last call's result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def gil_probe(work, label: str) -> list[dict]:
    """Does `work()` hold the GIL? A pure-Python counting thread runs beside a caller that sleeps 3 s, then beside
    one that runs `work` (rows named `label`), twice each: the counter's cores (its CPU over its wall seconds) and
    pace, and the calling thread's and the process's CPU seconds (native libraries work in threads of their own)."""
    import threading

    rows = []
    for caller in ("sleeps", label, "sleeps", label):
        stop, counted = threading.Event(), dict()

        def count(stop: threading.Event = stop, counted: dict = counted) -> None:
            wall, cpu, n = time.perf_counter(), time.thread_time(), 0
            while not stop.is_set():
                n += 1
            counted.update(n=n, wall=time.perf_counter() - wall, cpu=time.thread_time() - cpu)

        counter = threading.Thread(target=count)
        counter.start()
        wall, cpu, process_cpu = time.perf_counter(), time.thread_time(), time.process_time()
        if caller == "sleeps":
            time.sleep(3.0)
        else:
            work()
        caller_wall, caller_cpu = time.perf_counter() - wall, time.thread_time() - cpu
        process = time.process_time() - process_cpu
        stop.set()
        counter.join()
        rows.append(dict(caller=caller, caller_wall_s=round(caller_wall, 2), caller_thread_cpu_s=round(caller_cpu, 2),
                         process_cpu_s=round(process, 2), counter_cores=round(counted["cpu"] / counted["wall"], 2),
                         counter_mcounts_per_s=round(counted["n"] / counted["wall"] / 1e6, 2),
                         load=os.getloadavg()[0]))
    return rows


def settings_overrides(pairs: list[str]) -> dict:
    """NAME=VALUE pairs (a benchmark's --physics) -> the PhysicsSettings fields they set, each VALUE read and checked
    as a settings file's [physics] table would be (true, 0.5, "never"; a bare word is read as text; None switches off
    a setting that allows it). SystemExit with one sentence for the first bad pair."""
    texts = {}
    for pair in pairs:
        name, sep, text = pair.partition("=")
        if not sep:
            raise SystemExit(f"--physics {pair}: expected NAME=VALUE.")
        texts[name] = text
    known = [f.name for f in dataclasses.fields(PhysicsSettings)]
    for name in texts:
        if name not in known:
            raise SystemExit(f"--physics: unknown setting physics.{name}{nearest(name, known, 'physics.')}.")
    off = [name for name, text in texts.items() if text in ("None", "none")]
    table = tomllib.loads("\n".join(f"{name} = {_toml_value(text)}" for name, text in texts.items() if name not in off))
    try:
        physics = from_table(Settings, {"physics": table}, "--physics").physics
    except (InputError, SettingsError) as exc:
        raise SystemExit(str(exc)) from None
    try:
        physics = physics.replace(**dict.fromkeys(off)).check()
    except SettingsError as exc:
        raise SystemExit(f"--physics: {exc}") from None
    return {name: getattr(physics, name) for name in texts}


def _toml_value(text: str) -> str:
    """A --physics VALUE as TOML: as written where it is TOML (true, 0.5, "never"), else quoted as text."""
    try:
        tomllib.loads(f"v = {text}")
        return text
    except tomllib.TOMLDecodeError:
        return json.dumps(text)
