"""Where the default capture's error over its B.4 input sits on runs (issue 17's 3% target): the synthetic runs of
bench_synthetic (`--set runs`: held-out subject 9; `runs_validation`: subject 2 on two skeletons), seen by as many
cameras as asked, as bench_synthetic's "physcap on offline" row runs them (the B.4-refined kinematics and contacts,
`run_physcap(refined_input=True)`).

Per set:
- root-relative error (mm) of B.4 and of the default capture over all cases, and with `--trajopt` trajopt's and the
  share of its frames flagged (not converged);
- the legs' excess (knee, ankle, heel, toe; mm per joint and frame) by the phase of each foot in the truth's contact
  labels: in contact, the three frames before a touchdown, the three after a lift-off, the rest of the swing, and
  frames with no foot down;
- at each touchdown of the physics' own contacts, the misplacement of the point relative to the pelvis (the input's
  minus the unplanted output's, along the floor, mm) on the frame before and the first held frame, and how far the
  output's pelvis and point lead the input's along the track there;
- the truth's pelvis read over the labels' flights as the vertical force it needs (`contacts.flights.flight_support`,
  body weights: 0 a free fall, 1 held up);
- how far the truth's contact points stray from their contact's median spot over its labelled contact frames.

    .venv/bin/python benchmarks/bench_runs_breakdown.py [--set runs runs_validation validation test] [--seeds 0 1 ... 7]
        [--trajopt] [--noise free] [--physics NAME=VALUE ...]   # PhysicsSettings values tried in place of the defaults

`--set validation` scores bench_physics_limits's validation clips (walks, a jump, a dance, a bend and scoop) the same
way, for comparison, and `--set test` bench_synthetic's test set (held-out subjects 6 and 131). `--noise free` gives the pipeline the observations exactly as the camera sees the truth (no detector
error): what the physics costs over B.4 with a perfect detector, the method's own share of the excess.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_physics_limits import VALIDATION_CLIPS  # noqa: E402
from bench_synthetic import CLIP_SETS, FPS, SECONDS  # noqa: E402
from bench_trajopt import observe  # noqa: E402
from common import NOISE_FREE, RESULTS, settings_overrides  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.body.model import CONTACT_POINTS  # noqa: E402
from physmocap.contacts.flights import flight_support, runs  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.evaluation import EVAL_JOINTS, to_truth_world, true_contact_labels  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.metrics import GRAVITY, joint_errors  # noqa: E402
from physmocap.motion import valid_runs  # noqa: E402
from physmocap.trajopt.stage import run_trajopt  # noqa: E402

SETS = {"runs": CLIP_SETS["runs"], "runs_validation": CLIP_SETS["runs_validation"], "validation": VALIDATION_CLIPS,
        "test": CLIP_SETS["issue3"]}
NOISE = {"mediapipe": MEDIAPIPE_NOISE, "free": NOISE_FREE}
PHASES = ("contact", "before touchdown", "after lift-off", "swing", "no foot down")
EDGE_FRAMES = 3  # frames before a touchdown and after a lift-off counted as their own phase
LEG_JOINTS = ("knee", "ankle", "heel", "toe")


def root_relative(points: np.ndarray, names, truth: dict) -> np.ndarray:
    """(T, J) m: each EVAL_JOINTS joint's error after both hips' midpoints are subtracted, as
    evaluation.score_against_truth's root-relative error takes it (its mean over joints and frames)."""
    names, true_names = [str(n) for n in names], [str(n) for n in truth["joint_names"]]
    pred = points[:, [names.index(j) for j in EVAL_JOINTS]]
    true = truth["joints_world"][:, [true_names.index(j) for j in EVAL_JOINTS]]
    hips = [EVAL_JOINTS.index("left_hip"), EVAL_JOINTS.index("right_hip")]
    with_root = [np.concatenate([p[:, hips].mean(axis=1, keepdims=True), p], axis=1) for p in (pred, true)]
    return joint_errors(*with_root, align="root", joints=range(1, len(EVAL_JOINTS) + 1))


