"""Batch throughput: `physmocap batch` over the same short clips with 1 and 2 workers, through the process pool
and through a local Ray, whole commands alternated (pool-1, pool-2, ray-1, ray-2, then again) so that a change
in the machine's load hits every configuration alike; Ray's start-up and per-task overhead; a resumed batch that
must redo nothing; the per-frame stage costs behind a capacity estimate for 10,000 one-minute videos.

    .venv/bin/python benchmarks/bench_batch.py [--clips 10] [--frames 48] [--repeats 2]

The clips are --frames frames of the shared videos and the demo clip, taken in turn from a third of the way in
(later each time a source comes round again), written into a temporary folder. Writes benchmarks/results/batch.json and batch.md.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import REPO, RESULTS, VIDEOS, git_revision, machine_description  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.io.atomic import write_text  # noqa: E402
from physmocap.io.video import VideoWriter, iter_frames, probe_video  # noqa: E402

DEMO = REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"
CONFIGS = {"pool, 1 worker": ["--workers", "1"], "pool, 2 workers": ["--workers", "2"],
           "Ray local, 1 CPU": ["--ray", "--workers", "1"], "Ray local, 2 CPUs": ["--ray", "--workers", "2"]}


def make_clips(folder: Path, count: int, frames: int) -> list[Path]:
    """`count` clips of `frames` frames, cut from the shared videos and the demo in turn."""
    sources = sorted(VIDEOS.glob("*.mp4")) + [DEMO]
    clips = []
    for k in range(count):
        source = sources[k % len(sources)]
        info = probe_video(source)
        start = info.frame_count // 3 + (k // len(sources)) * frames  # a third in: the person is in view
        if start + frames > info.frame_count:
            start = max(0, info.frame_count - frames)
        clip = folder / f"clip{k:02d}_{source.stem}.mp4"
        with VideoWriter(clip, info.fps, info.width, info.height) as writer:
            for index, frame in iter_frames(source):
                if index >= start + frames:
                    break
                if index >= start:
                    writer.write(frame)
        clips.append(clip)
    return clips


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


# Process kinds of a batch's tree, by a fragment of their command line (first match wins).
PROCESS_KINDS = (("gcs_server", "Ray GCS"), ("raylet", "Ray raylet"), ("RuntimeEnvAgent", "Ray runtime-env agent"),
                 ("DashboardAgent", "Ray dashboard agent"), ("log_monitor.py", "Ray log monitor"),
                 ("autoscaler/_private/monitor.py", "Ray autoscaler monitor"), ("dashboard", "Ray dashboard"),
                 ("ray::", "worker"), ("default_worker.py", "worker"), ("multiprocessing", "worker"),
                 ("physmocap.cli", "driver"))
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def _process_tree(root: int) -> dict[int, tuple[str, float]]:
    """{pid: (command line, CPU seconds so far)} of `root` and every process below it, read from /proc."""
    children: dict[int, list[int]] = {}
    stats: dict[int, list[str]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        stats[int(entry.name)] = fields
        children.setdefault(int(fields[1]), []).append(int(entry.name))
    tree, todo = {}, [root]
    while todo:
        pid = todo.pop()
        if pid not in stats:
            continue
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        tree[pid] = (cmdline, (int(stats[pid][11]) + int(stats[pid][12])) / CLOCK_TICKS)  # utime + stime
        todo += children.get(pid, [])
    return tree


def process_kind(cmdline: str) -> str:
    return next((kind for fragment, kind in PROCESS_KINDS if fragment in cmdline), "other")


class TreeSampler:
    """CPU seconds of every process in a command's tree, by kind, sampled every `interval` s (the last sample of
    a process that exits is what it is credited with: up to `interval` of its CPU can be missed). CPU seconds
    are what the kernel accounts to each process, so much less affected by the machine's load than wall time."""

    def __init__(self, root: int, interval: float = 0.25):
        self.root, self.interval = root, interval
        self.latest: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            for pid, (cmdline, cpu) in _process_tree(self.root).items():
                if cmdline.strip():  # a process that exited between the reads keeps its last sample
                    self.latest[pid] = (cmdline, cpu)
            self._stop.wait(self.interval)

    def stop(self) -> dict[str, float]:
        """CPU seconds by process kind."""
        self._stop.set()
        self._thread.join()
        by_kind: dict[str, float] = {}
        for cmdline, cpu in self.latest.values():
            kind = process_kind(cmdline)
            by_kind[kind] = by_kind.get(kind, 0.0) + cpu
        return by_kind


