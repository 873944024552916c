"""PhysCap physics: the paper's settings against ours, one change at a time, on the synthetic ground-truth set.

Where PhysCap leaves a value open or the paper's value hurt on detector-like input, physmocap departs from it
(src/physmocap/config.py, PhysicsSettings, says why for each). This benchmark measures each departure with the
evaluation suite's instrument: the kinematic input, the paper's settings, then the departures added one by one
in the order below, up to physmocap's defaults. Same cases as bench_synthetic.py (held-out CMU subjects, random
cameras, MediaPipe-like noise, true intrinsics and height), first seed, on the offline fit (refined by Rempe's
B.4 as the pipeline does before offline physics, PhysicsSettings.refine_offline) and the online fit; a row
with the input's joint positions smoothed by a zero-lag (non-causal) Gaussian shows how much of the jitter
(e_smooth) any temporal smoothing could remove, a bound for a causal tracker; plus
the same ladder on noise-free observations of the first clip, which separates what the tracker itself loses from what
detector noise costs.

    .venv/bin/python benchmarks/bench_physics_ablation.py [--quick] [--json OUT.json]

Writes benchmarks/results/physics_ablation.json and .md.
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
from scipy.ndimage import gaussian_filter1d

sys.path.insert(0, str(Path(__file__).parent))
from bench_synthetic import CLIPS, FPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, NOISE_FREE, RESULTS  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.config import PhysicsSettings, Settings  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.evaluation import score_against_truth, to_truth_world  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import NoiseModel, make_observations, random_camera, resample  # noqa: E402

DEFAULTS = PhysicsSettings()
DEPARTURES = (  # label, {field: the paper's value (or the nearest setting where the paper has none)}; in order
    ("+ gentle penetration recovery", {"penetration_recovery": 1e-3}),  # pushed out within one step
    ("+ slide speed", {"slide_speed": 0.05}),  # sigma: PhysCap's contact-labelling speed
    ("+ contact release", {"release_distance": None}),  # contacts are never released
    ("+ half feed-forward", {"acceleration_feedforward": 1.0}),  # eq. (4) as written
    ("+ smoothed kinematic velocity", {"velocity_smoothing": 0.0}),  # backward differences as they come
    ("+ stiffer, critically damped gains", {"kp_joint": 300.0, "kd_joint": 20.0,  # section 5.1
                                            "kp_root_rotation": 340.0, "kd_root_rotation": 30.0}),
    ("+ weight on the feet", {"residual_weight_vertical": DEFAULTS.residual_weight}),  # one root weight
    ("+ touch margin", {"touch_margin": 0.0}),  # a foot point collides only once under the floor
    ("+ floor clearance", {"floor_clearance": 0.0}),  # resting contacts land exactly on the floor
    ("+ targets lifted out of the floor", {"target_lift_time": None}),  # the kinematic target as it comes
    ("+ flat feet in the targets", {"flatten_feet": False}),  # a fitted foot keeps its tilt
    ("+ stationary flag checked by root speed", {"stationary_max_speed": None}),  # the network's flag alone
    ("+ share of the rotational velocity", {"rotation_velocity_share": 1.0}),  # eq. (4): all of qd_kin
    ("+ stiffer joints on B.4 input", {"kp_joint_refined": None, "kd_joint_refined": None}),  # the joints' (offline)
    ("+ online floor refinement", {"floor_refit_interval": None}),  # the warm-up's floor kept (online)
    ("+ held feet planted in the output (defaults)", {"plant_reach": None}),  # the simulated pose as it comes
)
PAPER = dataclasses.replace(DEFAULTS, **{f: v for _, fields in DEPARTURES for f, v in fields.items()})


def ladder() -> list[tuple[str, PhysicsSettings]]:
    """(label, settings): the paper's settings, then each departure added to the row above, ending at DEFAULTS."""
    rungs = [("paper settings", PAPER)]
    for label, fields in DEPARTURES:
        rungs.append((label, dataclasses.replace(rungs[-1][1], **{f: getattr(DEFAULTS, f) for f in fields})))
    return rungs


LADDER = ladder()
COLUMNS = (("mpjpe_root_mm", "root-rel. mm"), ("global_root_mm", "global root mm"), ("e_smooth_mm", "e_smooth mm"),
           ("mpe_mm", "MPE mm"), ("pnp_percent", "PNP %"), ("floating_percent", "float %"),
           ("penetration_percent", "penetr. %"), ("skate_percent", "skate %"), ("grf_mean_percent_bw", "GRF % BW"),
           ("grf_ballistic_percent_bw", "ballistic % BW"), ("residual_mean_percent_bw", "residual % BW"))
ZERO_LAG_SIGMA = 1.0  # frames: the sigma with the lowest e_smooth (first seed; online fit 1: 7.05, 2: 7.27, 3: 8.83 mm;
# B.4-refined fit 1: 4.8, 2: 6.0, 3: 7.8 mm)
SMOOTHED = f"input smoothed without lag (Gaussian, sigma {ZERO_LAG_SIGMA:g} frame; a bound)"