def foot_phases(labels: np.ndarray) -> dict[str, np.ndarray]:
    """(T,) phase names (PHASES) of each foot ("left", "right") from contact labels (T, 4) in CONTACT_POINTS order.
    The frames beside a contact take its edge's phase over swing and no foot down; a frame both before a touchdown
    and after a lift-off is before the touchdown."""
    flight = ~labels.any(axis=1)
    out = {}
    for side in ("left", "right"):
        down = labels[:, [i for i, n in enumerate(CONTACT_POINTS) if n.startswith(side)]].any(axis=1)
        phase = np.where(down, "contact", np.where(flight, "no foot down", "swing")).astype(object)
        for start, end in valid_runs(down):
            phase[max(start - EDGE_FRAMES, 0):start][~down[max(start - EDGE_FRAMES, 0):start]] = "before touchdown"
            after = slice(end, min(end + EDGE_FRAMES, len(down)))
            phase[after] = np.where(down[after] | (phase[after] == "before touchdown"), phase[after], "after lift-off")
        out[side] = phase
    return out


def touchdowns(body, qpos_input: np.ndarray, qpos_output: np.ndarray, held: np.ndarray) -> list[list[float]]:
    """Per touchdown of the held contacts (T, 4) from frame 2 on: the point's misplacement relative to the pelvis
    along the floor (|input minus output|, m) on the frame before and on the first held frame, and the output's lead
    over the input along the input pelvis' track there (pelvis, point; m)."""
    feet, pelvis = body.point_index(CONTACT_POINTS), body.point_index(("pelvis",))[0]
    out_points, in_points = (kin.forward_kinematics(body, q).points for q in (qpos_output, qpos_input))

    def relative(points: np.ndarray) -> np.ndarray:  # (T, 4, 2) m: the contact points from the pelvis
        return points[:, feet, :2] - points[:, pelvis, None, :2]

    misplaced = np.linalg.norm(relative(in_points) - relative(out_points), axis=-1)
    track = np.gradient(in_points[:, pelvis, :2], axis=0)
    track /= np.maximum(np.linalg.norm(track, axis=1, keepdims=True), 1e-9)
    rows = []
    for k in range(len(CONTACT_POINTS)):
        for start, _ in valid_runs(held[:, k]):
            if start >= 2:
                lead = out_points[start, :, :2] - in_points[start, :, :2]
                rows.append([misplaced[start - 1, k], misplaced[start, k], float(lead[pelvis] @ track[start]),
                             float(lead[feet[k]] @ track[start])])
    return rows


def truth_contact_spread(truth: dict, labels: np.ndarray) -> list[float]:
    """Per labelled contact frame of each point (labels (T, 4), the truth's), how far along the floor the truth's
    point lies from its contact's median spot (m): what any output that holds each contact on one spot must differ
    from the truth by."""
    names = [str(n) for n in truth["joint_names"]]
    points = truth["joints_world"][:, [names.index(n) for n in CONTACT_POINTS], :2]
    spread: list[float] = []
    for k in range(len(CONTACT_POINTS)):
        for start, end in valid_runs(labels[:, k]):
            path = points[start:end, k]
            spread += np.linalg.norm(path - np.median(path, axis=0), axis=1).tolist()
    return spread


def truth_flight_support(truth: dict, labels: np.ndarray) -> list[float]:
    """The truth's pelvis height read over each whole-body flight of the labels (T, 4) inside the clip (BW)."""
    names = [str(n) for n in truth["joint_names"]]
    joints = truth["joints_world"]
    height = 0.5 * (joints[:, names.index("left_hip"), 2] + joints[:, names.index("right_hip"), 2])
    times = np.arange(len(height)) / float(truth["fps"])
    starts, lengths = runs(~labels.any(axis=1))
    return [flight_support(height, times, int(s), int(s + n), GRAVITY) for s, n in zip(starts, lengths, strict=True)
            if not labels[s].any() and s > 0 and s + n < len(labels)]


