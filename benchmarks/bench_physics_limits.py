"""Physics on real footage (issue 17), on the synthetic ground-truth set: PhysCap at any frame rate, its diagnosis
of frames the contact model cannot explain, the online tracker's planted feet, and the offline methods side by
side (kinematic, B.4-refined kinematics, PhysCap on the refined kinematics, trajectory optimisation).

Cases as bench_synthetic.py: CMU clips of the contact networks' held-out subjects (6, 131), random cameras,
MediaPipe-like noise, the true intrinsics and height, 8 s at 30 fps, seeds 0 and 1. Parts:

  framerate  131_01 and 006_01 at 60 fps (offline fit refined by B.4), that kinematic motion resampled to 10, 24,
             30 and 120 fps (the same motion), PhysCap at each rate: finite values, largest force, and the physics
             joints of each rate against the 60 fps run at common times (--set validation: every validation clip,
             walks, jump, dance and bend).
  diagnosis  the walking clips with a box: from 3.0 to 5.5 s the whole motion is raised 0.3 m (0.5 s ramps),
             the floor staying at z = 0 (a raised floor, or hands carrying the body). Truly unexplainable frames:
             lifted by 0.1 m or more (the feet above the contact height while bearing weight), and frames whose
             true body rests off its feet (131_01's slide on a knee). Reports the share of them flagged
             (PhysicsMotion.unexplained), and the frames flagged elsewhere.
  diagnosis_10fps  the same at 10 fps (issue 17's parkour videos declared 10 fps).
  seated     the same on CMU clips seated on stools (SEATED_CLIPS), split into seated frames (the true pelvis
             under SEATED of its standing height above the soles) and the others, with the mean contact force;
             the online fit and PhysCap on it (estimated floor) too.
  levels     real motion on other levels (CMU stairs, ladders, a playground: LEVEL_CLIPS, subject 13 with --set
             validation, 14 and 1 otherwise), the ground put at z = 0 (the lowest level the feet stand on), seed 0:
             each method's error against the truth, beside the plain kinematic fit's, on the frames whose true
             lowest sole is at least 0.1 m above the ground (another level) and on the others; the share of the
             raised frames flagged and of the others; the largest force.
  online     PhysCap on the online fit: slide of the contact points in use, per frame (median and 95th
             percentile, cm), and jitter (mean joint acceleration, m/s^2) against its kinematic input.
  online_framerate  the online path at 10, 24, 30, 60 and 120 fps: each clip observed at each rate (seed 0, its
             own noise per frame, as a camera at that rate gives), the online fit and PhysCap on it (estimated
             floor): error against the truth, jitter, skate and contact slide, kinematic and physics, per rate.
  methods    kinematic offline, B.4-refined, PhysCap on refined, trajopt: the synthetic table's metrics, the
             frames flagged and the physics stage's time.
  speed      frames per CPU second of the physics stage at 25, 30 and 60 fps, this tree against another
             (--against SRC, default ../main/src), in alternating child processes.
  speed_alternating  the same with the other tree's dynamics package loaded beside this one in one process,
             alternated run by run (steadier on a busy machine; only the dynamics package may differ).
  identical  every array of run_physcap from this tree and from the --against tree's dynamics package (as
             speed_alternating loads it) on eight runs: 131_01's 60 fps B.4 motion resampled to 10, 25, 30 and 60 fps,
             006_01's online fit (refined floor; calibrated floor; three legacy steps without foot lock) and
             131_01 with a box: which arrays differ and by how much (a speed change must leave them equal).
  profile    where the physics stage's CPU time goes: 131_01's 60 fps B.4 motion resampled to 30 fps, each method
             of the tracker, the stage and the QP workspace timed by a wrapper (time.process_time around each call;
             the wrappers add their own cost to the small calls: shares, not absolute figures).
  stability  the validation walks' 60 fps B.4 motion resampled, PhysCap with a forced number of equal steps per
             frame around the PD's stability limit (physcap.stability_limit): what limits the step.
  planting_long  the offline planting of the held feet (planting.plant_held_feet) on ten minutes: 131_01's
             B.4 motion and PhysCap's contacts at 30 fps looped to 18,000 frames; peak memory of its allocations
             (tracemalloc) and CPU seconds.

    .venv/bin/python benchmarks/bench_physics_limits.py [--parts framerate diagnosis diagnosis_10fps online methods] [--quick]
        [--set validation] [--methods ROW ...] [--physics NAME=VALUE ...]

--set validation runs parts methods, framerate and online on the validation clips (CMU training subjects 2, 5, 7),
where settings are chosen; --physics tries PhysicsSettings values in every part (e.g. contact_settle_time=0.1).

Writes benchmarks/results/physics_limits.json and .md. Fits are cached under the system's temporary folder
(physmocap_bench_physics_limits/DIGEST, a digest of the sources and data outside dynamics/) so that parts can be rerun
alone, and are built again when the fits or contact weights change.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import hashlib
import json
import os
import pickle
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_physics_videos import LIMB_LANDMARKS, aligned_error_mm, aligned_to_mm  # noqa: E402
from bench_synthetic import CLIPS, FPS, SECONDS, WALKING, first_seconds, model_height  # noqa: E402
from bench_trajopt import implied_vertical_force, observe  # noqa: E402
from common import MOCAP, RESULTS, settings_overrides, truth_scores  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.body.model import CONTACT_POINTS  # noqa: E402
from physmocap.body.support import resting_off_feet, resting_points  # noqa: E402
from physmocap.config import PhysicsSettings, Settings  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.physcap import stability_limit  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.evaluation import score_against_truth, to_truth_world, true_contact_labels  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.landmarks import LANDMARK_INDEX  # noqa: E402
from physmocap.mocap.bvh_reader import JOINT_NAMES, load_mocap  # noqa: E402
from physmocap.mocap.synthetic import NoiseModel, make_observations, random_camera, resample  # noqa: E402
from physmocap.trajopt import run_trajopt  # noqa: E402


def inputs_fingerprint() -> str:
    """A digest of what a case's fits and contacts come from: physmocap's sources and data outside dynamics/ (the
    code under test, which --against may swap). A change there (new contact weights, a new fit) builds cases again."""
    digest = hashlib.sha256()
    root = Path(physmocap.__file__).parent
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root)
        if path.is_file() and "dynamics" not in relative.parts and path.suffix in (".py", ".npz", ".json"):
            digest.update(str(relative).encode() + path.read_bytes())
    return digest.hexdigest()[:12]


CACHE = Path(tempfile.gettempdir()) / "physmocap_bench_physics_limits" / inputs_fingerprint()
GRAVITY = 9.81
BOX = dict(start=3.0, end=5.5, ramp=0.5, height=0.3)  # s, s, s, m
RATES = (10.0, 24.0, 30.0, 60.0, 120.0)
PHYSICS = PhysicsSettings()  # every case's physics settings: the defaults with main's --physics overrides
SOURCE_FPS = 120.0  # the motion capture's force read at this rate (source_vertical_force)  # issue 17 asks for 8 to 120 fps; 60 is the reference
# Validation clips (CMU training subjects 2, 5 and 7; the test set holds 6 and 131), on which settings are chosen:
# walks on both skeletons, jump and balance, dance steps, bend and scoop.
VALIDATION_CLIPS = ("cmu_raw_cgspeed/02_01.bvh", "cmu_iclone_cc3_retarget/007_01.bvh",
                    "cmu_iclone_cc3_retarget/002_04.bvh", "cmu_iclone_cc3_retarget/005_11.bvh",
                    "cmu_iclone_cc3_retarget/002_06.bvh")
VALIDATION_WALKING = ("02_01.bvh", "007_01.bvh")
# Real motion on other levels (clip, seconds from its start): stairs of three steps, ladders, a playground's climb and
# seat; left out of the contact networks' data (docs/decisions/contact-training-data.md). Subject 13 for validation.
LEVEL_CLIPS = {"validation": (("cmu_daz_cgspeed/13_35.bvh", 10.0), ("cmu_daz_cgspeed/13_33.bvh", 12.0)),
               "test": (("cmu_daz_cgspeed/14_21.bvh", 10.0), ("cmu_daz_cgspeed/14_33.bvh", 11.5),
                        ("cmu_daz_cgspeed/01_08.bvh", 12.0))}
RAISED = 0.1  # m: a true lowest sole this far above the ground stands on another level (or hangs)
# Seated on stools (the seat carries the weight the feet do not; subject 13 for validation)
SEATED_CLIPS = {"validation": (("cmu_daz_cgspeed/13_01.bvh", 12.0),),
                "test": (("cmu_daz_cgspeed/14_27.bvh", 12.0), ("cmu_daz_cgspeed/14_30.bvh", 12.0))}
SEATED = 0.85  # share of the standing pelvis height over the soles under which a frame is seated


def box_lift(times: np.ndarray) -> np.ndarray:
    """(T,) m: the box's lift of the whole motion at each time (smooth ramps up and down)."""
    up = np.clip((times - BOX["start"]) / BOX["ramp"], 0.0, 1.0)
    down = np.clip((BOX["end"] - times) / BOX["ramp"], 0.0, 1.0)
    ramp = np.minimum(up, down)
    return BOX["height"] * (3 * ramp ** 2 - 2 * ramp ** 3)


