"""Detection with one MediaPipe graph against two at once (issue 23): wall and CPU seconds, peak memory, and how far
the two graphs' landmarks are from the sequential run's, frame by frame.

Each run is `detect_video` in a child process (so that its peak resident memory is its own), one graph and two
graphs alternating, `--repeats` pairs per video. CPU seconds are the child's user + system time (all its threads);
peak memory is its ru_maxrss. The landmark comparison takes the last run of each: per frame, the largest distance
in pixels between the same keypoint of the two runs (frames valid in both), before the split (should be 0), at
the junction, and after it.

    .venv/bin/python benchmarks/bench_detect.py                                   # the looped 60 s 720p clip
    .venv/bin/python benchmarks/bench_detect.py --videos ../shared/data/videos/*.mp4 --repeats 2
    .venv/bin/python benchmarks/bench_detect.py --seek                            # cost of starting a reader mid-video
    .venv/bin/python benchmarks/bench_detect.py --junction --videos CLIP ...      # the junction check's tolerances
    .venv/bin/python benchmarks/bench_detect.py --gil                             # does process() hold the GIL?

--gil runs a pure-Python counting thread for 3 s beside an idle caller, then beside a caller detecting 60 frames:
if MediaPipe's process() held the GIL, the counter would nearly stop while the caller detects. Also the
detecting thread's own CPU seconds (the graph's work runs in MediaPipe's threads).

--junction measures what the junction check compares, on clips of any length: the sequential run's track against
a fresh follower started at every `--step`-th frame and run for the overlap, on the overlap's settled half: the
largest torso-centre distance (torso sizes) and size ratio per start, and whether the check would splice.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_capture import CLIP, looped_video  # noqa: E402
from common import gil_probe  # noqa: E402

CHILD = """
import json, resource, sys, time
from physmocap.detect.mediapipe_pose import detect_video
from physmocap.detect.two_graphs import two_part_plan
from physmocap.io.video import probe_video
path, graphs, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime
plan = two_part_plan(probe_video(path), graphs)
cpu0, wall0 = cpu(), time.perf_counter()
obs = detect_video(path, graphs=graphs)
wall, cpu_s = time.perf_counter() - wall0, cpu() - cpu0
obs.save(out)
print(json.dumps(dict(wall=wall, cpu=cpu_s, peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      frames=obs.num_frames, split=None if plan is None else plan.split)))
"""


def run_child(video: Path, graphs: int, out: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "src"))
    done = subprocess.run([sys.executable, "-c", CHILD, str(video), str(graphs), str(out)], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def landmark_differences(one: Path, two: Path, split: int | None) -> dict:
    """Per-frame largest keypoint distance (px) between the runs on frames valid in both, by region."""
    from physmocap.motion import Observations

    a, b = Observations.load(one), Observations.load(two)
    both = a.valid & b.valid
    distance = np.linalg.norm(a.keypoints_2d[..., :2] - b.keypoints_2d[..., :2], axis=-1).max(axis=1)
    distance[~both] = np.nan
    result = dict(frames=int(a.num_frames), validity_differs=int((a.valid != b.valid).sum()))
    if split is None:
        result["max_px"] = float(np.nanmax(distance, initial=0.0))
        return result
    before, after = distance[:split], distance[split:]
    differing = np.flatnonzero(np.nan_to_num(after) > 0)
    result.update(
        before_split_max_px=float(np.nanmax(before, initial=0.0)),
        junction_px=float(np.nan_to_num(distance[split])),
        after_split_max_px=float(np.nanmax(after, initial=0.0)),
        after_split_median_px=float(np.nanmedian(after)),
        after_split_frames_differing=int(len(differing)),
        after_split_frames_over_1px=int((np.nan_to_num(after) > 1.0).sum()),
        last_differing_frame_after_split=int(differing[-1]) if len(differing) else -1,
    )
    return result


def seek_cost(video: Path, start: int, repeats: int) -> dict:
    """Seconds to the first frame of a reader started at `start`: sought, against decoding from 0."""
    from physmocap.io import video as video_io

    times: dict[str, list[float]] = {"seek": [], "decode_from_0": []}
    for _ in range(repeats):
        for name in times:
            reader = video_io.iter_frames(video, start_frame=start)
            if name == "decode_from_0":
                reader._timeline = video_io._Timeline(reader.info, reader._slots, np.zeros(0, np.int64),
                                                      np.zeros(0, np.int64))  # as a stream without timestamps
            started = time.process_time()
            next(iter(reader))
            times[name].append(time.process_time() - started)
    return {name: float(np.median(values)) for name, values in times.items()}


def junction_measures(video: Path, step: int) -> list[dict]:
    """Per start frame: the largest centre distance and size ratio between the sequential track and a fresh
    follower over the compared frames, the frames compared, and the check's verdict."""
    from physmocap.detect import two_graphs
    from physmocap.detect.mediapipe_pose import Detections, PersonFollower, detect_video
    from physmocap.io.video import iter_frames, probe_video

    info = probe_video(video)
    sequential = detect_video(video, graphs=1)
    whole = Detections(0)
    for kp, wl, reason in zip(sequential.keypoints_2d, sequential.landmarks_3d, sequential.invalid_reason,
                              strict=True):
        whole.keypoints.append(kp)
        whole.world.append(wl)
        whole.reasons.append(str(reason))
    overlap = max(two_graphs.MIN_OVERLAP, round(two_graphs.OVERLAP_SECONDS * info.fps))
    rows = []
    for start in range(step, info.frame_count - overlap + 1, step):
        plan = two_graphs.Plan(info.frame_count, start + overlap, start, start + overlap - overlap // 2)
        follower = PersonFollower((info.width, info.height), info.fps)
        fresh = Detections(start)
        frames = iter(iter_frames(video, start_frame=start))
        try:
            fresh.detect(follower, frames, lambda index: None, stop_before=plan.split)
        finally:
            frames.close()
            follower.close()
        steps, ratios = [], []
        for frame in range(plan.compare_from, plan.split):
            if whole.reasons[frame] or fresh.reasons[frame - start]:
                continue
            centre_a, size_a = two_graphs.torso_centre_and_size(whole.keypoints.block[frame, :, :2])
            centre_b, size_b = two_graphs.torso_centre_and_size(fresh.keypoints.block[frame - start, :, :2])
            steps.append(float(np.linalg.norm(centre_b - centre_a)) / size_a)
            ratios.append(max(size_a, size_b) / min(size_a, size_b))
        rows.append(dict(start=start, compared=len(steps), max_step=max(steps, default=float("nan")),
                         max_ratio=max(ratios, default=float("nan")),
                         splice=not two_graphs.junction_mismatch(whole, fresh, plan)))
    return rows


def detection_gil_probe(video: Path) -> list[dict]:
    """Does MediaPipe hold the GIL? `common.gil_probe` with the caller detecting the video's first 60 frames."""
    from physmocap.detect.mediapipe_pose import PersonFollower
    from physmocap.io.video import iter_frames

    reader = iter_frames(video)
    frames = []
    for index, frame in reader:
        if index >= 60:
            break
        frames.append(frame)
    follower = PersonFollower((reader.info.width, reader.info.height), reader.info.fps)

    def detect() -> None:
        for index, frame in enumerate(frames):
            follower.detect(index, frame)

    try:
        return gil_probe(detect, "detects")
    finally:
        follower.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--videos", type=Path, nargs="*", default=None,
                        help="videos to detect (default: sports2d_demo looped to 60 s at 720p)")
    parser.add_argument("--repeats", type=int, default=2, help="pairs of runs (one graph, two graphs) per video")
    parser.add_argument("--seek", action="store_true", help="only the cost of starting a reader mid-video")
    parser.add_argument("--gil", action="store_true", help="only the GIL probe")
    parser.add_argument("--junction", action="store_true", help="only the junction check's measures")
    parser.add_argument("--step", type=int, default=10, help="--junction: frames between fresh starts")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "physmocap_bench_videos")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    videos = args.videos or [looped_video(CLIP, args.work / "loop_720p_60s.mp4", 60, 720)]
    print(f"load average before: {os.getloadavg()}", flush=True)
    if args.gil:
        for row in detection_gil_probe(videos[0]):
            print(json.dumps(row), flush=True)
        return 0
    if args.junction:
        for video in videos:
            for row in junction_measures(video, args.step):
                print(json.dumps(dict(video=video.name, **row)), flush=True)
        return 0
    if args.seek:
        for video in videos:
            from physmocap.io.video import probe_video

            start = probe_video(video).frame_count // 2
            print(json.dumps(dict(video=video.name, start=start, cpu_s=seek_cost(video, start, 3))), flush=True)
        return 0
    for video in videos:
        runs: dict[int, list[dict]] = {1: [], 2: []}
        for repeat in range(args.repeats):
            for graphs in (1, 2):
                out = args.work / f"{video.stem}_graphs{graphs}.npz"
                runs[graphs].append(run_child(video, graphs, out))
                print(json.dumps(dict(video=video.name, repeat=repeat, graphs=graphs, **runs[graphs][-1],
                                      load=os.getloadavg()[0])), flush=True)
        split = runs[2][-1]["split"]
        summary = {g: {k: float(np.median([r[k] for r in rs])) for k in ("wall", "cpu", "peak_mb")}
                   for g, rs in runs.items()}
        differences = landmark_differences(args.work / f"{video.stem}_graphs1.npz",
                                           args.work / f"{video.stem}_graphs2.npz", split)
        print(json.dumps(dict(video=video.name, split=split, median=summary, differences=differences)), flush=True)
    print(f"load average after: {os.getloadavg()}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