def timed_batch(inputs: list[Path], out: Path, options: list[str]) -> dict:
    """One whole `physmocap batch` command: wall seconds, CPU seconds of its process tree by process kind (Ray's
    daemons and workers are in the tree too), its rows."""
    started = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "physmocap.cli", "batch", *map(str, inputs), "-o", str(out),
                             *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    sampler = TreeSampler(proc.pid)
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - started
    cpu_by_kind = sampler.stop()
    if proc.returncode != 0:
        raise RuntimeError(f"batch {options} failed:\n{stdout}\n{stderr}")
    with open(out / "batch.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    ready = re.search(r"Ray with \d+ CPUs ready after ([0-9.]+) s", stderr)
    return dict(wall_s=wall, cpu_s=sum(cpu_by_kind.values()), cpu_by_kind=cpu_by_kind,
                frames=sum(int(r["frames"]) for r in rows), videos=len(rows),
                ray_start_s=float(ready.group(1)) if ready else 0.0,
                peak_worker_mb=max(int(r["worker_peak_memory_mb"] or 0) for r in rows), rows=rows)


def ray_overhead(tasks: int = 40) -> dict:
    """A local Ray of 2 CPUs: init and shutdown seconds, the round trip of one no-op num_cpus=1 task (after the
    first, which starts a worker process), and the no-op tasks per second when all are submitted at once."""
    code = f"""
import json, time, logging
t0 = time.perf_counter()
import ray
ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING)
t1 = time.perf_counter()
@ray.remote(num_cpus=1)
def noop(x):
    return x
first = time.perf_counter(); ray.get(noop.remote(0)); first = time.perf_counter() - first
trips = []
for i in range({tasks}):
    t = time.perf_counter(); ray.get(noop.remote(i)); trips.append(time.perf_counter() - t)
t = time.perf_counter(); ray.get([noop.remote(i) for i in range({tasks})]); burst = time.perf_counter() - t
t2 = time.perf_counter(); ray.shutdown(); t3 = time.perf_counter()
trips.sort()
print(json.dumps(dict(import_and_init_s=t1 - t0, first_task_s=first, task_round_trip_ms=1000 * trips[len(trips) // 2],
                      tasks_per_second_burst={tasks} / burst, shutdown_s=t3 - t2)))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


RAY_STARTS = {
    "the batch's local Ray (RayEngine)": "from physmocap.batch.engines import RayEngine\nengine = RayEngine(None, 2)",
    "ray.init defaults, runtime_env with the thread settings (the batch until this change)":
        "from physmocap.batch.task import THREAD_ENV\nray.init(num_cpus=2, include_dashboard=False, "
        "log_to_driver=False, logging_level=logging.WARNING, runtime_env={'env_vars': THREAD_ENV})",
}


def ray_own_cpu(start: str, hold_s: float) -> dict:
    """CPU seconds of a local 2-CPU Ray's process tree, by process kind, from before `import ray` until two tasks
    that sleep `hold_s` s return: what Ray itself costs (the tasks do no work), start-up and idle running."""
    code = f"""
import json, logging, os, sys, time
sys.path.insert(0, {str(Path(__file__).parent)!r})
from bench_batch import _process_tree, process_kind
started = time.perf_counter()
import ray
{start}
@ray.remote(num_cpus=1)
def hold(seconds):
    time.sleep(seconds)
ray.get([hold.remote({hold_s}) for _ in range(2)])
by_kind = {{}}
for pid, (cmdline, cpu) in _process_tree(os.getpid()).items():
    kind = "driver" if pid == os.getpid() else process_kind(cmdline)
    by_kind[kind] = by_kind.get(kind, 0.0) + cpu
print(json.dumps(dict(wall_s=time.perf_counter() - started, cpu_by_kind=by_kind)))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def stage_costs(out: Path) -> dict[str, float]:
    """Seconds per frame of each stage over the runs of a batch folder (their summary.json)."""
    totals: dict[str, float] = {}
    frames = 0
    for summary_path in out.glob("*/summary.json"):
        summary = json.loads(summary_path.read_text())
        frames += summary["frames"]
        for stage, seconds in summary["stage_seconds"].items():
            totals[stage] = totals.get(stage, 0.0) + seconds
    return {stage: seconds / frames for stage, seconds in totals.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--clips", type=int, default=10)
    parser.add_argument("--frames", type=int, default=48, help="frames per clip")
    parser.add_argument("--repeats", type=int, default=2, help="rounds of the four configurations")
    parser.add_argument("--hold", type=float, default=20.0,
                        help="seconds the idle tasks of Ray's own CPU measurement run (then three times as long)")
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    args = parser.parse_args()

    load = [uptime()]
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp = Path(tmp)
        clips = make_clips(tmp / "clips", args.clips, args.frames)
        runs: dict[str, list[dict]] = {name: [] for name in args.configs}
        costs = {}
        for round_ in range(args.repeats):
            for name in args.configs:
                out = tmp / f"{name.replace(' ', '').replace(',', '_')}_{round_}"
                run = timed_batch(clips, out, CONFIGS[name])
                print(f"{name}, round {round_ + 1}: {run['frames']} frames in {run['wall_s']:.1f} s "
                      f"({run['frames'] / run['wall_s']:.2f} frames/s, cpu {run['cpu_s']:.1f} s); {uptime()}",
                      flush=True)
                runs[name].append(run)
                if name == "pool, 1 worker":
                    costs.setdefault("rounds", []).append(stage_costs(out))
            load.append(uptime())
        # Resume: the same command again over a finished batch must redo nothing.
        finished = tmp / f"{args.configs[0].replace(' ', '').replace(',', '_')}_0"
        resumed = timed_batch(clips, finished, CONFIGS[args.configs[0]])
        redone = sum(r["resumed"] != "1" for r in resumed["rows"])
        overhead = ray_overhead()
        own_cpu = {name: [ray_own_cpu(start, hold) for hold in (args.hold, 3 * args.hold)]
                   for name, start in RAY_STARTS.items()}
    load.append(uptime())

    frames = runs[args.configs[0]][0]["frames"]
    table = {}
    for name, rounds in runs.items():
        walls = [r["wall_s"] for r in rounds]
        wall = statistics.median(walls)
        after_start = statistics.median(r["wall_s"] - r["ray_start_s"] for r in rounds)
        table[name] = dict(wall_s=walls, median_wall_s=wall, frames_per_second=frames / wall,
                           videos_per_hour=3600 * args.clips / wall,
                           ray_start_s=[r["ray_start_s"] for r in rounds], frames_per_second_after_start=frames
                           / after_start, cores_used=statistics.median(r["cpu_s"] / r["wall_s"] for r in rounds),
                           cpu_seconds_per_frame=statistics.median(r["cpu_s"] / frames for r in rounds),
                           cores_by_kind={kind: statistics.median(r["cpu_by_kind"].get(kind, 0.0) / r["wall_s"]
                                                                  for r in rounds)
                                          for kind in sorted({k for r in rounds for k in r["cpu_by_kind"]})},
                           peak_worker_mb=max(r["peak_worker_mb"] for r in rounds))
    ratios = {}
    for a, b in (("Ray local, 1 CPU", "pool, 1 worker"), ("Ray local, 2 CPUs", "pool, 2 workers")):
        if a in runs and b in runs:  # Ray's start-up taken out: what it costs per task
            ratios[f"{a} / {b}, Ray's start-up taken out"] = statistics.median(
                rb["wall_s"] / (ra["wall_s"] - ra["ray_start_s"]) for ra, rb in zip(runs[a], runs[b], strict=True))
    for a, b in (("pool, 2 workers", "pool, 1 worker"), ("Ray local, 2 CPUs", "Ray local, 1 CPU"),
                 ("Ray local, 1 CPU", "pool, 1 worker"), ("Ray local, 2 CPUs", "pool, 2 workers")):
        if a in runs and b in runs:  # round by round: both ran side by side under the same load
            ratios[f"{a} / {b}"] = statistics.median(
                rb["wall_s"] / ra["wall_s"] for ra, rb in zip(runs[a], runs[b], strict=True))
    per_frame = {stage: statistics.median(c[stage] for c in costs.get("rounds", [])) for stage in
                 costs.get("rounds", [{}])[0]} if costs else {}
    one_worker = table.get("pool, 1 worker", {}).get("cpu_seconds_per_frame")
    estimate = None
    if one_worker:
        # CPU seconds of the whole command (start-up, every stage, every output) per frame: what a core must give
        # each frame, measured as the kernel accounts it, so less inflated by the load than wall time.
        seconds_per_frame = one_worker
        total_frames = 10_000 * 60 * 30  # one-minute videos at 30 frames per second
        core_hours = total_frames * seconds_per_frame / 3600
        estimate = dict(seconds_per_frame_one_worker=seconds_per_frame, total_frames=total_frames,
                        core_hours=core_hours, days_on_2_cores=core_hours / 2 / 24, hours_on_64_cores=core_hours / 64,
                        hours_on_256_cores=core_hours / 256)
    result = dict(machine=machine_description(), revision=git_revision(), clips=args.clips,
                  frames_per_clip=args.frames, frames=frames, repeats=args.repeats, load=load, table=table,
                  ratios=ratios, resume=dict(wall_s=resumed["wall_s"], redone=redone, inputs=len(resumed["rows"])),
                  ray_overhead=overhead, ray_own_cpu=own_cpu, stage_seconds_per_frame_one_worker=per_frame,
                  capacity=estimate,
                  command=" ".join(["benchmarks/bench_batch.py", *sys.argv[1:]]))
    RESULTS.mkdir(exist_ok=True)
    write_text(RESULTS / "batch.json", json.dumps(result, indent=1))
    write_text(RESULTS / "batch.md", markdown(result))
    print(markdown(result))


def markdown(r: dict) -> str:
    lines = [f"`.venv/bin/python {r['command']}` — {r['clips']} clips of {r['frames_per_clip']} frames "
             f"({r['frames']} frames), default capture settings (offline fit, physics: {Settings().physics.method}, overlay), "
             f"{r['repeats']} alternating rounds; {r['machine']}, revision {r['revision']}.",
             "", "Load while measuring (`uptime`, before, after each round, at the end):", ""]
    lines += [f"    {line}" for line in r["load"]]
    lines += ["", "| configuration | wall s (each round) | frames/s | videos/hour | Ray start s | frames/s after "
                  "start | cores used | CPU s/frame | peak worker MB |", "|---|---|---|---|---|---|---|---|---|"]
    for name, row in r["table"].items():
        ray = name.startswith("Ray")
        cores = f"{row['cores_used']:.2f}"
        cpu = f"{row['cpu_seconds_per_frame']:.3f}"
        start = ", ".join(f"{s:.1f}" for s in row["ray_start_s"]) if ray else "–"
        lines.append(f"| {name} | {', '.join(f'{w:.1f}' for w in row['wall_s'])} | {row['frames_per_second']:.2f} "
                     f"| {row['videos_per_hour']:.0f} | {start} | {row['frames_per_second_after_start']:.2f} | {cores} "
                     f"| {cpu} | {row['peak_worker_mb']} |")
    kinds = sorted({kind for row in r["table"].values() for kind in row["cores_by_kind"]})
    lines += ["", "Cores used by each kind of process in the command's tree (its CPU seconds over the command's wall "
                  "time, median over rounds; sampled from /proc every 0.25 s):", "",
              "| configuration | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 1) + "|"]
    for name, row in r["table"].items():
        lines.append(f"| {name} | " + " | ".join(f"{row['cores_by_kind'].get(kind, 0.0):.3f}" for kind in kinds)
                     + " |")
    lines += ["", "Throughput ratios, median over rounds of the runs side by side:", ""]
    lines += [f"- {name}: {value:.2f}" for name, value in r["ratios"].items()]
    o = r["ray_overhead"]
    lines += ["", f"Ray local (2 CPUs): import and start {o['import_and_init_s']:.1f} s, shut down "
                  f"{o['shutdown_s']:.1f} s; first no-op task {o['first_task_s']:.2f} s (starts a worker); then "
                  f"{o['task_round_trip_ms']:.1f} ms per task round trip, {o['tasks_per_second_burst']:.0f} no-op "
                  "tasks per second submitted together."]
    lines += ["", "Ray's own CPU (a local 2-CPU Ray running two tasks that sleep; CPU seconds of its process tree "
                  "from before `import ray` until the tasks return; idle: the extra CPU per second of the longer "
                  "hold, in cores):", "", "| start | wall s | CPU s | by process | idle cores |",
              "|---|---|---|---|---|"]
    for name, (short, long) in r["ray_own_cpu"].items():
        short_cpu, long_cpu = sum(short["cpu_by_kind"].values()), sum(long["cpu_by_kind"].values())
        idle = (long_cpu - short_cpu) / (long["wall_s"] - short["wall_s"])
        kinds = ", ".join(f"{kind} {cpu:.2f}" for kind, cpu in sorted(short["cpu_by_kind"].items(),
                                                                       key=lambda kv: -kv[1]))
        lines.append(f"| {name} | {short['wall_s']:.1f} | {short_cpu:.2f} | {kinds} | {idle:.3f} |")
    res = r["resume"]
    lines += ["", f"Resume: the same command over the finished batch redid {res['redone']} of {res['inputs']} runs "
                  f"and took {res['wall_s']:.1f} s."]
    if r["stage_seconds_per_frame_one_worker"]:
        lines += ["", "Stage costs per frame, one worker (summary.json): " + ", ".join(
            f"{k} {1000 * v:.1f} ms" for k, v in r["stage_seconds_per_frame_one_worker"].items()) + "."]
    c = r["capacity"]
    if c:
        lines += ["", f"Capacity: 10,000 one-minute videos at 30 fps = {c['total_frames'] / 1e6:.0f} M frames; at "
                      f"{1000 * c['seconds_per_frame_one_worker']:.0f} CPU ms per frame (the whole command with one "
                      f"worker, start-up included) that is {c['core_hours']:.0f} core-hours: {c['days_on_2_cores']:.1f} days "
                      f"on this 2-core machine, {c['hours_on_64_cores']:.1f} h on 64 cores, "
                      f"{c['hours_on_256_cores']:.1f} h on 256 (when each core gets a worker to itself)."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