def build_case(name: str, seed: int, fps: float = FPS, noise: NoiseModel = MEDIAPIPE_NOISE, box: bool = False,
               online: bool = True, seconds: float = SECONDS, ground: bool = False) -> dict:
    """Observations, truth, the kinematic fits and the contacts of one clip's first `seconds`; cached on disk.
    ground: z = 0 put at the lowest level the feet stand on (the 2nd percentile of the lowest sole point), for clips
    on several levels, whose own floor (mocap.bvh_reader) may be any of them."""
    key = (f"{name.split('/')[0]}_{name.split('/')[-1][:-4]}_{seed}_{fps:g}{'_box' if box else ''}"
           f"{f'_{seconds:g}s_ground' if ground else ''}")
    path = CACHE / f"{key}.pkl"
    if path.exists():
        try:
            case = pickle.loads(path.read_bytes())
        except (ModuleNotFoundError, AttributeError):  # pickled by an older layout of physmocap: build it again
            path.unlink()
            return build_case(name, seed, fps, noise, box, online, seconds, ground)
        # the physics settings of the code under test (and --physics), not the defaults pickled with the case's fits
        case["settings"] = dataclasses.replace(case["settings"], physics=PHYSICS)
        if not online or "online" in case:
            return case
        return add_online_fits(case, path)
    clip = first_seconds(resample(load_mocap(MOCAP / name), fps), seconds)
    lift = box_lift(np.arange(clip.num_frames) / fps) if box else np.zeros(clip.num_frames)
    positions = clip.positions.copy()
    positions[:, :, 2] += lift[:, None]
    if ground:
        positions[:, :, 2] -= np.percentile(true_soles(positions).min(axis=1), 2)
    clip = dataclasses.replace(clip, positions=positions)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, noise)
    settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
    case = dict(name=key, obs=obs, truth=truth, lift=lift, settings=settings.replace(None, physics=PHYSICS))
    offline = fit_motion(obs, settings)
    contacts, stationary, _ = predict_contacts(obs, "centred")
    refined = refine_kinematics(obs, offline, contacts, settings.fit, settings.trajopt)
    case.update(offline=offline, contacts=contacts, stationary=stationary, refined=refined)
    CACHE.mkdir(parents=True, exist_ok=True)
    if online:
        return add_online_fits(case, path)
    path.write_bytes(pickle.dumps(case))
    return case


def add_online_fits(case: dict, path: Path) -> dict:
    """The case with the online fits (estimated and calibrated floor) and causal contacts; cached on disk."""
    obs, settings = case["obs"], case["settings"]
    calibrated = settings.replace("camera", floor=tuple(float(v) for v in case["truth"]["floor"]))
    causal, causal_stationary, _ = predict_contacts(obs, "causal")
    case.update(online=fit_motion(obs, settings.replace(None, online=True)),
                online_calibrated=fit_motion(obs, calibrated.replace(None, online=True)),
                causal=causal, causal_stationary=causal_stationary)
    path.write_bytes(pickle.dumps(case))
    return case


def physcap_offline(case: dict):
    """PhysCap on the B.4-refined kinematics, as offline capture runs it."""
    refined = case["refined"]
    return refined.motion, run_physcap(refined.motion.body, refined.motion.qpos, case["obs"].fps, refined.contacts,
                                       case["stationary"], case["settings"].physics, refined_input=True)


def physcap_online(case: dict, calibrated: bool = False):
    motion = case["online_calibrated" if calibrated else "online"]
    return motion, run_physcap(motion.body, motion.qpos, case["obs"].fps, case["causal"], case["causal_stationary"],
                               case["settings"].physics, refine_floor=not calibrated)


def points_in_truth(motion, qpos: np.ndarray, truth: dict) -> np.ndarray:
    return to_truth_world(kin.forward_kinematics(motion.body, qpos).points, motion.camera.R, motion.camera.t, truth)


def largest_force_bw(physics, mass: float) -> float:
    return float(contact_force_bw(physics, mass).max())


def contact_force_bw(physics, mass: float) -> np.ndarray:
    """(T,) body weights: the size of the frame's summed contact force."""
    return np.linalg.norm(physics.grf.sum(axis=1), axis=-1) / (mass * GRAVITY)


