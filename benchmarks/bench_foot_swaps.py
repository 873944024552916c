"""Left/right foot swaps found against the synthetic truth: the whole clip's decision (detect/foot_swaps.find_foot_swaps)
and the online fit's causal reading (CausalFootSwaps, through kinematics.online), per clip and seed.

The synthetic detector noise (contacts/noise.py, MEDIAPIPE_NOISE) swaps the two feet in episodes of about 0.4 s,
about one every four seconds, and records where (make_observations' truth "foot_swapped"). Per case: the frames
truly swapped (with a person), and for each reading the swapped frames it found and the ones it read swapped
wrongly. Validation clips are bench_physics_limits' (CMU subjects 2, 5, 7), test clips bench_synthetic's.

    .venv/bin/python benchmarks/bench_foot_swaps.py [--set validation|test] [--json OUT.json]

Writes benchmarks/results/foot_swaps_SET.json and .md (about a minute a set on 2 cores).
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
from bench_physics_limits import VALIDATION_CLIPS  # noqa: E402
from bench_synthetic import CLIPS as TEST_CLIPS, FPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, RESULTS, git_revision, machine_description  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.detect.foot_swaps import find_foot_swaps  # noqa: E402
from physmocap.io.atomic import write_text  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import make_observations, random_camera, resample  # noqa: E402

SEEDS = (0, 1)


def swap_case(name: str, seed: int) -> dict:
    """One clip seen by one random camera: the truly swapped frames and what each reading found."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), FPS), SECONDS)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, MEDIAPIPE_NOISE)
    true = truth["foot_swapped"] & obs.valid
    settings = Settings(online=True).replace("body", height=model_height(truth["landmarks_world"]))
    row = dict(clip=name.split("/")[-1], seed=seed, frames=int(obs.valid.sum()), swapped=int(true.sum()))
    for reading, found in (("offline", find_foot_swaps(obs)), ("online", fit_motion(obs, settings).foot_swaps)):
        row[f"{reading}_found"], row[f"{reading}_false"] = int((found & true).sum()), int((found & ~true).sum())
    return row


def markdown(report: dict) -> str:
    rows = report["rows"]
    out = [f"# Foot swaps against the synthetic truth ({report['set']} set)", "",
           f"Command: `{report['command']}`. Git {report['git']}; {report['machine']}.", "",
           "| clip | seed | frames | truly swapped | whole clip: found / false | online: found / false |",
           "|---|---|---|---|---|---|"]
    out += [f"| {r['clip']} | {r['seed']} | {r['frames']} | {r['swapped']} | {r['offline_found']} / "
            f"{r['offline_false']} | {r['online_found']} / {r['online_false']} |" for r in rows]
    total = {key: sum(r[key] for r in rows) for key in ("frames", "swapped", "offline_found", "offline_false",
                                                          "online_found", "online_false")}
    out.append(f"| all | | {total['frames']} | {total['swapped']} | {total['offline_found']} / "
               f"{total['offline_false']} | {total['online_found']} / {total['online_false']} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--set", choices=("validation", "test"), default="validation")
    parser.add_argument("--json", type=Path, default=None, help="default: benchmarks/results/foot_swaps_SET.json")
    args = parser.parse_args(argv)
    clips = VALIDATION_CLIPS if args.set == "validation" else TEST_CLIPS
    rows = []
    for name in clips:
        for seed in SEEDS:
            rows.append(swap_case(name, seed))
            print(json.dumps(rows[-1]), flush=True)
    report = dict(set=args.set, command=f".venv/bin/python benchmarks/bench_foot_swaps.py --set {args.set}",
                  git=git_revision(), machine=machine_description(), rows=rows)
    path = args.json or RESULTS / f"foot_swaps_{args.set}.json"
    write_text(path, json.dumps(report, indent=1) + "\n")
    write_text(path.with_suffix(".md"), markdown(report))
    print(markdown(report))
    return report


if __name__ == "__main__":
    main()