def case_rows(name: str, seed: int, online: bool, noise: NoiseModel) -> dict[str, dict]:
    """Scores of the kinematic input and of every rung of the ladder on one clip and camera."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), FPS), SECONDS)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, noise)
    settings = Settings(online=online).replace("body", height=model_height(truth["landmarks_world"]))
    motion = fit_motion(obs, settings)
    contacts, stationary, _ = predict_contacts(obs, "causal" if online else "centred")
    if not online and settings.physics.refine_offline:  # as the pipeline: offline physics tracks the B.4 motion
        refined = refine_kinematics(obs, motion, contacts, settings.fit, settings.trajopt)
        motion, contacts = refined.motion, refined.contacts

    def score(qpos, grf=None, residual=None):
        pose = kin.forward_kinematics(motion.body, qpos)
        points = to_truth_world(pose.points, motion.camera.R, motion.camera.t, truth)
        com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
        return score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass, grf, residual)

    rows = {"kinematic input": score(motion.qpos)}
    if noise is NOISE_FREE:
        return rows | physics_rows(motion, contacts, stationary, score, online)
    # What temporal smoothing alone could give: the input's points smoothed without lag (not causal, so a bound
    # for any causal tracker); only the pose and smoothness columns mean something for it.
    pose = kin.forward_kinematics(motion.body, motion.qpos)
    smoothed = gaussian_filter1d(pose.points, ZERO_LAG_SIGMA, axis=0, mode="nearest")
    points = to_truth_world(smoothed, motion.camera.R, motion.camera.t, truth)
    com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
    rows[SMOOTHED] = score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass)
    return rows | physics_rows(motion, contacts, stationary, score, online)


def physics_rows(motion, contacts, stationary, score, online: bool) -> dict[str, dict]:
    rows = {}
    for label, physics in LADDER:  # as the pipeline: the online floor is refined (unless the rung turns it off)
        out = run_physcap(motion.body, motion.qpos, FPS, contacts, stationary, physics, refine_floor=online,
                          valid=motion.valid, refined_input=not online and physics.refine_offline)
        rows[label] = score(out.qpos, out.grf, out.residual)
        rows[label]["fallback_frames"] = float((out.qp_failures > 0).sum())
    return rows


def mean_rows(cases: list[dict[str, dict]]) -> dict[str, dict]:
    return {label: {k: float(np.nanmean([c[label][k] for c in cases])) for k in cases[0][label]}
            for label in cases[0]}


def table(title: str, rows: dict[str, dict]) -> list[str]:
    lines = [f"**{title}**", "", "| settings | " + " | ".join(h for _, h in COLUMNS) + " |",
             "|---|" + "---|" * len(COLUMNS)]
    for label, row in rows.items():
        lines.append(f"| {label} | " + " | ".join("n/a" if row[k] != row[k] else f"{row[k]:.1f}"
                                                  for k, _ in COLUMNS) + " |")
    return lines + [""]


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="three clips")
    parser.add_argument("--json", default=str(RESULTS / "physics_ablation.json"))
    args = parser.parse_args(argv)
    clips = CLIPS[:3] if args.quick else CLIPS
    out = {"clips": list(clips), "seed": 0, "fps": FPS, "seconds": SECONDS,
           "ladder": {label: dataclasses.asdict(s) for label, s in LADDER}}
    for online in (False, True):
        fit = "online" if online else "offline"
        cases = []
        for name in clips:
            cases.append(case_rows(name, 0, online, MEDIAPIPE_NOISE))
            print(f"{fit} {name}: " + ", ".join(f"{k} {v['mpjpe_root_mm']:.1f}" for k, v in cases[-1].items()),
                  flush=True)
        out[f"{fit} fit"] = mean_rows(cases)
    out["noise-free, offline fit"] = case_rows(CLIPS[0], 0, False, NOISE_FREE)
    lines = ["## PhysCap: the paper's settings against ours", "",
             f"`.venv/bin/python benchmarks/bench_physics_ablation.py` — each row adds one departure from PhysCap's "
             f"settings (reasons in `config.py`, PhysicsSettings) to the row above; clips of the synthetic set "
             f"({len(clips)}, first seed, {SECONDS:.0f} s at {FPS:.0f} fps), metrics as in the synthetic table.", ""]
    for key in ("offline fit", "online fit", "noise-free, offline fit"):
        refined = " refined by B.4" if "offline" in key and DEFAULTS.refine_offline else ""
        lines += table(f"Input: {key}{refined}" + (f" ({CLIPS[0]})" if key.startswith("noise") else ""), out[key])
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    Path(args.json).with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return out


if __name__ == "__main__":
    main()