# ---- parts ----------------------------------------------------------------------------------------------------
def resample_motion(body, qpos: np.ndarray, fps: float, new_fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The motion (T, nq) at another frame rate, interpolated on the manifold between the nearest frames; returns
    it and, for each new frame, the index of the source frame at or before it."""
    model = body.mujoco_model()
    times = np.arange(int(np.floor((len(qpos) - 1) / fps * new_fps + 1e-9)) + 1) / new_fps
    position = times * fps
    lower = np.minimum(np.floor(position + 1e-9).astype(int), len(qpos) - 2)
    out = np.empty((len(times), qpos.shape[1]))
    step = np.zeros(model.nv)
    for k, (i, w) in enumerate(zip(lower, position - lower, strict=True)):
        mujoco.mj_differentiatePos(model, step, 1.0, qpos[i], qpos[i + 1])
        out[k] = qpos[i]
        mujoco.mj_integratePos(model, out[k], step, float(w))
    return out, lower


def against_reference(run: dict, reference: dict) -> tuple[list[int], list[int], np.ndarray, np.ndarray]:
    """A rate's run against the 60 fps one (each with "times" (T,) s and joint "points" (T, J, 3) m), at the
    times both hold from 0.5 s on: the run's frames there, the reference's matching frames, and per common time
    the mean joint distance (m) and the same for the posture alone (joints relative to the root)."""
    index = [i for i, time in enumerate(run["times"]) if time >= 0.5
             and np.isclose(reference["times"], time, atol=1e-6).any()]
    match = [int(np.argmin(np.abs(reference["times"] - run["times"][i]))) for i in index]
    a, b = run["points"][index], reference["points"][match]
    return (index, match, np.linalg.norm(a - b, axis=-1).mean(axis=1),
            np.linalg.norm((a - a[:, :1]) - (b - b[:, :1]), axis=-1).mean(axis=1))


def part_framerate(clips) -> dict:
    """The 60 fps offline case's B.4-refined kinematic motion resampled to each rate (the same motion), PhysCap at
    each rate as offline capture runs it (refined_input); joints against the 60 fps run at common times."""
    rows = []
    for name in clips:
        case = build_case(name, 0, 60.0, online=False)
        motion, refined = case["refined"].motion, case["refined"]
        body = motion.body
        runs = {}
        for fps in RATES:
            qpos, source = resample_motion(body, motion.qpos, 60.0, fps)
            physics = run_physcap(body, qpos, fps, refined.contacts[source], case["stationary"][source],
                                  case["settings"].physics, refined_input=True)
            points = kin.forward_kinematics(body, physics.qpos).points
            to_input = np.linalg.norm(points - kin.forward_kinematics(body, qpos).points, axis=-1).mean(axis=1)
            explained = ~physics.unexplained if physics.unexplained is not None else np.ones(len(qpos), bool)
            runs[fps] = dict(times=np.arange(len(qpos)) / fps, physics=physics, points=points,
                             to_input=to_input[np.arange(len(qpos)) / fps >= 0.5],
                             jitter=metrics.explained_acceleration(points, fps, explained),
                             input_jitter=metrics.explained_acceleration(kin.forward_kinematics(body, qpos).points,
                                                                         fps, explained))
        reference = runs[60.0]
        for fps in RATES:
            run, physics = runs[fps], runs[fps]["physics"]
            index, match, distance, relative = against_reference(run, reference)
            root_horizontal = np.linalg.norm(physics.qpos[index, :2] - reference["physics"].qpos[match, :2], axis=-1)
            flagged = getattr(physics, "unexplained", None)
            rows.append(dict(clip=name.split("/")[-1], fps=fps,
                             finite=bool(np.isfinite(physics.qpos).all() and np.isfinite(physics.grf).all()),
                             largest_force_bw=largest_force_bw(physics, body.mass),
                             flagged_percent=float("nan") if flagged is None else 100 * float(flagged.mean()),
                             physics_vs_60_mm=1000 * float(distance.mean()),
                             physics_vs_60_p95_mm=1000 * float(np.percentile(distance, 95)),
                             physics_vs_60_max_mm=1000 * float(distance.max()),
                             root_relative_vs_60_mm=1000 * float(relative.mean()),
                             root_relative_vs_60_p95_mm=1000 * float(np.percentile(relative, 95)),
                             root_horizontal_vs_60_mm=1000 * float(root_horizontal.mean()),
                             physics_vs_own_input_mm=1000 * float(run["to_input"].mean()),
                             jitter=run["jitter"], input_jitter=run["input_jitter"],
                             common_times=len(index), ms_per_frame=1000 * physics.seconds / len(physics.qpos)))
            print("framerate", rows[-1], flush=True)
    return dict(rows=rows)


def true_soles(positions: np.ndarray) -> np.ndarray:
    """(T, 4) m: the heights of a clip's sole points (CONTACT_POINTS) in its joint positions (T, J, 3), J as
    mocap.JOINT_NAMES."""
    return positions[:, [JOINT_NAMES.index(n) for n in CONTACT_POINTS], 2]


def raised_frames(truth: dict) -> np.ndarray:
    """(T,) bool: frames whose true lowest sole is RAISED or more above the ground (another level, or hanging)."""
    return true_soles(truth["joints_world"]).min(axis=1) >= RAISED


def seated_frames(truth: dict) -> np.ndarray:
    """(T,) bool: frames whose true pelvis is less than SEATED of its standing height (the clip's 90th percentile)
    above the lowest sole: sitting or squatting, the weight on a seat or over bent legs."""
    joints = truth["joints_world"]
    above = joints[:, JOINT_NAMES.index("pelvis"), 2] - true_soles(joints).min(axis=1)
    return above < SEATED * np.percentile(above, 90)


def part_levels(clips, seed: int = 0, held=raised_frames, groups=("raised", "ground"), online: bool = False) -> dict:
    """Each method on real motion (clips: (name, seconds) pairs) against the truth, on the frames `held` (truth ->
    (T,) bool) picks and on the others (their keys' prefixes: `groups`); online: the online fit and PhysCap on it
    (estimated floor) too."""
    rows = []
    for name, seconds in clips:
        case = build_case(name, seed, online=online, seconds=seconds, ground=True)
        truth = case["truth"]
        picked = held(truth)
        runs = {"kinematic offline": (case["offline"], case["offline"].qpos, None),
                "kinematic refined (B.4)": (case["refined"].motion, case["refined"].motion.qpos, None)}
        motion, physics = physcap_offline(case)
        runs["physcap on refined"] = (motion, physics.qpos, physics)
        result = run_trajopt(motion.body, motion.qpos, FPS, case["refined"].contacts, case["settings"].trajopt)
        runs["trajopt"] = (motion, result.qpos, result)
        if online:
            runs["kinematic online"] = (case["online"], case["online"].qpos, None)
            online_motion, online_physics = physcap_online(case)
            runs["physcap on online"] = (online_motion, online_physics.qpos, online_physics)
        for method, (motion, qpos, solved) in runs.items():
            points = points_in_truth(motion, qpos, truth)[:, [motion.body.point_names.index(j) for j in JOINT_NAMES]]
            row = dict(clip=name.split("/")[-1], method=method, frames=len(qpos))
            row[f"{groups[0]}_frames"] = int(picked.sum())
            for part, frames in zip(groups, (picked, ~picked), strict=True):
                pred, true = points[frames], truth["joints_world"][frames]
                row[f"{part}_root_relative_mm"] = 1000 * metrics.mpjpe(pred, true, align="root")
                row[f"{part}_procrustes_mm"] = 1000 * metrics.mpjpe(pred, true, align="procrustes")
                row[f"{part}_global_root_mm"] = 1000 * float(np.linalg.norm(pred[:, 0] - true[:, 0], axis=-1).mean())
            if solved is not None:
                flagged = np.asarray(solved.unexplained if method.startswith("physcap") else solved.qp_failures > 0,
                                     bool)
                force = contact_force_bw(solved, motion.body.mass)
                row[f"{groups[0]}_flagged_percent"] = 100 * float(flagged[picked].mean())
                row[f"{groups[1]}_flagged_percent"] = 100 * float(flagged[~picked].mean())
                row.update(largest_force_bw=float(force.max()),
                           largest_unflagged_force_bw=float(force[~flagged].max()) if (~flagged).any() else 0.0,
                           mean_force_bw={part: float(force[frames & ~flagged].mean()) if (frames & ~flagged).any()
                                          else None for part, frames in zip(groups, (picked, ~picked), strict=True)},
                           finite=bool(np.isfinite(qpos).all() and np.isfinite(solved.grf).all()))
            rows.append(row)
            print("levels", {k: round(v, 1) if isinstance(v, float) else v for k, v in row.items()}, flush=True)
    return dict(rows=rows, raised_m=RAISED, seated_share=SEATED, groups=list(groups))


def true_resting_off_feet(truth: dict) -> np.ndarray:
    """(T,) bool: frames in which the true body rests on the floor off its feet (body.support: a knee, an elbow)."""
    names = [str(n) for n in truth["joint_names"]]
    return resting_off_feet(np.asarray(truth["joints_world"])[:, resting_points(names), 2])


def part_diagnosis(clips, seeds, fps: float = FPS) -> dict:
    rows = []
    for name in clips:
        for seed in seeds:
            for box in (True, False):
                case = build_case(name, seed, fps, box=box)
                truly = (case["lift"] >= 0.1) | true_resting_off_feet(case["truth"])
                for method, (motion, physics) in (("physcap on offline", physcap_offline(case)),
                                                  ("physcap on online", physcap_online(case)),
                                                  ("physcap on online, calibrated floor",
                                                   physcap_online(case, calibrated=True))):
                    flagged = physics.unexplained
                    truth = case["truth"]
                    final = points_in_truth(motion, physics.qpos, truth)
                    true_points = truth["joints_world"]
                    names = [str(n) for n in truth["joint_names"]]
                    pelvis = names.index("pelvis")
                    root_error = np.linalg.norm(final[:, motion.body.point_names.index("pelvis")]
                                                - true_points[:, pelvis], axis=-1)
                    rows.append(dict(clip=name.split("/")[-1], seed=seed, box=box, method=method,
                                     frames=len(flagged), truly_unexplained=int(truly.sum()),
                                     flagged=int(flagged.sum()),
                                     recall_percent=100 * float(flagged[truly].mean()) if truly.any() else None,
                                     false_flag_percent=100 * float(flagged[~truly].mean()),
                                     largest_force_bw=largest_force_bw(physics, motion.body.mass),
                                     root_error_in_box_mm=(1000 * float(root_error[truly].mean()) if truly.any()
                                                           else None),
                                     finite=bool(np.isfinite(physics.qpos).all())))
                    print("diagnosis", rows[-1], flush=True)
    return dict(rows=rows, box=BOX, fps=fps)


def held_slides_cm(points: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """cm: the horizontal displacement of every sole point (T, 4, 3) (z up) from frame t-1 to t where it is in
    contact (T, 4) in both."""
    step = 100 * np.linalg.norm(np.diff(points[:, :, :2], axis=0), axis=-1)
    return step[contacts[1:] & contacts[:-1]]


def contact_slide_cm(body, qpos: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """cm: `held_slides_cm` of the motion qpos (T, nq)."""
    return held_slides_cm(kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)], contacts)


def part_online(clips, seeds) -> dict:
    rows = []
    for name in clips:
        for seed in seeds:
            case = build_case(name, seed)
            truth = case["truth"]
            feet_down = true_contact_labels(truth).any(axis=1) & case["obs"].valid & ~true_resting_off_feet(truth)
            for calibrated in (False, True):
                motion, physics = physcap_online(case, calibrated)
                forces = vertical_force_errors(motion.body, None, physics.grf, case["obs"].fps,
                                               true_vertical_force(motion.body, truth), feet_down)
                body, fps = motion.body, case["obs"].fps
                slide = contact_slide_cm(body, physics.qpos, physics.contacts)
                kinematic_slide = contact_slide_cm(body, motion.qpos, physics.contacts)
                joints = kin.forward_kinematics(body, physics.qpos).points
                joints_kin = kin.forward_kinematics(body, motion.qpos).points
                scores, kinematic_scores = (truth_scores(motion, qpos, case["truth"]) for qpos in (physics.qpos, motion.qpos))
                force = contact_force_bw(physics, motion.body.mass)
                rows.append(dict(largest_force_bw=float(force.max()),
                                 over_2bw_percent=100 * float((force > 2.0).mean()),clip=name.split("/")[-1], seed=seed, calibrated=calibrated, slides=slide.tolist(),
                                 kinematic_slides=kinematic_slide.tolist(),
                                 jitter=metrics.mean_acceleration(joints, fps),
                                 kinematic_jitter=metrics.mean_acceleration(joints_kin, fps),
                                 flagged_percent=100 * float(physics.unexplained.mean()),
                                 root_relative_mm=scores["mpjpe_root_mm"], skate_percent=scores["skate_percent"],
                                 floating_percent=scores["floating_percent"], global_root_mm=scores["global_root_mm"],
                                 kinematic_global_root_mm=kinematic_scores["global_root_mm"],
                                 kinematic_root_relative_mm=kinematic_scores["mpjpe_root_mm"],
                                 kinematic_skate_percent=kinematic_scores["skate_percent"],
                                 kinematic_floating_percent=kinematic_scores["floating_percent"], **forces))
                print("online", {k: v for k, v in rows[-1].items() if "slides" not in k},
                      f"median slide {np.median(slide):.2f} cm", flush=True)
    summary = {}
    for calibrated in (False, True):
        sel = [r for r in rows if r["calibrated"] == calibrated]
        slides = np.concatenate([r["slides"] for r in sel])
        kinematic = np.concatenate([r["kinematic_slides"] for r in sel])
        summary["calibrated floor" if calibrated else "estimated floor"] = dict(
            slide_median_cm=float(np.median(slides)), slide_p95_cm=float(np.percentile(slides, 95)),
            kinematic_slide_median_cm=float(np.median(kinematic)),
            kinematic_slide_p95_cm=float(np.percentile(kinematic, 95)),
            jitter=float(np.mean([r["jitter"] for r in sel])),
            kinematic_jitter=float(np.mean([r["kinematic_jitter"] for r in sel])),
            flagged_percent=float(np.mean([r["flagged_percent"] for r in sel])),
            over_2bw_percent=float(np.mean([r["over_2bw_percent"] for r in sel])),
            largest_force_bw=float(max(r["largest_force_bw"] for r in sel)),
            **{key: float(np.mean([r[key] for r in sel])) for key in (
                "root_relative_mm", "skate_percent", "kinematic_root_relative_mm", "kinematic_skate_percent",
                "floating_percent", "kinematic_floating_percent", "global_root_mm", "kinematic_global_root_mm",
                "vertical_force_error_bw", "constant_force_error_bw")})
    return dict(rows=[{k: v for k, v in r.items() if "slides" not in k} for r in rows], summary=summary)


def build_online_case(name: str, seed: int, fps: float) -> dict:
    """Observations, truth, the online fit (estimated floor) and causal contacts of one clip at `fps`; no offline
    fits. Cached on disk."""
    path = CACHE / f"{name.split('/')[0]}_{name.split('/')[-1][:-4]}_{seed}_{fps:g}_online_only.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    obs, truth, settings = observe(name, seed, SECONDS, fps)
    causal, causal_stationary, _ = predict_contacts(obs, "causal")
    case = dict(obs=obs, truth=truth, settings=settings, causal=causal, causal_stationary=causal_stationary,
                online=fit_motion(obs, settings.replace(None, online=True)))
    CACHE.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(case))
    return case


def part_online_framerate(clips) -> dict:
    """The online fit and PhysCap on it at every rate of RATES, each clip observed at that rate; per rate the
    means over the clips."""
    rows = []
    for name in clips:
        for fps in RATES:
            case = build_online_case(name, 0, fps)
            motion, physics = physcap_online(case)
            row = dict(clip=name.split("/")[-1], fps=fps, flagged_percent=100 * float(physics.unexplained.mean()),
                       largest_force_bw=largest_force_bw(physics, motion.body.mass))
            for label, qpos in (("kinematic", motion.qpos), ("physics", physics.qpos)):
                scores = truth_scores(motion, qpos, case["truth"])
                joints = kin.forward_kinematics(motion.body, qpos).points
                slide = contact_slide_cm(motion.body, qpos, physics.contacts)
                row.update({f"{label}_root_relative_mm": scores["mpjpe_root_mm"],
                            f"{label}_global_root_mm": scores["global_root_mm"],
                            f"{label}_skate_percent": scores["skate_percent"],
                            f"{label}_jitter": metrics.mean_acceleration(joints, fps),
                            f"{label}_slide_median_cm": float(np.median(slide)) if slide.size else float("nan")})
            rows.append(row)
            print("online_framerate", row, flush=True)
    summary = {f"{fps:g}": {key: float((np.max if key == "largest_force_bw" else np.mean)(
        [r[key] for r in rows if r["fps"] == fps])) for key in rows[0] if key not in ("clip", "fps")} for fps in RATES}
    return dict(rows=rows, summary=summary)


METHODS = ("kinematic offline", "kinematic refined (B.4)", "physcap on refined", "trajopt")


def part_methods(clips, seeds, methods=METHODS, walking=WALKING, fps: float = FPS) -> dict:
    """The methods' metrics on the clips filmed at `fps`."""
    rows = []
    for name in clips:
        for seed in seeds:
            case = build_case(name, seed, fps, online=False)
            truth = case["truth"]
            true_force = true_vertical_force(case["offline"].body, truth)
            source_force = source_vertical_force(case["offline"].body, name, fps, len(true_force))
            true_contacts = true_contact_labels(truth)
            # Issue 17's phases where only the feet touch the ground: not where the true body rests off its feet
            feet_down = true_contacts.any(axis=1) & case["obs"].valid & ~true_resting_off_feet(truth)
            for method in methods:
                grf, residual, flagged, seconds = None, None, None, 0.0
                if method == "kinematic offline":
                    motion, qpos, seconds = case["offline"], case["offline"].qpos, case["offline"].seconds
                elif method == "kinematic refined (B.4)":
                    motion, qpos = case["refined"].motion, case["refined"].motion.qpos
                    seconds = case["offline"].seconds + case["refined"].seconds
                elif method == "physcap on refined":
                    motion, physics = physcap_offline(case)
                    qpos, grf, residual, flagged = physics.qpos, physics.grf, physics.residual, physics.unexplained
                    seconds = case["offline"].seconds + case["refined"].seconds + physics.seconds
                else:
                    motion = case["refined"].motion
                    start = time.perf_counter()
                    result = run_trajopt(motion.body, motion.qpos, fps, case["refined"].contacts,
                                         case["settings"].trajopt)
                    qpos, grf, flagged = result.qpos, result.grf, result.qp_failures > 0
                    grf = grf if result.converged.all() else None
                    seconds = case["offline"].seconds + case["refined"].seconds + time.perf_counter() - start
                pose = kin.forward_kinematics(motion.body, qpos)
                points = to_truth_world(pose.points, motion.camera.R, motion.camera.t, truth)
                com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
                row = score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass, grf,
                                          residual)
                row.update(grf_horizontal_components(grf, motion.body.mass))
                feet = motion.body.point_index(CONTACT_POINTS)
                names = [str(n) for n in truth["joint_names"]]
                row.update(vertical_force_errors(motion.body, com, grf, fps, true_force, feet_down))
                row.update({f"{key[:-3]}_source_bw": value for key, value in
                            vertical_force_errors(motion.body, com, grf, fps, source_force, feet_down).items()})
                # cm per frame, the median over the case (docs/decisions/physics-planted-feet.md)
                slides = (held_slides_cm(points[:, feet], true_contacts),
                          held_slides_cm(truth["joints_world"][:, [names.index(n) for n in CONTACT_POINTS]],
                                         true_contacts))
                row.update(contact_slide_cm=float(np.median(slides[0])) if slides[0].size else float("nan"),
                           truth_contact_slide_cm=float(np.median(slides[1])) if slides[1].size else float("nan"))
                # the real videos' aligned error (against the detector's 3D, which the fit was fitted to) beside the
                # same measure against the true landmarks, on the feet-only frames the method explains, for the method
                # and its own input (motion.qpos) on the same frames
                judged = feet_down & (True if flagged is None else ~np.asarray(flagged, bool))
                true_limbs = truth["landmarks_world"][:, [LANDMARK_INDEX[a] for a, _ in LIMB_LANDMARKS]]
                for key, points_of in (("", pose.points), ("_input", kin.forward_kinematics(motion.body,
                                                                                              motion.qpos).points)):
                    row[f"feet_only_aligned_to_detector{key}_mm"] = aligned_error_mm(
                        points_of, list(motion.body.point_names), case["obs"], judged)
                    row[f"feet_only_aligned_to_truth{key}_mm"] = aligned_to_mm(
                        points_of, list(motion.body.point_names), true_limbs, judged)
                row.update(method=method, clip=name.split("/")[-1], seed=seed,
                           jitter=metrics.mean_acceleration(pose.points, fps),
                           flagged_percent=0.0 if flagged is None else 100 * float(np.mean(flagged)),
                           largest_force_bw=(float("nan") if grf is None else
                                             float(np.linalg.norm(grf.sum(axis=1), axis=-1).max())
                                             / (motion.body.mass * GRAVITY)),
                           seconds_per_second=seconds / (len(qpos) / fps))
                rows.append(row)
                print("methods", method, row["clip"], seed, f"root-rel {row['mpjpe_root_mm']:.1f} skate "
                      f"{row['skate_percent']:.1f} float {row['floating_percent']:.1f}", flush=True)
    summary = {}
    for method in methods:
        sel = [r for r in rows if r["method"] == method]
        keys = [k for k, v in sel[0].items() if isinstance(v, float)]
        summary[method] = {k: float(np.nanmean([r[k] for r in sel])) for k in keys}
        summary[method]["grf_mean_percent_bw_walking"] = float(np.nanmean(
            [r["grf_mean_percent_bw"] for r in sel if r["clip"] in walking]))
    return dict(rows=rows, summary=summary)


def true_vertical_force(body, truth: dict) -> np.ndarray:
    """(T,) body weights: the vertical force the true motion implies (bench_trajopt.implied_vertical_force: a force
    plate's reading after the usual 0.3 s low-pass), its centre of mass from its joints with `body`'s masses."""
    names = [str(n) for n in truth["joint_names"]]
    com = kin.center_of_mass_from_points(body, truth["joints_world"], names)
    return implied_vertical_force(com, body.mass, float(truth["fps"])) / (body.mass * GRAVITY)


def source_vertical_force(body, name: str, fps: float, frames: int) -> np.ndarray:
    """(frames,) body weights: `true_vertical_force` read off the motion capture at 120 fps and sampled at the
    case's frames (fps, a divisor of 120). The case's own truth has the frame rate of the video: at 10 fps its
    0.3 s low-pass spans 5 frames (0.5 s), too coarse to show when a force comes."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), SOURCE_FPS), SECONDS)
    com = kin.center_of_mass_from_points(body, clip.positions, list(JOINT_NAMES))
    force = implied_vertical_force(com, body.mass, SOURCE_FPS) / (body.mass * GRAVITY)
    return force[np.round(np.arange(frames) * SOURCE_FPS / fps).astype(int)]


def vertical_force_errors(body, com: np.ndarray, grf, fps: float, true_force: np.ndarray, frames: np.ndarray) -> dict:
    """Body weights, root mean square over `frames` (T,) bool (the truth's frames on its feet alone): the
    method's net vertical contact force (its motion's own m (z'' + g), second differences, without forces)
    against `true_force` (T,) (`true_vertical_force`), and a constant one body weight against the same (issue 17:
    on real footage neither method was closer to the force plates than that constant). com: (T, 3) the method's
    centre of mass in the truth's world."""
    force = (metrics.implied_grf(com, body.mass, fps)[:, 2] if grf is None else grf[..., 2].sum(axis=1))
    force = force / (body.mass * GRAVITY)
    rms = lambda x: float(np.sqrt(np.mean(x[frames] ** 2))) if frames.any() else float("nan")  # noqa: E731
    return dict(vertical_force_error_bw=rms(force - true_force), constant_force_error_bw=rms(1.0 - true_force))


def grf_horizontal_components(grf, mass: float) -> dict:
    """% BW: the mean over frames of the net contact force's vertical component, of its horizontal magnitude, and
    of that magnitude after a 9-frame moving average (what the horizontal force does beyond frame-to-frame
    chatter: docs/decisions/physics-grf-chatter.md); nan without forces."""
    if grf is None:
        return dict(grf_vertical_percent_bw=float("nan"), grf_horizontal_percent_bw=float("nan"),
                    grf_horizontal_9_frames_percent_bw=float("nan"))
    net = 100 * grf.sum(axis=1) / (mass * GRAVITY)
    averaged = np.stack([np.convolve(net[:, i], np.ones(9) / 9, "valid") for i in range(2)], axis=1)
    return dict(grf_vertical_percent_bw=float(net[:, 2].mean()),
                grf_horizontal_percent_bw=float(np.linalg.norm(net[:, :2], axis=1).mean()),
                grf_horizontal_9_frames_percent_bw=float(np.linalg.norm(averaged, axis=1).mean()))


SPEED_RATES = (25.0, 30.0, 60.0)
# (fps, steps per frame): the default's steps, then steps of 0.020, 0.025, 0.021 and 0.033 s
STABILITY_CASES = ((10.0, 10), (10.0, 5), (10.0, 4), (24.0, 2), (30.0, 1))


def part_stability() -> dict:
    """PhysCap on the validation walks' 60 fps B.4 motion resampled, with STABILITY_CASES' equal steps (the legacy
    `iterations` path): step as a share of stability_limit, largest force, frames flagged, distance to the input."""
    rows = []
    limit = stability_limit(PhysicsSettings())
    for name in VALIDATION_CLIPS[:2]:
        case = build_case(name, 0, 60.0, online=False)
        motion, refined = case["refined"].motion, case["refined"]
        for fps, steps in STABILITY_CASES:
            qpos, source = resample_motion(motion.body, motion.qpos, 60.0, fps)
            settings = dataclasses.replace(PhysicsSettings(), step_stability_share=None, iterations=steps, step=None)
            physics = run_physcap(motion.body, qpos, fps, refined.contacts[source], case["stationary"][source],
                                  settings, refined_input=True)
            distance = np.linalg.norm(kin.forward_kinematics(motion.body, physics.qpos).points
                                      - kin.forward_kinematics(motion.body, qpos).points, axis=-1).mean(axis=1)
            rows.append(dict(clip=name.split("/")[-1], fps=fps, steps=steps, step_ms=1000 / (fps * steps),
                             share_of_limit=1 / (fps * steps * limit),
                             finite=bool(np.isfinite(physics.qpos).all() and np.isfinite(physics.grf).all()),
                             largest_force_bw=largest_force_bw(physics, motion.body.mass),
                             flagged_percent=100 * float(physics.unexplained.mean()),
                             to_input_mm=1000 * float(distance.mean())))
            print("stability", rows[-1], flush=True)
    return dict(rows=rows, limit_s=limit)


def time_physics(repeats: int) -> dict:
    """CPU seconds per frame of run_physcap (median of `repeats`) on the 60 fps 131_01 case's B.4-refined motion
    resampled to each of SPEED_RATES, tracked as offline capture does (refined_input, where the code under test
    has it); run in a child process whose PYTHONPATH picks the code under test."""
    import inspect

    refined_input = "refined_input" in inspect.signature(run_physcap).parameters
    case = build_case(CLIPS[0], 0, 60.0, online=False)
    motion, refined = case["refined"].motion, case["refined"]
    out = {}
    for fps in SPEED_RATES:
        qpos, source = resample_motion(motion.body, motion.qpos, 60.0, fps)
        runs = []
        for _ in range(repeats):
            start = time.process_time()
            run_physcap(motion.body, qpos, fps, refined.contacts[source], case["stationary"][source],
                        case["settings"].physics, refined_input=refined_input)
            runs.append((time.process_time() - start) / len(qpos))
        out[f"{fps:g}"] = float(np.median(runs))
    return out


def part_speed(against: str, rounds: int = 3, repeats: int = 3) -> dict:
    """Frames per CPU second of this tree's PhysCap and of the tree whose src folder is `against` (e.g. main's),
    alternating child processes, `rounds` each; the median per rate."""
    import subprocess

    build_case(CLIPS[0], 0, 60.0, online=False)  # cached before timing
    mine = str(Path(__file__).resolve().parents[1] / "src")
    seconds = {"this branch": [], "before": []}
    for _ in range(rounds):
        for label, src in (("this branch", mine), ("before", against)):
            done = subprocess.run([sys.executable, __file__, "--time-only", str(repeats)], capture_output=True,
                                  text=True, env={**os.environ, "PYTHONPATH": src}, check=True)
            seconds[label].append(json.loads(done.stdout.strip().splitlines()[-1]))
    return {label: {rate: 1.0 / float(np.median([run[rate] for run in runs])) for rate in runs[0]}
            for label, runs in seconds.items()} | dict(against=against, load_average=os.getloadavg()[0])


def other_tree(against: str):
    """(run_physcap, its default PhysicsSettings) of the tree whose src folder is `against`: its dynamics package
    and config loaded beside this tree's in one process (the rest of physmocap is this tree's)."""
    import importlib
    import importlib.util

    folder = Path(against) / "physmocap" / "dynamics"
    spec = importlib.util.spec_from_file_location("physmocap.dynamics_against", folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = package
    spec.loader.exec_module(package)
    # the tree's own default physics settings (a renamed setting would break the other tree's code)
    config_spec = importlib.util.spec_from_file_location("physmocap.config_against",
                                                         Path(against) / "physmocap" / "config.py")
    config_against = importlib.util.module_from_spec(config_spec)
    sys.modules[config_spec.name] = config_against
    config_spec.loader.exec_module(config_against)
    return importlib.import_module(f"{spec.name}.stage").run_physcap, config_against.PhysicsSettings()


def part_speed_alternating(against: str, rounds: int = 7) -> dict:
    """Frames per CPU second (median and best of `rounds`) of this tree's physics stage and of the dynamics package
    of the tree whose src folder is `against`, loaded beside it in one process (other_tree; each runs with its own
    tree's default PhysicsSettings) and alternated run by run, so that a busy machine's changing load falls on both
    alike."""
    run_against, settings_against = other_tree(against)
    runners = {"this branch": run_physcap, "before": run_against}
    physics_settings = {"this branch": PhysicsSettings(), "before": settings_against}
    case = build_case(CLIPS[0], 0, 60.0, online=False)
    motion, refined = case["refined"].motion, case["refined"]
    online_case = build_case(CLIPS[1], 0)
    online = online_case["online"]
    out: dict = {"this branch": {}, "before": {}, "this branch best": {}, "before best": {}}
    # per column: the motion, its frame rate, contacts, stationary flags and run_physcap's keywords
    columns = {f"{fps:g}": (qpos, fps, refined.contacts[source], case["stationary"][source],
                            dict(refined_input=True))
               for fps in SPEED_RATES for qpos, source in [resample_motion(motion.body, motion.qpos, 60.0, fps)]}
    # the online path (planted feet, refined floor): 006_01's online fit
    columns[f"{online_case['obs'].fps:g} online"] = (online.qpos, online_case["obs"].fps, online_case["causal"],
                                                      online_case["causal_stationary"], dict(refine_floor=True))
    for column, (qpos, fps, contacts, stationary, keywords) in columns.items():
        seconds: dict[str, list[float]] = {label: [] for label in runners}
        for round_ in range(rounds + 1):  # the first round warms both up
            for label, run in runners.items():
                start = time.process_time()
                run(motion.body if "refined_input" in keywords else online.body, qpos, fps, contacts, stationary,
                    physics_settings[label], **keywords)
                if round_:
                    seconds[label].append((time.process_time() - start) / len(qpos))
        for label, runs in seconds.items():
            out[label][column] = 1.0 / float(np.median(runs))
            out[f"{label} best"][column] = 1.0 / float(np.min(runs))
    return out | dict(against=against, load_average=os.getloadavg()[0], rounds=rounds)


def identity_runs(run, settings: PhysicsSettings):
    """(name, PhysicsMotion) of part identical's eight runs with `run` (a run_physcap) and default `settings`."""
    case = build_case(CLIPS[0], 0, 60.0, online=False)
    motion, refined = case["refined"].motion, case["refined"]
    for fps in (10.0, 25.0, 30.0, 60.0):
        qpos, source = resample_motion(motion.body, motion.qpos, 60.0, fps)
        yield f"131_01 at {fps:g} fps", run(motion.body, qpos, fps, refined.contacts[source],
                                            case["stationary"][source], settings, refined_input=True)
    case = build_case(CLIPS[1], 0)
    fps, contacts, stationary = case["obs"].fps, case["causal"], case["causal_stationary"]
    online, calibrated = case["online"], case["online_calibrated"]
    yield "006_01 online, refined floor", run(online.body, online.qpos, fps, contacts, stationary, settings,
                                              refine_floor=True)
    yield "006_01 online, calibrated floor", run(calibrated.body, calibrated.qpos, fps, contacts, stationary,
                                                 settings)
    legacy = dataclasses.replace(settings, step_stability_share=None, iterations=3, step=None, foot_lock="never")
    yield "006_01 online, 3 legacy steps, no foot lock", run(calibrated.body, calibrated.qpos, fps, contacts,
                                                             stationary, legacy)
    case = build_case(CLIPS[0], 0, box=True, online=False)
    refined = case["refined"]
    yield "131_01 with a box", run(refined.motion.body, refined.motion.qpos, case["obs"].fps, refined.contacts,
                                   case["stationary"], settings, refined_input=True)


def part_identical(against: str) -> dict:
    """Every array of run_physcap (but the time) from this tree and from the tree whose src folder is `against`
    (other_tree), each with its own default settings, on identity_runs: the arrays not bit for bit equal."""
    run_against, settings_against = other_tree(against)
    rows = []
    for (name, mine), (_, theirs) in zip(identity_runs(run_physcap, PhysicsSettings()),
                                         identity_runs(run_against, settings_against), strict=True):
        ours, base = mine.to_arrays(), theirs.to_arrays()
        differing = {key: float(np.nanmax(np.abs(ours[key].astype(float) - base[key].astype(float))))
                     if ours[key].shape == base[key].shape else float("nan")
                     for key in ours if key != "seconds" and not np.array_equal(ours[key], base[key], equal_nan=True)}
        rows.append(dict(run=name, frames=len(mine.qpos), arrays=len(ours) - 1, differing=differing,
                         flagged=int(np.count_nonzero(mine.unexplained))))
        print("identical", rows[-1], flush=True)
    return dict(rows=rows, against=against)


PROFILED = {  # module -> class -> methods of part profile (nested calls count in both)
    "physmocap.dynamics.stage": {"PhysicsStream": ("push", "_diagnose", "_deviation")},
    "physmocap.dynamics.balance": {"BalanceCorrector": ("correct",)},
    "physmocap.dynamics.physcap": {"PhysCapTracker": (
        "track", "_dynamics", "_step_state", "_rigid_body_terms", "_desired_acceleration", "ground_reaction_forces",
        "pose_accelerations", "_pose_accelerations", "_velocity_bounds", "_unconstrained", "kinematic_misfit")},
    "physmocap.dynamics.qp": {"DenseQP": ("solve",)},
}


def part_planting_long(minutes: float = 10.0) -> dict:
    """Peak memory (MB, tracemalloc: numpy's allocations included) and CPU seconds of plant_held_feet over
    `minutes` of 131_01's 30 fps B.4 motion and PhysCap's held contacts, looped."""
    import tracemalloc

    from physmocap.dynamics.planting import plant_held_feet

    case = build_case(CLIPS[0], 0, online=False)
    motion, physics = physcap_offline(case)
    fps = case["obs"].fps
    loops = int(np.ceil(minutes * 60 * fps / len(physics.qpos)))
    qpos, contacts = np.tile(physics.qpos, (loops, 1)), np.tile(physics.contacts, (loops, 1))
    reference = np.tile(motion.qpos, (loops, 1))
    tracemalloc.start()
    start = time.process_time()
    plant_held_feet(motion.body, qpos, contacts, fps, PhysicsSettings().plant_reach, np.zeros(len(qpos), bool),
                    reference)
    seconds = time.process_time() - start
    peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
    tracemalloc.stop()
    print("planting_long", len(qpos), "frames", f"{peak:.0f} MB", f"{seconds:.1f} CPU s", flush=True)
    return dict(frames=len(qpos), peak_mb=peak, cpu_seconds=seconds)


def part_profile(fps: float = 30.0) -> dict:
    """CPU microseconds per frame and calls per frame of each PROFILED method (those the tree has) while
    run_physcap tracks 131_01's 60 fps B.4 motion resampled to `fps`; and the stage's CPU time per frame without
    the wrappers."""
    import importlib

    case = build_case(CLIPS[0], 0, 60.0, online=False)
    motion, refined = case["refined"].motion, case["refined"]
    qpos, source = resample_motion(motion.body, motion.qpos, 60.0, fps)

    def run() -> float:
        start = time.process_time()
        run_physcap(motion.body, qpos, fps, refined.contacts[source], case["stationary"][source], PhysicsSettings(),
                    refined_input=True)
        return (time.process_time() - start) / len(qpos)

    run()  # warm
    unwrapped = min(run() for _ in range(3))
    seconds: dict[str, float] = {}
    calls: dict[str, int] = {}
    originals = []

    def wrapped(label, method):
        def timed(*args, **kwargs):
            start = time.process_time()
            try:
                return method(*args, **kwargs)
            finally:
                seconds[label] = seconds.get(label, 0.0) + time.process_time() - start
                calls[label] = calls.get(label, 0) + 1
        return timed

    for module_name, classes in PROFILED.items():
        try:
            module = importlib.import_module(module_name)
        except ImportError:  # a tree without the module (the QP workspace)
            continue
        for class_name, methods in classes.items():
            owner = getattr(module, class_name)
            for name in methods:
                if hasattr(owner, name):
                    originals.append((owner, name, getattr(owner, name)))
                    setattr(owner, name, wrapped(f"{class_name}.{name}", getattr(owner, name)))
    physcap_module = importlib.import_module("physmocap.dynamics.physcap")
    if hasattr(physcap_module, "daqp"):  # a tree calling daqp.solve
        import types

        originals.append((physcap_module, "daqp", physcap_module.daqp))
        physcap_module.daqp = types.SimpleNamespace(solve=wrapped("daqp.solve", physcap_module.daqp.solve))
    try:
        run()
    finally:
        for owner, name, method in originals:
            setattr(owner, name, method)
    frames = len(qpos)
    rows = [dict(method=label, us_per_frame=1e6 * value / frames, calls_per_frame=calls[label] / frames)
            for label, value in sorted(seconds.items(), key=lambda item: -item[1])]
    return dict(fps=fps, unwrapped_us_per_frame=1e6 * unwrapped, rows=rows, load_average=os.getloadavg()[0])


# ---- report ---------------------------------------------------------------------------------------------------
def _speed_table(sp: dict, title: str, cell) -> list[str]:
    """A speed part's table: a row per code version, a column per frame rate; cell(label, rate, median) its text."""
    rates = list(sp["this branch"])
    lines = [title, "", "| code | " + " | ".join(f"{r} fps" for r in rates) + " |", "|---|" + "---|" * len(rates)]
    for label in ("this branch", "before"):
        name = label if label == "this branch" else f"before ({sp['against']})"
        lines.append(f"| {name} | " + " | ".join(cell(label, r, v) for r, v in sp[label].items()) + " |")
    return lines + [""]


def split_table_rows(rows: list[dict], groups: tuple[str, str], last) -> list[str]:
    """Markdown rows of parts levels and seated: per clip and method, each measure on the `groups[0]` / `groups[1]`
    frames, the frames flagged, and last(row) for a physics method (empty cells for a kinematic one)."""
    a, b = groups
    lines = []
    for r in rows:
        cells = [f"{r[f'{a}_{key}']:.1f} / {r[f'{b}_{key}']:.1f}" for key in (
            "root_relative_mm", "procrustes_mm", "global_root_mm")]
        solved = "largest_force_bw" in r
        flagged = f"{r[f'{a}_flagged_percent']:.0f} / {r[f'{b}_flagged_percent']:.0f}" if solved else ""
        lines.append(f"| {r['clip']} | {r['method']} | {r[f'{a}_frames']} of {r['frames']} | {' | '.join(cells)} | "
                     f"{flagged} | {last(r) if solved else ''} |")
    return lines


def markdown(out: dict) -> str:
    lines = []
    if "framerate" in out:
        lines += ["**Same motion at 10, 24, 30, 60 and 120 fps** (the 60 fps case's B.4-refined kinematics resampled; "
                  "PhysCap; mean joint distance to the 60 fps run at common times from 0.5 s on)", "",
                  "| clip | fps | finite | largest force BW | flagged % | physics vs 60 fps: mean mm | p95 mm | "
                  "max mm | root-relative mm (p95) | root horizontal mm | physics vs its own input mm | jitter m/s² (input) | ms/frame |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in out["framerate"]["rows"]:
            lines.append(f"| {r['clip']} | {r['fps']:g} | {r['finite']} | {r['largest_force_bw']:.2f} | "
                         f"{r['flagged_percent']:.1f} | {r['physics_vs_60_mm']:.1f} | "
                         f"{r['physics_vs_60_p95_mm']:.1f} | {r['physics_vs_60_max_mm']:.1f} | "
                         f"{r.get('root_relative_vs_60_mm', np.nan):.1f} "
                         f"({r.get('root_relative_vs_60_p95_mm', np.nan):.1f}) | "
                         f"{r.get('root_horizontal_vs_60_mm', np.nan):.1f} | "
                         f"{r.get('physics_vs_own_input_mm', np.nan):.1f} | {r.get('jitter', np.nan):.2f} "
                         f"({r.get('input_jitter', np.nan):.2f}) | {r['ms_per_frame']:.2f} |")
        lines.append("")
    if "online_framerate" in out:
        lines += ["**The online path at 10 to 120 fps** (each clip observed at each rate; online fit, then PhysCap "
                  "on it, estimated floor; means over the clips: kinematic input / physics)", "",
                  "| fps | root-relative mm | global root mm | jitter m/s² | skate % | contact slide median cm/frame | "
                  "flagged % | largest force BW |", "|---|---|---|---|---|---|---|---|"]
        for fps, s in out["online_framerate"]["summary"].items():
            pair = [f"{s['kinematic_' + key]:.1f} / {s['physics_' + key]:.1f}" for key in (
                "root_relative_mm", "global_root_mm", "jitter", "skate_percent")]
            lines.append(f"| {fps} | {' | '.join(pair)} | {s['kinematic_slide_median_cm']:.2f} / "
                         f"{s['physics_slide_median_cm']:.2f} | {s['flagged_percent']:.1f} | "
                         f"{s['largest_force_bw']:.2f} |")
        lines.append("")
    for part in ("seated_validation", "seated"):
        if part not in out:
            continue
        lines += [f"**Seated on stools{', validation' if 'validation' in part else ''}** (CMU; seated: the true pelvis "
                  f"under {out[part]['seated_share']:g} of its standing height above the soles; each cell seated / "
                  "standing frames)", "", "| clip | method | seated frames | root-relative mm | Procrustes mm | "
                  "global root mm | flagged % | mean contact force, unflagged, BW |", "|---|---|---|---|---|---|---|---|"]
        lines += split_table_rows(out[part]["rows"], ("seated", "standing"), lambda r: " / ".join(
            "-" if v is None else f"{v:.2f}" for v in r["mean_force_bw"].values())) + [""]
    for part in ("levels_validation", "levels"):
        if part not in out:
            continue
        lines += [f"**Real motion on other levels{', validation' if 'validation' in part else ''}** (CMU stairs, "
                  "ladders, a playground; ground at z = 0; raised: the true lowest sole "
                  f"{out[part]['raised_m']:g} m or more above it; each cell raised / ground frames)", "",
                  "| clip | method | raised frames | root-relative mm | Procrustes mm | global root mm | flagged % | "
                  "largest force BW |", "|---|---|---|---|---|---|---|---|"]
        lines += split_table_rows(out[part]["rows"], ("raised", "ground"),
                                  lambda r: f"{r['largest_force_bw']:.2f}") + [""]
    for part in ("diagnosis", "diagnosis_10fps"):
        if part not in out:
            continue
        rows = out[part]["rows"]
        lines += [f"**Diagnosis: a box under the walk at {out[part].get('fps', FPS):g} fps** (0.3 m from 3.0 to 5.5 s; "
                  "truly unexplainable: lifted >= 0.1 m, or the true body resting off its feet, a knee or elbow within "
                  "body.support.RESTING_HEIGHT of the floor: 131_01's knee slide)",
                  "", "| method | share of truly unexplainable frames flagged % | frames flagged elsewhere on "
                  "the box clips % | truly unexplainable frames of the ordinary clips flagged % | frames flagged "
                  "elsewhere on the ordinary clips % | root error in the box mm | largest force BW |",
                  "|---|---|---|---|---|---|---|"]
        for method in dict.fromkeys(r["method"] for r in rows):
            box = [r for r in rows if r["method"] == method and r["box"]]
            plain = [r for r in rows if r["method"] == method and not r["box"]]
            box_truly = sum(r["truly_unexplained"] for r in box)  # a short validation clip may end before the box
            recall = 100 * sum(r["recall_percent"] * r["truly_unexplained"] / 100 for r in box
                               if r["truly_unexplained"]) / box_truly if box_truly else float("nan")
            resting = sum(r["truly_unexplained"] for r in plain)
            plain_recall = 100 * sum(r["recall_percent"] * r["truly_unexplained"] / 100 for r in plain
                                     if r["truly_unexplained"]) / resting if resting else float("nan")
            lines.append(f"| {method} | {recall:.1f} | {np.mean([r['false_flag_percent'] for r in box]):.1f} | "
                         f"{plain_recall:.1f} | {np.mean([r['false_flag_percent'] for r in plain]):.2f} | "
                         f"{np.mean([r['root_error_in_box_mm'] for r in box if r['truly_unexplained']]):.0f} | "
                         f"{max(r['largest_force_bw'] for r in rows if r['method'] == method):.2f} |")
        lines.append("")
    if "online" in out:
        lines += ["**Online PhysCap: contact slide and jitter**", "",
                  "| floor | slide median cm/frame | slide p95 cm/frame | input's slide at those contacts median "
                  "(p95) | jitter m/s² | input's jitter m/s² | flagged % | root-rel. mm (input) | skate % (input) | "
                  "float % (input) | frames over 2 BW % | largest contact force BW |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for floor, s in out["online"]["summary"].items():
            lines.append(f"| {floor} | {s['slide_median_cm']:.2f} | {s['slide_p95_cm']:.2f} | "
                         f"{s['kinematic_slide_median_cm']:.2f} ({s['kinematic_slide_p95_cm']:.2f}) | "
                         f"{s['jitter']:.2f} | {s['kinematic_jitter']:.2f} | {s['flagged_percent']:.2f} | "
                         f"{s.get('root_relative_mm', np.nan):.1f} ({s.get('kinematic_root_relative_mm', np.nan):.1f}) "
                         f"| {s.get('skate_percent', np.nan):.1f} ({s.get('kinematic_skate_percent', np.nan):.1f}) | "
                         f"{s.get('floating_percent', np.nan):.1f} ({s.get('kinematic_floating_percent', np.nan):.1f}) | "
                         f"{s.get('over_2bw_percent', np.nan):.2f} | {s.get('largest_force_bw', np.nan):.2f} |")
        lines.append("")
    if "speed" in out:
        sp = out["speed"]
        lines += _speed_table(sp, f"**Speed** (frames per CPU second of the physics stage, median of 3 child "
                              f"processes x 3 runs, alternating; load average {sp['load_average']:.1f})",
                              lambda label, rate, v: f"{v:.0f}")
    if "speed_alternating" in out:
        sp = out["speed_alternating"]
        lines += _speed_table(sp, f"**Speed, alternating in one process** (frames per CPU second of the physics "
                              f"stage, median (best) of {sp['rounds']} runs each; load average "
                              f"{sp['load_average']:.1f})",
                              lambda label, rate, v: f"{v:.0f} ({sp[label + ' best'][rate]:.0f})")
    if "planting_long" in out:
        pl = out["planting_long"]
        lines += [f"**The offline planting on ten minutes** ({pl['frames']} frames of 131_01's motion looped): peak "
                  f"memory of its allocations {pl['peak_mb']:.0f} MB, {pl['cpu_seconds']:.1f} CPU s", ""]
    if "identical" in out:
        lines += [f"**Every array of run_physcap against {out['identical']['against']}** (bit for bit: np.array_equal)",
                  "", "| run | frames | frames flagged | arrays | arrays differing (largest difference) |",
                  "|---|---|---|---|---|"]
        for r in out["identical"]["rows"]:
            differing = ", ".join(f"{k} ({v:.2g})" for k, v in r["differing"].items()) or "none"
            lines.append(f"| {r['run']} | {r['frames']} | {r['flagged']} | {r['arrays']} | {differing} |")
        lines.append("")
    if "profile" in out:
        pr = out["profile"]
        lines += [f"**Where the time goes** (131_01 at {pr['fps']:g} fps; {pr['unwrapped_us_per_frame']:.0f} us of CPU "
                  f"a frame without the wrappers; load average {pr['load_average']:.1f})", "",
                  "| method | CPU us per frame | calls per frame |", "|---|---|---|"]
        for r in pr["rows"]:
            lines.append(f"| {r['method']} | {r['us_per_frame']:.0f} | {r['calls_per_frame']:.2f} |")
        lines.append("")
    if "stability" in out:
        lines += [f"**Step against the PD's stability limit** ({1000 * out['stability']['limit_s']:.1f} ms; "
                  "validation walks, 60 fps B.4 motion resampled)", "",
                  "| clip | fps | steps | step ms | share of the limit | finite | largest force BW | flagged % | "
                  "to input mm |", "|---|---|---|---|---|---|---|---|---|"]
        for r in out["stability"]["rows"]:
            lines.append(f"| {r['clip']} | {r['fps']:g} | {r['steps']} | {r['step_ms']:.1f} | "
                         f"{r['share_of_limit']:.2f} | {r['finite']} | {r['largest_force_bw']:.2f} | "
                         f"{r['flagged_percent']:.1f} | {r['to_input_mm']:.1f} |")
        lines.append("")
    for part, title in (("methods", "Offline methods"), ("methods_10fps", "Offline methods, videos filmed at 10 fps")):
        if part not in out:
            continue
        lines += [f"**{title}**", "", "| method | root-rel. mm | Procrustes mm | global root mm | "
                  "skate % | float % | penetr. % | slide in true contact cm/frame (truth's) | jitter m/s² | e_smooth mm "
                  "| GRF mean % BW | GRF mean walks % BW | GRF max % BW | ballistic % BW | GRF vertical / horizontal / "
                  "horizontal 9-frame % BW | vertical force against the truth's, RMS BW (a constant 1 BW's) | the same, "
                  "the truth's read at 120 fps | flagged % | s per s of video |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for method, s in out[part]["summary"].items():
            lines.append(
                f"| {method} | {s['mpjpe_root_mm']:.1f} | {s['mpjpe_procrustes_mm']:.1f} | {s['global_root_mm']:.1f} "
                f"| {s['skate_percent']:.1f} | {s['floating_percent']:.1f} | {s['penetration_percent']:.2f} | "
                f"{s.get('contact_slide_cm', np.nan):.2f} ({s.get('truth_contact_slide_cm', np.nan):.2f}) | "
                f"{s['jitter']:.2f} | {s['e_smooth_mm']:.2f} | {s['grf_mean_percent_bw']:.1f} | "
                f"{s['grf_mean_percent_bw_walking']:.1f} | {s['grf_max_percent_bw']:.0f} | "
                f"{s['grf_ballistic_percent_bw']:.1f} | {s.get('grf_vertical_percent_bw', np.nan):.1f} / "
                f"{s.get('grf_horizontal_percent_bw', np.nan):.1f} / "
                f"{s.get('grf_horizontal_9_frames_percent_bw', np.nan):.1f} | "
                f"{s.get('vertical_force_error_bw', np.nan):.3f} ({s.get('constant_force_error_bw', np.nan):.3f}) | "
                f"{s.get('vertical_force_error_source_bw', np.nan):.3f} "
                f"({s.get('constant_force_error_source_bw', np.nan):.3f}) | "
                f"{s['flagged_percent']:.2f} | {s['seconds_per_second']:.2f} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--parts", nargs="+", default=["framerate", "diagnosis", "diagnosis_10fps", "online", "methods"])
    parser.add_argument("--quick", action="store_true", help="three clips (two for framerate), one seed")
    parser.add_argument("--set", choices=("test", "validation"), default="test",
                        help="clips of parts methods, framerate and levels: the test set or the validation clips "
                             "(training subjects; settings are chosen there)")
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS),
                        help="the rows of part methods")
    parser.add_argument("--physics", nargs="*", default=[], metavar="NAME=VALUE",
                        help="PhysicsSettings fields for PhysCap in parts methods, framerate and online (trying "
                             "settings on validation clips)")
    parser.add_argument("--json", default=str(RESULTS / "physics_limits.json"))
    parser.add_argument("--against", default=str(Path(__file__).resolve().parents[2] / "main" / "src"),
                        help="src folder of the code to compare with in parts speed, speed_alternating and "
                             "identical (default: ../main/src)")
    parser.add_argument("--time-only", type=int, default=None, help=argparse.SUPPRESS)  # child of part speed
    args = parser.parse_args(argv)
    if args.time_only:
        print(json.dumps(time_physics(args.time_only)))
        return {}
    all_clips, walks = (VALIDATION_CLIPS, VALIDATION_WALKING) if args.set == "validation" else (CLIPS, WALKING)
    clips = all_clips[:3] if args.quick else all_clips
    seeds = (0,) if args.quick else (0, 1)
    walking = [c for c in clips if c.split("/")[-1] in walks]
    path = Path(args.json)
    out = json.loads(path.read_text()) if path.exists() else {}
    global PHYSICS
    PHYSICS = dataclasses.replace(PhysicsSettings(), **settings_overrides(args.physics))
    for part in args.parts:
        start = time.perf_counter()
        if part == "framerate":
            # validation: the jump, dance and bend clips too, where the diagnosis flags frames (the walks flag none)
            out[part] = part_framerate(all_clips if args.set == "validation" else all_clips[:2])
        elif part == "diagnosis":
            out[part] = part_diagnosis(walking, seeds)
        elif part == "diagnosis_10fps":
            out[part] = part_diagnosis(walking, seeds, 10.0)
        elif part == "levels":  # kept beside the other set's (both in the markdown)
            part = "levels_validation" if args.set == "validation" else "levels"
            out[part] = part_levels(LEVEL_CLIPS[args.set])
        elif part == "seated":
            part = "seated_validation" if args.set == "validation" else "seated"
            out[part] = part_levels(SEATED_CLIPS[args.set], held=seated_frames, groups=("seated", "standing"),
                                    online=True)
        elif part == "online":
            out[part] = part_online(clips, seeds)
        elif part == "online_framerate":
            out[part] = part_online_framerate(clips)
        elif part == "methods":
            out[part] = part_methods(clips, seeds, args.methods, walks)
        elif part == "methods_10fps":  # the whole capture of videos filmed at 10 fps (issue 17's low-rate footage)
            out[part] = part_methods(clips, seeds, args.methods, walks, 10.0)
        elif part == "speed":
            out[part] = part_speed(args.against)
        elif part == "stability":
            out[part] = part_stability()
        elif part == "speed_alternating":
            out[part] = part_speed_alternating(args.against)
        elif part == "identical":
            out[part] = part_identical(args.against)
        elif part == "profile":
            out[part] = part_profile()
        elif part == "planting_long":
            out[part] = part_planting_long()
        out[part]["minutes"] = (time.perf_counter() - start) / 60
    RESULTS.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    path.with_suffix(".md").write_text(markdown(out))
    print(markdown(out))
    return out


if __name__ == "__main__":
    main()
