"""Whole capture, as a user runs it: wall time and peak memory of `physmocap capture` (default settings unless
--args says otherwise) on long videos made by looping a shared clip, per stage and per output.

Each case runs `physmocap capture VIDEO -o RUN` in a child process under /usr/bin/time -v (CPU seconds, peak
resident memory with native allocations); inside the child the output writers are wrapped with timers, so
summary.json's stage_seconds come with each output's own seconds, and each stage's own peak resident memory is
read from the kernel's high-water mark, reset before the stage (the run's peak is the largest of them). The
looped videos are made once in --videos (not committed): the clip is scaled and encoded once (libx264 veryfast,
CRF 20), then its packets are repeated with shifted timestamps, so the person jumps back to the clip's start at
every loop, as in any looped clip.

    .venv/bin/python benchmarks/bench_capture.py                       # 10 s and 60 s at 720p and 1080p
    .venv/bin/python benchmarks/bench_capture.py --seconds 10 60 600   # the full set (the 10-minute runs take long)
    .venv/bin/python benchmarks/bench_capture.py --seconds 60 --heights 720 --args=--physics=physcap
    .venv/bin/python benchmarks/bench_capture.py --seconds 60 --heights 720 --before ../old/src  # old, then this
    .venv/bin/python benchmarks/bench_capture.py --overlay-only        # overlay frames per second at 1280 px
    .venv/bin/python benchmarks/bench_capture.py --overlay-only --before ../main/src   # and an older checkout's
    .venv/bin/python benchmarks/bench_capture.py --overlay-pieces      # CPU ms per frame of each overlay step
    .venv/bin/python benchmarks/bench_capture.py --overlay-only --overlay-parts --seconds 10 60 --heights 720
                                                           # the overlay in one part against two, alternating
    .venv/bin/python benchmarks/bench_capture.py --overlay-gil         # a Python thread beside the rendering
    .venv/bin/python benchmarks/bench_capture.py --outputs-pieces RUNS/720p_60s --before ../old/src
                                                           # each output of a capture on its own, side by side
    .venv/bin/python benchmarks/bench_capture.py --time-orientation    # issue 24: variable rate, rotation

A capture with --before SRC runs first with the physmocap in SRC, then with this checkout's, on the same video.
--overlay-only --before SRC renders each case with this checkout's physmocap and with the one in SRC, in child
processes, alternating run by run so that both see the same load. Detection's CPU seconds in a capture come from
its own timer around detect_video; an output writer's CPU seconds are those of the thread that ran it (the overlay
runs in a worker beside the others, so its CPU is the outputs stage's less theirs).

--time-orientation judges whichever physmocap is on PYTHONPATH (point it at an older checkout for "before"):
a 24/12/8 fps video cut from the demo clip (each frame's index stamped in binary in its corner), read back:
the rate found, the largest error between a frame's position on the read timeline and its true time, and the
speed of each segment as read against its true speed; and the demo clip stored sideways with a phone's display
matrix: the image size detection reports and whether the person stands upright in the keypoints.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import itertools
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import REPO, VIDEOS, gil_probe, git_revision, machine_description  # noqa: E402
from physmocap.io.video import probe_video  # noqa: E402

CLIP = VIDEOS / "sports2d_demo.mp4"  # 30 fps, one person walking across the frame
LOOP_CRF = 20

# Output writers timed inside the child: (module, attribute) as write_outputs looks them up when it runs.
OUTPUT_WRITERS = (
    ("physmocap.pipeline", "build_result"), ("physmocap.pipeline", "save_result"),
    ("physmocap.io.bvh_export", "write_bvh"), ("physmocap.io.glb", "write_glb"),
    ("physmocap.export", "export_result"), ("physmocap.viz.overlay", "render_overlay"),
    ("physmocap.viz.viewer", "write_viewer"), ("physmocap.viz.report", "write_report"),
    ("physmocap.viz.report", "write_report_parts"),  # from outputs2 on: the plots and metrics, before summary.json
)
# Writers that run in the outputs stage's own thread: beside the overlay's worker, the report's parts after it.
MAIN_THREAD_WRITERS = ("build_result", "save_result", "write_bvh", "write_glb", "export_result", "write_viewer",
                       "write_report_parts")
# Stages whose own peak resident memory the child records (the kernel's high-water mark, reset before each).
STAGES = ("detect_stage", "stream_stage", "kinematics_stage", "contacts_stage", "refine_stage", "physics_stage",
          "trajopt_stage", "write_outputs")


def looped_video(clip: Path, out: Path, seconds: float, height: int) -> Path:
    """`clip` scaled to `height` lines (even width, same aspect), repeated to `seconds` long, as H.264 MP4 `out`."""
    if out.is_file():
        return out
    out.parent.mkdir(parents=True, exist_ok=True)
    once = out.with_suffix(".once.mp4")
    with av.open(str(clip)) as source, av.open(str(once), "w") as target:
        stream_in = source.streams.video[0]
        stream_in.thread_type = "AUTO"
        width = 2 * round(stream_in.width * height / stream_in.height / 2)
        rate = stream_in.average_rate
        stream = target.add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": str(LOOP_CRF), "preset": "veryfast"}
        for index, frame in enumerate(source.decode(stream_in)):
            scaled = frame.reformat(width=width, height=height, format="yuv420p", interpolation="AREA")
            scaled.pts, scaled.time_base = index, 1 / rate
            target.mux(stream.encode(scaled))
        target.mux(stream.encode(None))
    with av.open(str(once)) as source:
        stream_in = source.streams.video[0]
        packets = [p for p in source.demux(stream_in) if p.size]
        clip_ticks = int(round(len(packets) / rate / stream_in.time_base))
        loops = int(np.ceil(seconds * rate / len(packets)))
        frames = int(round(seconds * rate))
        tmp = out.with_suffix(".partial.mp4")
        with av.open(str(tmp), "w", options={"movflags": "+faststart"}) as target:
            stream = target.add_stream_from_template(stream_in)
            written = 0
            for loop in range(loops):
                for packet in sorted(packets, key=lambda p: p.dts):
                    if written >= frames:
                        break
                    copy = av.Packet(bytes(packet))
                    copy.pts, copy.dts = packet.pts + loop * clip_ticks, packet.dts + loop * clip_ticks
                    copy.is_keyframe, copy.time_base, copy.stream = packet.is_keyframe, stream_in.time_base, stream
                    target.mux(copy)
                    written += 1
    once.unlink()
    tmp.replace(out)
    return out


def load_average() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def run_case(video: Path, run_dir: Path, extra_args: list[str], source: Path = REPO / "src") -> dict:
    """One `physmocap capture` in a child under /usr/bin/time -v, with the physmocap in `source`: wall seconds,
    peak MB, stages, outputs."""
    timings = run_dir.with_suffix(".outputs.json")
    command = ["/usr/bin/time", "-v", sys.executable, __file__, "--child", str(timings), "capture", str(video),
               "-o", str(run_dir), *extra_args]
    load_before = load_average()
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(source)})
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"capture failed ({done.returncode}):\n{done.stdout}\n{done.stderr[-3000:]}")
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr).group(1))
    cpu = sum(float(re.search(rf"{kind} time \(seconds\): ([\d.]+)", done.stderr).group(1))
              for kind in ("User", "System"))
    summary = json.loads((run_dir / "summary.json").read_text())
    info = probe_video(video)
    duration = info.frame_count / info.fps
    child_report = json.loads(timings.read_text())
    outputs = child_report["seconds"]
    overlay_seconds = outputs.get("render_overlay")
    writer_cpu = child_report["writer_cpu_seconds"]
    outputs_cpu = child_report["cpu_seconds"]["write_outputs"] - writer_cpu.get("write_report", 0.0)
    detect_cpu = child_report["cpu_seconds"].get("detect_video")
    return dict(
        video=video.name, code=str(source), frames=summary["frames"], video_seconds=round(duration, 2),
        width=info.width, height=info.height, args=" ".join(extra_args), wall_seconds=round(wall, 1),
        wall_over_duration=round(wall / duration, 2), cpu_seconds=round(cpu, 1),
        cpu_over_duration_per_core=round(cpu / (os.cpu_count() or 1) / duration, 2),
        # the child resets the kernel's high-water mark before each stage, which /usr/bin/time reads too
        peak_rss_mb=round(max([peak_kb / 1024, *child_report["peak_mb"].values()])),
        stage_seconds={k: round(v, 1) for k, v in summary["stage_seconds"].items()},
        outputs_over_detection=round(summary["stage_seconds"]["outputs"] / summary["stage_seconds"]["detect"], 3),
        output_seconds={k: round(v, 2) for k, v in outputs.items()},
        stage_peak_rss_mb={k: round(v) for k, v in child_report["peak_mb"].items()},
        stage_cpu_seconds={k: round(v, 1) for k, v in child_report.get("cpu_seconds", {}).items()},
        writer_cpu_seconds={k: round(v, 2) for k, v in writer_cpu.items()},
        # the stage's CPU without the report, as its wall clock stops before the report
        outputs_cpu_seconds=round(outputs_cpu, 1),
        # and all of write_outputs, the report (its plots, metrics and page) and summary.json included
        outputs_with_report_cpu_seconds=round(child_report["cpu_seconds"]["write_outputs"], 1),
        outputs_with_report_seconds=round(child_report.get("wall_seconds", {}).get("write_outputs", 0.0), 1),
        outputs_with_report_over_detection_cpu=None if not detect_cpu
        else round(child_report["cpu_seconds"]["write_outputs"] / detect_cpu, 3),
        overlay_cpu_seconds=round(outputs_cpu - sum(writer_cpu.get(k, 0.0) for k in MAIN_THREAD_WRITERS), 1)
        if overlay_seconds else None,
        outputs_over_detection_cpu=None if not detect_cpu else round(outputs_cpu / detect_cpu, 3),
        overlay_fps=None if not overlay_seconds else round(summary["frames"] / overlay_seconds, 1),
        load_average_before=load_before, load_average_after=load_average(),
    )


def child(timings_path: str, cli_args: list[str]) -> int:
    """Run the CLI with the output writers wrapped in timers; write {writer: seconds} to `timings_path`."""
    import importlib

    from physmocap import cli

    seconds: dict[str, float] = {}
    writer_cpu: dict[str, float] = {}

    def timed(name, function):
        def wrapper(*args, **kwargs):
            started, cpu_started = time.perf_counter(), time.thread_time()
            try:
                return function(*args, **kwargs)
            finally:
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - started
                writer_cpu[name] = writer_cpu.get(name, 0.0) + time.thread_time() - cpu_started
        return wrapper

    peak_mb: dict[str, float] = {}
    cpu_seconds: dict[str, float] = {}
    wall_seconds: dict[str, float] = {}

    def high_water(name, function):
        def wrapper(*args, **kwargs):
            Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM to the current resident size
            cpu_started, started = time.process_time(), time.perf_counter()  # CPU: all threads of the process
            try:
                return function(*args, **kwargs)
            finally:
                cpu_seconds[name] = time.process_time() - cpu_started
                wall_seconds[name] = time.perf_counter() - started
                status = Path("/proc/self/status").read_text()
                peak_mb[name] = int(re.search(r"VmHWM:\s+(\d+) kB", status).group(1)) / 1024
        return wrapper

    for module_name, attribute in OUTPUT_WRITERS:
        module = importlib.import_module(module_name)
        if hasattr(module, attribute):  # an older checkout may lack a newer writer
            setattr(module, attribute, timed(attribute, getattr(module, attribute)))
    detection = importlib.import_module("physmocap.detect.mediapipe_pose")  # the detect stage looks it up there
    detection.detect_video = high_water("detect_video", detection.detect_video)
    pipeline = importlib.import_module("physmocap.pipeline")
    for stage in STAGES:
        if hasattr(pipeline, stage):
            setattr(pipeline, stage, high_water(stage, getattr(pipeline, stage)))
    code = cli.main(cli_args)
    Path(timings_path).write_text(json.dumps({"seconds": seconds, "peak_mb": peak_mb, "cpu_seconds": cpu_seconds,
                                              "writer_cpu_seconds": writer_cpu, "wall_seconds": wall_seconds}))
    return code or 0


def overlay_speed(video: Path, width: int | None, repeats: int, parts: int | None = None) -> dict:
    """Frames per second of render_overlay on `video` with a full skeleton, contacts, keypoints and arrows drawn,
    in `parts` parts (None: as render_overlay chooses; an older checkout's render_overlay takes no `parts`)."""
    from physmocap.body.kinematics import forward_kinematics
    from physmocap.body.model import build_body_model, template_lengths
    from physmocap.viz import overlay
    from physmocap.viz.overlay import render_overlay, skeleton_edges

    info = probe_video(video)
    body = build_body_model(template_lengths(1.7), 70)
    world = forward_kinematics(body, body.rest_qpos).points[0]
    T = info.frame_count
    sway = np.sin(np.arange(T) / 10.0)[:, None, None]
    pixels = np.stack([info.width / 2 - info.height / 2.2 * world[:, 1],
                       info.height * 0.95 - info.height / 2.2 * world[:, 2]], axis=1)[None] + 20 * sway
    keypoints = np.concatenate([pixels[:, np.arange(33) % pixels.shape[1]], np.full((T, 33, 1), 0.9)], axis=2)
    arrows = np.stack([pixels[:, :4], pixels[:, :4] - [0.0, 80.0]], axis=2)
    contacts = np.ones((T, 4), bool)
    times, cpu, join_seconds = [], [], []
    join = getattr(overlay, "join_video_parts", None)
    if join is not None:  # the joining step's own wall seconds
        def timed_join(*args, **kwargs):
            started = time.perf_counter()
            try:
                return join(*args, **kwargs)
            finally:
                join_seconds.append(time.perf_counter() - started)
        overlay.join_video_parts = timed_join
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(repeats):
            started, cpu_started = time.perf_counter(), time.process_time()
            report = render_overlay(video, Path(folder) / "overlay.mp4", pixels, skeleton_edges(body),
                                    np.ones(T, bool), keypoints=keypoints, contacts=contacts,
                                    labels=body.point_names, force_arrows=arrows, max_width=width,
                                    **({} if parts is None else {"parts": parts}))
            times.append(time.perf_counter() - started)
            cpu.append(time.process_time() - cpu_started)  # all threads: decoder, drawing, x264
            size = (Path(folder) / "overlay.mp4").stat().st_size
        background_error = background_difference(video, Path(folder) / "overlay.mp4", report.width)
    seconds = float(np.median(times))
    return dict(video=video.name, input=f"{info.width}x{info.height}", output=f"{report.width}x{report.height}",
                preset=overlay.OVERLAY_PRESET, parts=getattr(report, "parts", 1), frames=T, seconds=round(seconds, 2),
                fps=round(T / seconds, 1), cpu_seconds=round(float(np.median(cpu)), 2),
                cores_busy=round(float(np.median(np.divide(cpu, times))), 2),
                join_seconds=round(float(np.median(join_seconds)), 3) if join_seconds else None,
                cpu_ms_per_frame=round(1000 * float(np.median(cpu)) / T, 1), megabytes=round(size / 1e6, 1),
                background_error=background_error,
                repeats=repeats, load_average=load_average())


def background_difference(video: Path, overlay_video: Path, width: int, every: int = 50) -> float:
    """Mean absolute difference (0-255, BGR) between the overlay and its source video, scaled to the overlay's
    width, in the left quarter of every `every`-th frame, where overlay_speed draws nothing."""
    import cv2

    def frames(path: Path) -> list[np.ndarray]:
        with av.open(str(path)) as container:
            decoded = itertools.islice(container.decode(container.streams.video[0]), 0, None, every)
            return [frame.to_ndarray(format="bgr24") for frame in decoded]

    differences = []
    # strict=False: a variable-rate source decodes to more or fewer frames than its constant-rate overlay
    for source, drawn in zip(frames(video), frames(overlay_video), strict=False):
        source = cv2.resize(source, drawn.shape[1::-1], interpolation=cv2.INTER_AREA)
        quarter = drawn.shape[1] // 4
        differences.append(np.abs(source[:, :quarter].astype(int) - drawn[:, :quarter]).mean())
    return round(float(np.mean(differences)), 2)


def overlay_side_by_side(video: Path, width: int | None, repeats: int, before: Path) -> list[dict]:
    """overlay_speed of this checkout and of the physmocap in `before`, one render per child process, the two
    alternating; each side's median over its `repeats` runs."""
    runs: dict[str, list[dict]] = {"after": [], "before": []}
    for _ in range(repeats):
        for side, source in (("before", before), ("after", REPO / "src")):
            command = [sys.executable, __file__, "--overlay-child", str(video), str(width or 0)]
            done = subprocess.run(command, capture_output=True, text=True, check=True,
                                  env={**os.environ, "PYTHONPATH": str(source)})
            runs[side].append(json.loads(done.stdout.splitlines()[-1]))
    rows = []
    for side, source in (("before", before), ("after", REPO / "src")):
        row = dict(runs[side][0], code=f"{side} ({source})", repeats=repeats, load_average=load_average())
        for key in ("seconds", "fps", "cpu_ms_per_frame"):
            row[key] = round(float(np.median([run[key] for run in runs[side]])), 2)
        rows.append(row)
    return rows


def overlay_parts_side_by_side(video: Path, width: int | None, repeats: int) -> list[dict]:
    """overlay_speed in one part and in two, one render per child process, the two alternating run by run so that
    both see the same load; each side's median over its `repeats` runs (wall and CPU seconds, cores busy)."""
    runs: dict[int, list[dict]] = {1: [], 2: []}
    for _ in range(repeats):
        for parts in (1, 2):
            command = [sys.executable, __file__, "--overlay-child", str(video), str(width or 0), str(parts)]
            done = subprocess.run(command, capture_output=True, text=True, check=True)
            runs[parts].append(json.loads(done.stdout.splitlines()[-1]))
    rows = []
    for side in runs.values():
        row = dict(side[0], repeats=repeats, load_average=load_average(),
                   runs=[dict(seconds=run["seconds"], cpu_seconds=run["cpu_seconds"], load=run["load_average"])
                         for run in side])
        for key in ("seconds", "fps", "cpu_seconds", "cores_busy", "cpu_ms_per_frame"):
            row[key] = round(float(np.median([run[key] for run in side])), 2)
        rows.append(row)
    return rows


def overlay_gil_probe(video: Path, width: int | None) -> list[dict]:
    """Does the overlay hold the GIL? `common.gil_probe` with the caller rendering `video` in one part."""
    from physmocap.viz import overlay

    def render() -> None:
        T = probe_video(video).frame_count
        points = np.full((T, 1, 2), 100.0) + np.arange(T)[:, None, None] % 200
        overlay.render_overlay(video, Path(tempfile.mkdtemp()) / "overlay.mp4", points, [], np.ones(T, bool),
                               keypoints=np.concatenate([points, np.ones((T, 1, 1))], axis=2), max_width=width,
                               parts=1)

    return gil_probe(render, "renders")


def overlay_pieces(video: Path, width: int, frames: int = 300) -> dict:
    """CPU ms per frame of each step of the overlay, old way and new, each over the first `frames` frames on its
    own (all threads of the process; decoding uses PyAV's frame threads as the reader does)."""
    import cv2

    from physmocap.body.kinematics import forward_kinematics
    from physmocap.body.model import build_body_model, template_lengths
    from physmocap.io.video import VideoWriter, copy_yuv420, yuv420_planes
    from physmocap.viz import overlay

    def cpu_ms(step, items):
        started = time.process_time()
        result = [step(item) for item in items]
        return result, round(1000 * (time.process_time() - started) / len(items), 2)

    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        started = time.process_time()
        decoded = list(itertools.islice(container.decode(stream), frames))
        decode_ms = round(1000 * (time.process_time() - started) / len(decoded), 2)
    height = 2 * round(decoded[0].height * width / decoded[0].width / 2)
    body = build_body_model(template_lengths(1.7), 70)
    world = forward_kinematics(body, body.rest_qpos).points[0]
    pixels = np.stack([width / 2 - height / 2.2 * world[:, 1], height * 0.95 - height / 2.2 * world[:, 2]], axis=1)
    keypoints = np.concatenate([pixels[np.arange(33) % len(pixels)], np.full((33, 1), 0.9)], axis=1)
    arrows = np.stack([pixels[:4], pixels[:4] - [0.0, 80.0]], axis=1)
    contacts, edges = np.ones(4, bool), overlay.skeleton_edges(body)
    drawing = (pixels, edges, body.point_names, keypoints, contacts, arrows, True, False)

    def encode(pictures) -> int:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "overlay.mp4"
            with VideoWriter(path, 30.0, width, height, qp=overlay.OVERLAY_QP, preset=overlay.OVERLAY_PRESET) as out:
                for picture in pictures:  # through a picture of our own, as render_overlay does
                    out.write_yuv420(copy_yuv420(picture, canvas))
            return path.stat().st_size

    row = dict(video=video.name, input=f"{decoded[0].width}x{decoded[0].height}", output=f"{width}x{height}",
               frames=len(decoded), decode_ms=decode_ms)
    bgr, row["old_to_bgr_scaled_ms"] = cpu_ms(
        lambda f: f.to_ndarray(format="bgr24", width=width, height=height, interpolation="AREA"), decoded)
    _, row["old_draw_bgr_ms"] = cpu_ms(lambda image: overlay._draw_in_place(image, *drawing), bgr)
    _, row["old_bgr_to_yuv420p_ms"] = cpu_ms(
        lambda image: av.VideoFrame.from_ndarray(image, format="bgr24").reformat(format="yuv420p"), bgr)
    scaled, row["new_scale_yuv420p_ms"] = cpu_ms(
        lambda f: f.reformat(width=width, height=height, format="yuv420p", interpolation="AREA"), decoded)
    canvas = copy_yuv420(scaled[0])
    _, row["new_copy_ms"] = cpu_ms(lambda picture: copy_yuv420(picture, canvas), scaled)
    scratch = overlay.YuvScratch(width, height)
    _, row["new_draw_yuv420p_ms"] = cpu_ms(
        lambda picture: overlay._draw_yuv420(yuv420_planes(copy_yuv420(picture, canvas)), scratch, *drawing), scaled)
    row["new_draw_yuv420p_ms"] = round(row["new_draw_yuv420p_ms"] - row["new_copy_ms"], 2)
    started = time.process_time()
    size = encode(scaled)
    row["encode_ms"] = round(1000 * (time.process_time() - started) / len(scaled) - row["new_copy_ms"], 2)
    row["megabytes_per_10_s"] = round(size / 1e6 * 10 * 30 / len(scaled), 1)
    row["cv2_threads"] = cv2.getNumThreads()
    row["load_average"] = load_average()
    return row


def _timed(step) -> tuple[float, float]:
    """CPU seconds (all threads of the process) and wall seconds of step()."""
    cpu_started, started = time.process_time(), time.perf_counter()
    step()
    return time.process_time() - cpu_started, time.perf_counter() - started


def _run_drawing(run: Path):
    """The overlay's drawing of a capture's run folder, as the pipeline's _start_overlay makes it, from
    result.npz: (video, result, body, render_overlay's arguments after the video and output path). Rebuilt here
    from public pieces so that an older checkout, run with --before, draws the same."""
    from physmocap.body.model import CONTACT_POINTS
    from physmocap.camera import Camera
    from physmocap.export import body_from_result
    from physmocap.result import RESULT_POINTS, load_result
    from physmocap.viz import overlay

    result = load_result(run / "result.npz")
    video = Path(json.loads((run / "summary.json").read_text())["input"])
    body = body_from_result(result)
    camera = Camera(result["camera_K"], result["camera_R"], result["camera_t"],
                    tuple(int(v) for v in result["image_size"]))
    soles = result["joints_world"][:, [RESULT_POINTS.index(n) for n in CONTACT_POINTS]]
    arrows = overlay.force_arrows_2d(soles, result["grf"], camera.project,
                                     overlay.force_arrow_scale(body.mass, body.height))
    drawing = dict(points_2d=camera.project(result["joints_world"]), edges=overlay.skeleton_edges(body),
                   valid=result["valid"], keypoints=result["keypoints_2d"], contacts=result["contacts"],
                   labels=RESULT_POINTS, force_arrows=arrows, unexplained=result["physics_unexplained"])
    return video, result, body, drawing


def _overlay_steps(video: Path, drawing: dict, folder: Path) -> dict:
    """CPU and wall seconds of the overlay's steps over every frame, each pass in this thread: decoding alone,
    decoding with the copy and the drawing, and decoding with the copy and x264 at CRF 23 and at QP 21 (where the
    writer takes `qp`), nothing drawn."""
    import inspect

    from physmocap.io.video import VideoWriter, copy_yuv420, iter_frames, yuv420_planes
    from physmocap.viz import overlay

    state = overlay._overlay_drawing(**drawing)
    new_writer = "qp" in inspect.signature(VideoWriter).parameters

    def frames():
        """(reader, its first state.frames pictures): the frames the overlay draws."""
        reader = iter_frames(video, max_width=1280, pixel_format="yuv420p")
        return reader, itertools.islice(reader, state.frames)

    def decode() -> None:
        for _ in frames()[1]:
            pass

    def draw() -> None:
        (reader, pictures), canvas = frames(), None
        scale = np.array(reader.output_size) / [reader.info.width, reader.info.height]
        scratch = overlay.YuvScratch(*reader.output_size)
        for index, picture in pictures:
            canvas = copy_yuv420(picture, canvas)
            overlay._draw_yuv420(yuv420_planes(canvas), scratch, state.points_2d[index] * scale, state.edges,
                                 state.labels, state.keypoints[index] * np.append(scale, 1.0), state.contacts[index],
                                 state.force_arrows[index] * scale, bool(state.valid[index]),
                                 bool(state.unexplained[index]))

    def encode(**rate) -> None:
        (reader, pictures), canvas = frames(), None
        with VideoWriter(folder / "encoded.mp4", reader.info.fps, *reader.output_size, preset="ultrafast",
                         **rate) as writer:
            for _, picture in pictures:
                canvas = copy_yuv420(picture, canvas)
                writer.write_yuv420(canvas)

    steps = {"decode": decode, "decode_copy_draw": draw, "decode_copy_x264_crf23": lambda: encode(crf=23)}
    if new_writer:
        steps["decode_copy_x264_qp21"] = lambda: encode(qp=21)
    row = {}
    for name, step in steps.items():
        row[name] = _timed(step)
        if name.startswith("decode_copy_x264"):
            row[name.replace("decode_copy_", "") + "_megabytes"] = round((folder / "encoded.mp4").stat().st_size / 1e6, 1)
    return row


def outputs_pieces(run: Path) -> dict:
    """CPU and wall seconds of each output of a capture's run folder on its own, from its result.npz and video:
    the writers one after the other, the overlay's steps (_overlay_steps) and the whole overlay in one part and
    in two. Runs the physmocap on PYTHONPATH."""
    from physmocap.export import EXPORTERS
    from physmocap.io.bvh_export import write_bvh
    from physmocap.io.glb import write_glb
    from physmocap.result import save_result
    from physmocap.viz.overlay import render_overlay
    from physmocap.viz.plots import write_plots
    from physmocap.viz.report import run_metrics, write_report
    from physmocap.viz.viewer import write_viewer

    video, result, body, drawing = _run_drawing(run)
    fps = float(result["fps"])
    with tempfile.TemporaryDirectory() as name:
        folder = Path(name)
        writers = {
            "result.npz": lambda: save_result(folder / "result.npz", result),
            "motion.bvh": lambda: write_bvh(folder / "motion.bvh", body, result["qpos"], fps),
            "motion.glb": lambda: write_glb(folder / "motion.glb", body, result["qpos"], fps),
            "opensim": lambda: EXPORTERS["opensim"](result, folder),
            "viewer.html": lambda: write_viewer(result, folder / "viewer.html"),
            "plots": lambda: write_plots(result, folder / "plots"),
            "metrics": lambda: run_metrics(result),
            "report (plots, metrics, page)": lambda: write_report(folder, result),
        }
        row = {name: _timed(step) for name, step in writers.items()}
        row.update(_overlay_steps(video, drawing, folder))
        for parts in (1, 2):
            row[f"overlay, {parts} part{'s' * (parts > 1)}"] = _timed(
                lambda parts=parts: render_overlay(video, folder / "overlay.mp4", **drawing, max_width=1280,
                                                   parts=parts))
        row["overlay_megabytes"] = round((folder / "overlay.mp4").stat().st_size / 1e6, 1)
    return dict(frames=len(result["valid"]), **{k: [round(x, 3) for x in v] if isinstance(v, tuple) else v
                                                for k, v in row.items()}, load_average=load_average())


def outputs_pieces_side_by_side(run: Path, repeats: int, before: Path | None) -> list[dict]:
    """outputs_pieces of this checkout and, where given, of the physmocap in `before`, one child process each,
    alternating run by run; each figure's median over the `repeats` runs of its side."""
    sides = [("after", REPO / "src")] if before is None else [("before", before), ("after", REPO / "src")]
    runs: dict[str, list[dict]] = {side: [] for side, _ in sides}
    for _ in range(repeats):
        for side, source in sides:
            command = [sys.executable, __file__, "--pieces-child", str(run)]
            done = subprocess.run(command, capture_output=True, text=True, check=True,
                                  env={**os.environ, "PYTHONPATH": str(source)})
            runs[side].append(json.loads(done.stdout.splitlines()[-1]))
            print(json.dumps(dict(side=side, **runs[side][-1])), flush=True)
    rows = []
    for side, source in sides:
        row: dict = dict(code=f"{side} ({source})", repeats=repeats, frames=runs[side][0]["frames"])
        for key, value in runs[side][0].items():
            if isinstance(value, list):  # [CPU s, wall s] -> medians, and CPU ms per frame
                cpu, wall = np.median([run[key] for run in runs[side]], axis=0)
                row[key] = dict(cpu_s=round(float(cpu), 3), wall_s=round(float(wall), 3),
                                cpu_ms_per_frame=round(1000 * float(cpu) / row["frames"], 2))
            elif key.endswith("megabytes"):
                row[key] = value
        rows.append(row)
    return rows


def time_and_orientation(folder: Path) -> list[dict]:
    """Issue 24's time and orientation cases on the demo clip (see the module docstring)."""
    import cv2

    sys.path.insert(0, str(REPO / "tests"))
    from physmocap.detect.mediapipe_pose import detect_video
    from physmocap.io.video import iter_frames
    from physmocap.landmarks import LANDMARK_INDEX
    from test_video_io import write_timed_video

    folder.mkdir(parents=True, exist_ok=True)
    frames = [frame for _, frame in iter_frames(REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4")]
    step = 1001 / 24000
    kept = list(range(0, 32)) + list(range(32, 64, 2)) + list(range(64, 96, 3))  # 24, 12, then 8 fps
    stamped = []
    for index in kept:
        frame = frames[index].copy()
        for bit in range(7):
            frame[:16, 16 * bit:16 * bit + 16] = 255 * ((index >> bit) & 1)
        stamped.append(frame)
    vfr = write_timed_video(folder / "vfr.mp4", stamped, kept, Fraction(1001, 24000))
    info = probe_video(vfr)
    shown = np.array([sum(int(f[4:12, 16 * b + 4:16 * b + 12].mean() > 128) << b for b in range(7))
                      for _, f in iter_frames(vfr)])
    true_time, read_time = shown * step, np.arange(len(shown)) / info.fps
    starts = [0, int(np.searchsorted(shown, 32)), int(np.searchsorted(shown, 64)), len(shown)]
    speed = [(true_time[b - 1] - true_time[a]) / (read_time[b - 1] - read_time[a]) for a, b in itertools.pairwise(starts)]
    rows = [dict(case="24/12/8 fps video", fps_read=round(info.fps, 2), frames_read=len(shown),
                 max_time_error_ms=round(1000 * float(np.abs(read_time - true_time).max()), 1),
                 speed_24_12_8fps_segments=[round(v, 2) for v in speed])]
    sideways = [cv2.rotate(frame, cv2.ROTATE_90_COUNTERCLOCKWISE) for frame in frames[:24]]
    phone = write_timed_video(folder / "phone.mp4", sideways, list(range(24)), Fraction(1001, 24000), rotation_cw=90)
    obs = detect_video(phone)
    x, y = obs.keypoints_2d[..., 0], obs.keypoints_2d[..., 1]
    ankle, nose = LANDMARK_INDEX["left_ankle"], LANDMARK_INDEX["nose"]
    upright = np.median(y[:, ankle] - y[:, nose]) > np.median(np.abs(x[:, ankle] - x[:, nose]))
    rows.append(dict(case="phone video, display matrix 90 deg clockwise, stored 360x640",
                     image_size=list(obs.image_size), valid_frames=f"{int(obs.valid.sum())}/{obs.num_frames}",
                     person_upright_in_keypoints=bool(upright)))
    return rows


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        return child(sys.argv[2], sys.argv[3:])
    if len(sys.argv) == 3 and sys.argv[1] == "--pieces-child":  # RUN
        print(json.dumps(outputs_pieces(Path(sys.argv[2]))))
        return 0
    if len(sys.argv) in (4, 5) and sys.argv[1] == "--overlay-child":  # VIDEO WIDTH [PARTS]
        parts = int(sys.argv[4]) if len(sys.argv) == 5 else None
        print(json.dumps(overlay_speed(Path(sys.argv[2]), int(sys.argv[3]) or None, 1, parts)))
        return 0
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, nargs="+", default=[10, 60])
    parser.add_argument("--heights", type=int, nargs="+", default=[720, 1080])
    parser.add_argument("--args", default="", help="extra capture arguments, e.g. --args=--physics=physcap")
    parser.add_argument("--videos", type=Path, default=Path(tempfile.gettempdir()) / "physmocap_bench_videos")
    parser.add_argument("--runs", type=Path, default=None, help="run folders (default: a temporary folder)")
    parser.add_argument("--overlay-only", action="store_true", help="only overlay speed, 10 s at each height")
    parser.add_argument("--overlay-width", type=int, default=1280)
    parser.add_argument("--repeats", type=int, default=3, help="overlay-only: runs per case (median)")
    parser.add_argument("--presets", nargs="+", default=None, help="overlay-only: libx264 presets to compare")
    parser.add_argument("--before", type=Path, default=None,
                        help="also run with the physmocap in this src folder, side by side (captures: that one first)")
    parser.add_argument("--overlay-pieces", action="store_true", help="CPU ms per frame of each overlay step")
    parser.add_argument("--overlay-gil", action="store_true", help="a Python thread beside the overlay's rendering")
    parser.add_argument("--overlay-parts", action="store_true",
                        help="overlay-only: one part against two, alternating (--seconds: the looped videos' lengths)")
    parser.add_argument("--outputs-pieces", type=Path, default=None, metavar="RUN",
                        help="each output's CPU and wall seconds from a capture's run folder (with --before: side by "
                             "side, alternating; --repeats runs each)")
    parser.add_argument("--time-orientation", action="store_true", help="only issue 24's time and rotation cases")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args()

    print(f"# {machine_description()}, commit {git_revision()}", flush=True)
    rows = []
    if args.time_orientation:
        rows = time_and_orientation(Path(tempfile.mkdtemp(prefix="bench_time_")))
        print("\n".join(json.dumps(row) for row in rows), flush=True)
    elif args.outputs_pieces is not None:
        rows = outputs_pieces_side_by_side(args.outputs_pieces, args.repeats,
                                           None if args.before is None else args.before.resolve())
        print("\n".join(json.dumps(row) for row in rows), flush=True)
    elif args.overlay_pieces:
        for height in args.heights:
            video = looped_video(CLIP, args.videos / f"loop_{height}p_10s.mp4", 10, height)
            rows.append(overlay_pieces(video, args.overlay_width))
            print(json.dumps(rows[-1]), flush=True)
    elif args.overlay_gil:
        video = looped_video(CLIP, args.videos / "loop_720p_10s.mp4", 10, 720)
        rows = overlay_gil_probe(video, args.overlay_width)
        print("\n".join(json.dumps(row) for row in rows), flush=True)
    elif args.overlay_only and args.overlay_parts:
        for seconds in args.seconds:
            for height in args.heights:
                video = looped_video(CLIP, args.videos / f"loop_{height}p_{seconds:g}s.mp4", seconds, height)
                for row in overlay_parts_side_by_side(video, args.overlay_width, args.repeats):
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    elif args.overlay_only and args.before is not None:
        for height in args.heights:
            video = looped_video(CLIP, args.videos / f"loop_{height}p_10s.mp4", 10, height)
            for row in overlay_side_by_side(video, args.overlay_width, args.repeats, args.before.resolve()):
                rows.append(row)
                print(json.dumps(row), flush=True)
    elif args.overlay_only:
        from physmocap.viz import overlay

        for preset in args.presets or [overlay.OVERLAY_PRESET]:
            overlay.OVERLAY_PRESET = preset
            for height in args.heights:
                video = looped_video(CLIP, args.videos / f"loop_{height}p_10s.mp4", 10, height)
                rows.append(overlay_speed(video, args.overlay_width, args.repeats))
                print(json.dumps(rows[-1]), flush=True)
    else:
        runs = Path(tempfile.mkdtemp(prefix="bench_capture_")) if args.runs is None else args.runs
        for seconds in args.seconds:
            for height in args.heights:
                video = looped_video(CLIP, args.videos / f"loop_{height}p_{seconds:g}s.mp4", seconds, height)
                sources = [REPO / "src"] if args.before is None else [args.before.resolve(), REPO / "src"]
                for source in sources:
                    suffix = "_before" if source != REPO / "src" else ""
                    run_dir = runs / f"{height}p_{seconds:g}s{suffix}"
                    rows.append(run_case(video, run_dir, shlex.split(args.args), source))
                    print(json.dumps(rows[-1]), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