def breakdown_case(name: str, seed: int, with_trajopt: bool, overrides: dict, noise: str = "mediapipe") -> dict:
    """One run seen by the camera of `seed` through the detector errors NOISE[noise]: the figures of the module's
    docstring, the physics with `overrides` (PhysicsSettings fields)."""
    obs, truth, settings = observe(name, seed, SECONDS, noise=NOISE[noise])
    fitted = fit_motion(obs, settings.replace(None, online=False))
    contacts, stationary = predict_contacts(obs, "centred")[:2]
    refined = refine_kinematics(obs, fitted, contacts, settings.fit, settings.trajopt)
    motion, body = refined.motion, refined.motion.body

    def physics(physics_settings):
        return run_physcap(body, motion.qpos, FPS, refined.contacts, stationary, physics_settings, valid=motion.valid,
                           refined_input=True, floor_trusted=motion.floor.trusted)

    def errors(qpos: np.ndarray) -> np.ndarray:
        points = to_truth_world(kin.forward_kinematics(body, qpos).points, motion.camera.R, motion.camera.t, truth)
        return root_relative(points, body.point_names, truth)

    chosen = dataclasses.replace(settings.physics, **overrides)
    default, unplanted = physics(chosen), physics(dataclasses.replace(chosen, plant_reach=0))
    b4, out = errors(motion.qpos), errors(default.qpos)
    labels = true_contact_labels(truth)
    phases = {phase: [0.0, 0.0, 0] for phase in PHASES}  # summed B.4 and default errors (m), joint-frames
    for side, phase_of in foot_phases(labels).items():
        legs = [EVAL_JOINTS.index(f"{side}_{j}") for j in LEG_JOINTS]
        for phase in PHASES:
            frames = phase_of == phase
            phases[phase][0] += float(b4[frames][:, legs].sum())
            phases[phase][1] += float(out[frames][:, legs].sum())
            phases[phase][2] += int(frames.sum()) * len(legs)
    row = dict(clip=name.split("/")[-1], seed=seed, b4_mm=1000 * float(b4.mean()), default_mm=1000 * float(out.mean()),
               phases=phases, touchdowns=touchdowns(body, motion.qpos, unplanted.qpos, unplanted.contacts),
               truth_flight_support=truth_flight_support(truth, refined.contacts),
               truth_contact_spread_mm=1000 * float(np.mean(truth_contact_spread(truth, labels) or [np.nan])))
    if with_trajopt:
        trajopt = run_trajopt(body, motion.qpos, FPS, refined.contacts, settings.trajopt)
        row.update(trajopt_mm=1000 * float(errors(trajopt.qpos).mean()),
                   trajopt_flagged_percent=100 * float(np.mean(trajopt.qp_failures > 0)))
    print(f"{row['clip']} seed {seed}: B.4 {row['b4_mm']:.2f}, default {row['default_mm']:.2f} mm", flush=True)
    return row


def summarise(rows: list[dict]) -> dict:
    """The set's means and pooled figures (module docstring), and the same per clip ("clips")."""
    clips = dict.fromkeys(r["clip"] for r in rows)
    out = _pooled(rows)
    out["clips"] = {clip: _pooled([r for r in rows if r["clip"] == clip]) for clip in clips} if len(clips) > 1 else {}
    return out


def _pooled(rows: list[dict]) -> dict:
    b4, default = np.mean([r["b4_mm"] for r in rows]), np.mean([r["default_mm"] for r in rows])
    phases = {p: [sum(r["phases"][p][i] for r in rows) for i in range(3)] for p in PHASES}
    touch = np.array([t for r in rows for t in r["touchdowns"]]).reshape(-1, 4)
    support = [s for r in rows for s in r["truth_flight_support"]]
    out = dict(cases=len(rows), b4_mm=b4, default_mm=default, default_over_b4_percent=100 * (default / b4 - 1),
               phases={p: dict(joint_frames=n, b4_mm=1000 * a / max(n, 1), default_mm=1000 * b / max(n, 1),
                               excess_share=(b - a) / max(sum(v[1] - v[0] for v in phases.values()), 1e-12))
                       for p, (a, b, n) in phases.items()},
               touchdowns=len(touch),
               touchdown_median_mm=(1000 * np.median(touch, axis=0)).tolist() if len(touch) else [],
               truth_flight_support_median=float(np.median(support)) if support else float("nan"),
               truth_contact_spread_mm=float(np.nanmean([r["truth_contact_spread_mm"] for r in rows])),
               truth_flight_support_range=[float(np.min(support)), float(np.max(support))] if support else [])
    if "trajopt_mm" in rows[0]:
        trajopt = np.mean([r["trajopt_mm"] for r in rows])
        out.update(trajopt_mm=trajopt, trajopt_over_b4_percent=100 * (trajopt / b4 - 1),
                   trajopt_flagged_percent=float(np.mean([r["trajopt_flagged_percent"] for r in rows])))
    return out


def summary_lines(name: str, s: dict) -> list[str]:
    """The set's summary as markdown lines."""
    lines: list[str] = []
    add = lines.append
    trajopt = (f", trajopt {s['trajopt_mm']:.2f} ({s['trajopt_over_b4_percent']:+.1f}%; "
               f"{s['trajopt_flagged_percent']:.0f}% of frames flagged)" if "trajopt_mm" in s else "")
    add(f"**{name}** ({s['cases']} cases): B.4 {s['b4_mm']:.2f} mm, default {s['default_mm']:.2f} "
        f"({s['default_over_b4_percent']:+.1f}%, {s['default_mm'] - s['b4_mm']:+.2f} mm){trajopt}")
    add("")
    add("| the foot's phase (truth's labels) | joint-frames | B.4 mm | default mm | share of the legs' excess |")
    add("|---|---|---|---|---|")
    for phase, v in s["phases"].items():
        add(f"| {phase} | {v['joint_frames']} | {v['b4_mm']:.1f} | {v['default_mm']:.1f} | {v['excess_share']:.2f} |")
    if s["touchdowns"]:
        before, onset, pelvis, point = s["touchdown_median_mm"]
        add("")
        add(f"{s['touchdowns']} touchdowns, medians: misplacement relative to the pelvis {before:.1f} mm the frame "
            f"before, {onset:.1f} mm on the first held frame; the output leads the input along the track there by "
            f"{pelvis:.1f} mm (pelvis) and {point:.1f} mm (the point).")
    add(f"The truth's contact points lie {s['truth_contact_spread_mm']:.1f} mm from their contact's median spot along "
        "the floor (mean over its labelled contact frames): about what an output that holds each contact on one spot "
        "differs from it by there.")
    low, high = s["truth_flight_support_range"] or [float("nan")] * 2
    add(f"The truth's pelvis over the labels' flights: median {s['truth_flight_support_median']:.2f} BW "
        f"({low:.2f} to {high:.2f}).")
    add("")
    if s["clips"]:
        add("| clip | B.4 mm | default mm | touchdown misplacement before / at, lead of pelvis / point, mm "
            "| the truth's pelvis in flight, BW |")
        add("|---|---|---|---|---|")
    for clip, c in s["clips"].items():
        touch = " / ".join(f"{v:.1f}" for v in c["touchdown_median_mm"])
        add(f"| {clip} | {c['b4_mm']:.2f} | {c['default_mm']:.2f} ({c['default_over_b4_percent']:+.1f}%, "
            f"{c['default_mm'] - c['b4_mm']:+.2f} mm) | {touch} | "
            f"{c['truth_flight_support_median']:.2f} |")
    return lines


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--set", nargs="+", choices=tuple(SETS), default=["runs_validation", "runs"])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(8)), help="the cameras (default 0-7)")
    parser.add_argument("--trajopt", action="store_true", help="score trajopt on the same input too")
    parser.add_argument("--physics", nargs="*", default=[], metavar="NAME=VALUE",
                        help="PhysicsSettings values in place of the defaults (e.g. plant_reach=0)")
    parser.add_argument("--noise", choices=tuple(NOISE), default="mediapipe",
                        help="the detector's errors: MediaPipe's as measured, or none (free)")
    parser.add_argument("--json", help="default: results/runs_breakdown.json, or runs_breakdown_noise_free.json")
    args = parser.parse_args(argv)
    args.json = args.json or str(RESULTS / ("runs_breakdown.json" if args.noise == "mediapipe"
                                            else "runs_breakdown_noise_free.json"))
    out, text = {}, [f"`.venv/bin/python benchmarks/bench_runs_breakdown.py {' '.join(argv or sys.argv[1:])}`", ""]
    overrides = settings_overrides(args.physics)
    for set_name in args.set:
        rows = [breakdown_case(name, seed, args.trajopt, overrides, args.noise) for name in SETS[set_name]
                for seed in args.seeds]
        out[set_name] = dict(summary=summarise(rows), rows=rows, seeds=args.seeds)
        text += [*summary_lines(set_name, out[set_name]["summary"]), ""]
    print("\n".join(text))
    Path(args.json).write_text(json.dumps(out, indent=1))
    Path(args.json).with_suffix(".md").write_text("\n".join(text))
    return out


if __name__ == "__main__":
    main()
