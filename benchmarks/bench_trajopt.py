"""Trajectory optimisation (Rempe et al. 2020) on the synthetic ground-truth set: the metrics of Rempe tables 2
and 3 for the kinematic motion, the B.4-refined kinematic motion, PhysCap on it (as the pipeline runs PhysCap
offline) and trajopt; the share of clips whose optimisation converges; and solve time against clip length.

Synthetic set: the clips of bench_synthetic (held-out CMU subjects 6 and 131), its observations (MediaPipe-like
noise, true intrinsics, true height), the offline kinematic fit, the centred contact network's predictions, then
refine_kinematics (B.4) and run_trajopt; once more with the true floor given (the paper's table 2 protocol;
the estimated floor is its table E3). Convergence is counted as the paper counts it, on 2-second clips at
30 fps: the refined motion of every case is cut into 2 s pieces, each optimised on its own; a piece converges
when IPOPT converges on it. Scaling: the 22.9 s CMU clip 001_01 (jumps and turns) fitted the same way, trajopt on
its first 2, 5, 10 and 20 s (wall time of run_trajopt alone, median of --repeats runs).

    .venv/bin/python benchmarks/bench_trajopt.py [--quick] [--seeds 0 1] [--repeats 1] [--scaling-only]
        [--clips 131_01.bvh ...] [--accuracy-only] [--json OUT.json]

Writes benchmarks/results/trajopt.json and trajopt.md. Other modes (issues 23, 24):
    --validation 0 1e-5 ...  the force_rate weight on validation clips (subjects 2, 5, 7) at 24 and 30 fps:
                             accuracy, largest solved vertical force over the largest the true motion implies,
                             frame-to-frame alternation; writes results/trajopt_validation.json
    --long 2 5 10 30 ...     time against clip length on a looped dance, wall and CPU seconds, load, every
                             window's frames, iterations, seconds, restarts and contact switches; writes
                             results/trajopt_long.json
    --compare-parallel 10 15 windows one after another against two at a time (trajopt.parallel_windows), runs
                             interleaved --repeats times: wall and CPU seconds, differences; writes
                             results/trajopt_parallel.json
    --window 60 178 297      one window of that looped dance (seconds, first and last frame) from a free start
    --flights                the labels' whole-body flights on validation clips (subjects 1, 2, 5, 7) at 24 and
                             30 fps: the support their COM needs; writes results/trajopt_flights.json
    --framerate test|validation  the same motion at 10, 24, 30, 60 and 120 fps (issue 17): trajopt's joints against
                             its 60 fps run; writes results/trajopt_framerate_SET.json
    --videos RUN ...         trajopt on capture run folders' refined motion: solved against implied forces;
                             writes results/trajopt_videos.json
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import logging
import os
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

sys.path.insert(0, str(Path(__file__).parent))
from bench_synthetic import CLIP_SETS, FPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, RESULTS, git_revision, machine_description, truth_scores  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.body.model import CONTACT_POINTS  # noqa: E402
from physmocap.config import Settings, TrajoptSettings  # noqa: E402
from physmocap.contacts.labels import LabelSettings, contact_labels  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.io.atomic import write_text  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import NoiseModel, make_observations, random_camera, resample  # noqa: E402
from physmocap.trajopt import run_trajopt  # noqa: E402

METHODS = ("kinematic offline", "kinematic refined (B.4)", "physcap on offline", "trajopt",
           "kinematic refined, true floor", "trajopt, true floor")
PIECE_SECONDS = 2.0
TOUCHING = 0.02  # m: a heel or toe this close to the floor touches it (the labels' height limit is 5 cm)
SCALING_CLIP = "cmu_iclone_cc3_retarget/001_01.bvh"
SCALING_SECONDS = (2.0, 5.0, 10.0, 20.0)
LONG_CLIP = "cmu_iclone_cc3_retarget/005_07.bvh"  # dance: small jetes, attitude, pirouette, turn (subject 5)
# Validation clips (CMU subjects 2, 5 and 7; the test set holds 6 and 131): walk, jump and balance, dance steps,
# slow walk, bend and scoop; the force_rate weight is chosen on these, at 24 and 30 fps.
VALIDATION_CLIPS = ("cmu_iclone_cc3_retarget/002_01.bvh", "cmu_iclone_cc3_retarget/002_04.bvh",
                    "cmu_iclone_cc3_retarget/005_11.bvh", "cmu_iclone_cc3_retarget/007_04.bvh",
                    "cmu_iclone_cc3_retarget/002_06.bvh")
ALIGNED_KEYS = ("mpjpe_root_mm", "mpjpe_procrustes_mm", "floating_percent")  # --validation's pose figures
KEYS = ("global_mpjpe_mm", "first_frame_aligned_mm", "mpjpe_root_mm", "floating_percent", "penetration_percent",
        "skate_percent", "grf_mean_percent_bw", "grf_max_percent_bw", "grf_ballistic_percent_bw", "e_smooth_mm")


def observe(name: str, seed: int, seconds: float, fps: float = FPS, noise: NoiseModel = MEDIAPIPE_NOISE):
    """(observations, truth, settings at the truth's height): the clip's first `seconds` at `fps`, seen by the camera
    of `seed` through the detector errors `noise`."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), fps), seconds)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, noise)
    settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
    return obs, truth, settings


def true_flight(truth: dict, body, grf: np.ndarray) -> dict:
    """The true motion's flight frames (no point in contact by the true labels) and the GRF its own motion implies
    there, its centre of mass from its joints with the body model's segment masses
    (kin.center_of_mass_from_points): what the ballistic GRF metric gives the truth itself, the floor below which
    no estimate can be expected to go. Also how many of those frames have a heel or toe within TOUCHING of the
    floor (in the air by the labels only because the point moves faster than their speed limit: a rolling push-off),
    and the median net force of `grf` (T, 4, 3), trajopt's, over those frames and over the others (airborne);
    per flight frame, its index, whether it touches and trajopt's net force there (% of body weight).
    Also the truth's own floating, penetration and skate against its labels (the motion capture's feet slide and
    dip through the floor too)."""
    names = [str(n) for n in truth["joint_names"]]
    sites = truth["joints_world"][:, [names.index(n) for n in CONTACT_POINTS]]
    labels = contact_labels(sites, float(truth["fps"]))
    com = kin.center_of_mass_from_points(body, truth["joints_world"], names)
    forces = metrics.grf_statistics(metrics.implied_grf(com, body.mass, float(truth["fps"])), body.mass, labels)
    flight = ~labels.any(axis=1)
    touching = flight & (sites[..., 2] < TOUCHING).any(axis=1)
    percent = 100 * np.linalg.norm(grf.sum(axis=1), axis=-1) / (body.mass * metrics.GRAVITY)
    median = lambda frames: float(np.median(percent[frames])) if frames.any() else float("nan")  # noqa: E731
    feet = metrics.foot_contact_errors(sites, labels, fps=float(truth["fps"]))
    return dict(frames=int(flight.sum()), touching_frames=int(touching.sum()),
                flight_frames=np.flatnonzero(flight).tolist(), flight_touching=touching[flight].tolist(),
                flight_trajopt_percent_bw=percent[flight].tolist(),
                **{k: feet[k] for k in ("floating_percent", "penetration_percent", "skate_percent")},
                ballistic_percent_bw=forces["ballistic_percent_bw"], trajopt_touching_percent_bw=median(touching),
                trajopt_airborne_percent_bw=median(flight & ~touching))


def evaluate_case(name: str, seed: int, settings_trajopt: TrajoptSettings, pieces: bool = True) -> dict:
    obs, truth, settings = observe(name, seed, SECONDS)
    motion = fit_motion(obs, settings)
    contacts, stationary, _ = predict_contacts(obs, "centred")
    start = time.perf_counter()
    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings_trajopt)
    refine_seconds = time.perf_counter() - start
    # As the pipeline runs offline PhysCap (physics.refine_offline): on the B.4-refined motion and contacts.
    physcap = run_physcap(refined.motion.body, refined.motion.qpos, obs.fps, refined.contacts, stationary,
                          settings.physics, valid=obs.valid)
    start = time.perf_counter()
    result = run_trajopt(refined.motion.body, refined.motion.qpos, obs.fps, refined.contacts, settings_trajopt)
    trajopt_seconds = time.perf_counter() - start
    # The paper's table 2 protocol: the true floor given to the kinematic stage and kept by the refinement.
    floored = settings.replace("camera", floor=tuple(float(v) for v in truth["floor"]))
    motion_f = fit_motion(obs, floored)
    refined_f = refine_kinematics(obs, motion_f, contacts, settings.fit, settings_trajopt, keep_floor=True)
    result_f = run_trajopt(refined_f.motion.body, refined_f.motion.qpos, obs.fps, refined_f.contacts,
                           settings_trajopt)
    rows = {
        "kinematic refined, true floor": truth_scores(refined_f.motion, refined_f.motion.qpos, truth),
        "trajopt, true floor": truth_scores(refined_f.motion, result_f.qpos, truth,
                                     result_f.grf if result_f.converged.all() else None),
        "kinematic offline": truth_scores(motion, motion.qpos, truth),
        "kinematic refined (B.4)": truth_scores(refined.motion, refined.motion.qpos, truth),
        "physcap on offline": truth_scores(refined.motion, physcap.qpos, truth, physcap.grf, physcap.residual),
        # Forces only where the optimisation converged; elsewhere the kinematic motion (and its implied forces).
        "trajopt": truth_scores(refined.motion, result.qpos, truth, result.grf if result.converged.all() else None),
    }
    # The paper's protocol: 2 s pieces of the refined motion, each on its own.
    step = int(round(PIECE_SECONDS * obs.fps))
    pieces, starts = [], range(0, len(refined.motion.qpos) - step // 2, step) if pieces else []
    for a in starts:
        sl = slice(a, min(a + step, len(refined.motion.qpos)))
        t0 = time.perf_counter()
        piece = run_trajopt(refined.motion.body, refined.motion.qpos[sl], obs.fps, refined.contacts[sl],
                            settings_trajopt)
        pieces.append(dict(start=a, frames=sl.stop - a, converged=bool(piece.converged.all()),
                           seconds=time.perf_counter() - t0,
                           statuses=[s.status for w in piece.windows for s in w.stages]))
    return dict(
        clip=name.split("/")[-1], seed=seed, frames=len(motion.qpos), rows=rows,
        converged_fraction=float(result.converged.mean()), true_flight=true_flight(truth, motion.body, result.grf),
        converged_fraction_true_floor=float(result_f.converged.mean()), refine_seconds=refine_seconds,
        trajopt_seconds=trajopt_seconds, trajopt_ms_per_frame=1000 * trajopt_seconds / len(motion.qpos),
        windows=[dict(start=w.start, stop=w.stop, keep=w.keep, converged=w.converged,
                                              seconds=w.seconds, build_seconds=w.build_seconds,
                                              variables=w.variables, constraints=w.constraints,
                                              com_departure_m=w.com_departure, feet_departure_m=w.feet_departure,
                                              stages=[dataclasses.asdict(s) for s in w.stages])
                                         for w in result.windows],
        pieces=pieces)


def implied_vertical_force(com: np.ndarray, mass: float, fps: float) -> np.ndarray:
    """(T,) N: the vertical force a centre-of-mass path (T, 3) implies, m (z'' + g), its acceleration from a
    cubic Savitzky-Golay fit over about 0.3 s (at least 5 frames), as a force plate would read it after the usual
    low-pass."""
    window = max(5, int(round(0.3 * fps)) | 1)
    return mass * (savgol_filter(com[:, 2], window, 3, deriv=2, delta=1.0 / fps) + metrics.GRAVITY)


def force_check(grf: np.ndarray, converged: np.ndarray, implied: np.ndarray, mass: float) -> dict:
    """The largest solved vertical force (over converged frames) against the largest the motion implies, both in
    % of body weight, their ratio, and the largest frame-to-frame alternation of the solved net vertical force
    (second difference, % BW): the chatter of issue 24. Also the ratio against the largest implied over the same
    converged frames (ratio_converged): on real footage the largest implied may sit on frames no solution covers
    (a person leaving the view), which the plain ratio then compares with."""
    weight = mass * metrics.GRAVITY
    fz = grf[..., 2].sum(axis=1)
    solved = float(fz[converged].max()) if converged.any() else float("nan")
    implied_converged = float(implied[converged].max()) if converged.any() else float("nan")
    alternation = float(np.abs(np.diff(fz, 2)).max()) if len(fz) > 2 else 0.0
    return dict(solved_max_percent_bw=100 * solved / weight, implied_max_percent_bw=100 * float(implied.max()) / weight,
                ratio=solved / float(implied.max()), ratio_converged=solved / implied_converged,
                implied_converged_max_percent_bw=100 * implied_converged / weight,
                alternation_percent_bw=100 * alternation / weight, converged_fraction=float(converged.mean()))


def refined_clip(name: str, fps: float, settings_trajopt: TrajoptSettings):
    """Observations, truth and the B.4-refined motion (the pipeline's trajopt input) of `name`'s first SECONDS at
    `fps`, seed 0."""
    obs, truth, settings = observe(name, 0, SECONDS, fps)
    motion = fit_motion(obs, settings)
    contacts, _, _ = predict_contacts(obs, "centred")
    return obs, truth, refine_kinematics(obs, motion, contacts, settings.fit, settings_trajopt)


def validation(weights: list[float], fps_values: list[float]) -> list[dict]:
    """Trajopt's accuracy and forces on the validation clips (VALIDATION_CLIPS, subjects the reported test set
    does not hold) at each frame rate, for each force_rate weight: what the weight is chosen on."""
    rows = []
    for name in VALIDATION_CLIPS:
        for fps in fps_values:
            obs, truth, refined = refined_clip(name, fps, TrajoptSettings())
            body = refined.motion.body
            names = [str(n) for n in truth["joint_names"]]
            true_com = kin.center_of_mass_from_points(body, truth["joints_world"], names)
            implied = implied_vertical_force(true_com, body.mass, fps)
            given = truth_scores(refined.motion, refined.motion.qpos, truth)
            for weight in weights:
                settings_trajopt = TrajoptSettings(force_rate=weight)
                start = time.perf_counter()
                result = run_trajopt(body, refined.motion.qpos, obs.fps, refined.contacts, settings_trajopt)
                seconds = time.perf_counter() - start
                scores = truth_scores(refined.motion, result.qpos, truth)
                rows.append(dict(clip=name.split("/")[-1], fps=fps, force_rate=weight, seconds=seconds,
                                 global_mpjpe_mm=scores["global_mpjpe_mm"], skate_percent=scores["skate_percent"],
                                 **{k: scores[k] for k in ALIGNED_KEYS},
                                 **{f"input_{k}": given[k] for k in ("global_mpjpe_mm", "skate_percent") + ALIGNED_KEYS},
                                 **force_check(result.grf, result.converged, implied, body.mass)))
                r = rows[-1]
                print(f"validation {r['clip']} {fps:.0f} fps force_rate {weight:g}: {seconds:.1f} s, global "
                      f"{r['global_mpjpe_mm']:.1f} mm, skate {r['skate_percent']:.1f}%, solved max "
                      f"{r['solved_max_percent_bw']:.0f}% BW / implied {r['implied_max_percent_bw']:.0f}% = "
                      f"{r['ratio']:.2f}, alternation {r['alternation_percent_bw']:.0f}% BW, converged "
                      f"{r['converged_fraction']:.2f}; root-relative / Procrustes {r['mpjpe_root_mm']:.1f} / "
                      f"{r['mpjpe_procrustes_mm']:.1f} mm (input {r['input_mpjpe_root_mm']:.1f} / "
                      f"{r['input_mpjpe_procrustes_mm']:.1f}), floating {r['floating_percent']:.1f}%", flush=True)
    return rows


# Flights in the labels on validation clips (subjects 1, 2, 5, 7): jumps, a run, jetes, walks, a scoop; the
# flight_support threshold of trajopt.stage is chosen on these.
FLIGHT_CLIPS = ("cmu_iclone_cc3_retarget/001_01.bvh", "cmu_iclone_cc3_retarget/002_03.bvh",
                "cmu_iclone_cc3_retarget/002_04.bvh", "cmu_iclone_cc3_retarget/002_06.bvh",
                "cmu_iclone_cc3_retarget/005_05.bvh", "cmu_iclone_cc3_retarget/005_07.bvh",
                "cmu_iclone_cc3_retarget/005_16.bvh", "cmu_iclone_cc3_retarget/002_01.bvh",
                "cmu_iclone_cc3_retarget/007_04.bvh")


def flights(fps_values: list[float]) -> list[dict]:
    """Every whole-body flight (no point in contact) of the contact labels trajopt receives (the B.4 relabelled
    centred-network flags, short runs merged as run_trajopt merges them) on FLIGHT_CLIPS, seed 0: its frames, the
    support its input COM needs (phases.flight_support, body weights), how far its lowest point strays, and the
    share of its frames in which the true motion has a point in contact by the true labels (1: a false flight)."""
    from physmocap.contacts.flights import flight_support
    from physmocap.trajopt.phases import clean_flags
    from physmocap.trajopt.reduced import reduced_motion

    rows = []
    for name in FLIGHT_CLIPS:
        for fps in fps_values:
            s = TrajoptSettings()
            _, truth, refined = refined_clip(name, fps, s)
            red = reduced_motion(refined.motion.body, refined.motion.qpos, fps)
            min_frames = max(1, int(np.ceil(s.min_phase_seconds * fps - 1e-9)))
            flags = np.stack([clean_flags(refined.contacts[:, i], min_frames) for i in range(4)], axis=1)
            names = [str(n) for n in truth["joint_names"]]
            sites = truth["joints_world"][:, [names.index(n) for n in CONTACT_POINTS]]
            true_contact = contact_labels(sites, fps).any(axis=1)
            edges = np.flatnonzero(np.diff(np.concatenate([[1], flags.any(axis=1).astype(int), [1]])))
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                heights = red.feet[a:b, :, 2].mean(axis=0)
                lowest = int(np.argmin(heights))
                xy = red.feet[a:b, lowest, :2]
                rows.append(dict(clip=name.split("/")[-1], fps=fps, start=int(a), frames=int(b - a),
                                 support=flight_support(red.com[:, 2], red.times, int(a), int(b), s.gravity),
                                 lowest_height_m=float(heights[lowest]),
                                 lowest_drift_m=float(np.linalg.norm(xy - np.median(xy, axis=0), axis=1).max()),
                                 true_contact_share=float(true_contact[a:b].mean())))
                r = rows[-1]
                print(f"flight {r['clip']} {fps:.0f} fps frames {a}-{b - 1}: support {r['support']:.2f} BW, lowest "
                      f"point {100 * r['lowest_height_m']:.0f} cm up, strays {100 * r['lowest_drift_m']:.0f} cm, "
                      f"true contact in {100 * r['true_contact_share']:.0f}% of its frames", flush=True)
    return rows


def videos(run_folders: list[str]) -> list[dict]:
    """Trajopt on the B.4-refined motion of each run folder (`physmocap capture VIDEO --physics physcap` or
    `trajopt` leaves it in cache/refined.npz): the largest solved net vertical force against the largest the
    refined motion implies (implied_vertical_force), the alternation, the frames above 400% of body weight, the
    converged share, the whole-body flights relabelled as supported, and the CPU seconds of this process and its
    workers."""
    from physmocap.motion import Observations
    from physmocap.stages import RefinedMotion

    rows = []
    for folder in map(Path, run_folders):
        with np.load(folder / "cache" / "refined.npz") as arrays:
            refined = RefinedMotion.from_arrays(arrays)
        obs = Observations.load(folder / "cache" / "observations.npz")
        body, qpos = refined.motion.body, refined.motion.qpos
        implied = implied_vertical_force(kin.center_of_mass(body, kin.forward_kinematics(body, qpos)), body.mass,
                                         obs.fps)
        cpu, wall = cpu_seconds(), time.perf_counter()
        result = run_trajopt(body, qpos, obs.fps, refined.contacts, TrajoptSettings(), valid=obs.valid)
        cpu, wall = cpu_seconds() - cpu, time.perf_counter() - wall
        weight = body.mass * metrics.GRAVITY
        fz = result.grf[..., 2].sum(axis=1)
        rows.append(dict(video=folder.name, fps=obs.fps, frames=len(qpos), cpu_seconds=cpu, wall_seconds=wall,
                         window_iterations=[sum(st.iterations for st in w.stages) for w in result.windows],
                         frames_over_4bw=int((fz > 4 * weight).sum()),
                         relabelled_flight_frames=int((result.contacts.any(axis=1)
                                                       & ~refined.contacts.any(axis=1) & obs.valid).sum()),
                         **force_check(result.grf, result.converged, implied, body.mass)))
        r = rows[-1]
        print(f"video {r['video']} {r['fps']:.3g} fps, {r['frames']} frames: solved {r['solved_max_percent_bw']:.0f}"
              f" / implied {r['implied_max_percent_bw']:.0f}% BW = {r['ratio']:.2f} (implied over the converged frames "
              f"{r['implied_converged_max_percent_bw']:.0f}% BW: {r['ratio_converged']:.2f}), alternation "
              f"{r['alternation_percent_bw']:.0f}% BW, frames > 400% BW {r['frames_over_4bw']}, converged "
              f"{100 * r['converged_fraction']:.0f}%, flight frames given a support {r['relabelled_flight_frames']}, "
              f"CPU {cpu:.1f} s (workers included), wall {wall:.1f} s, IPOPT iterations per window "
              f"{r['window_iterations']}", flush=True)
    return rows


def scaling(settings_trajopt: TrajoptSettings, repeats: int) -> list[dict]:
    obs, truth, settings = observe(SCALING_CLIP, 0, max(SCALING_SECONDS) + 0.5)
    motion = fit_motion(obs, settings)
    contacts, _, _ = predict_contacts(obs, "centred")
    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings_trajopt)
    out = []
    for seconds in SCALING_SECONDS:
        n = int(round(seconds * obs.fps))
        times, result = [], None
        for _ in range(repeats):
            start = time.perf_counter()
            result = run_trajopt(refined.motion.body, refined.motion.qpos[:n], obs.fps, refined.contacts[:n],
                                 settings_trajopt)
            times.append(time.perf_counter() - start)
        out.append(dict(seconds=seconds, frames=n, wall_seconds=statistics.median(times), runs=times,
                        windows=len(result.windows), converged_fraction=float(result.converged.mean()),
                        largest_program_variables=max(w.variables for w in result.windows),
                        largest_program_constraints=max(w.constraints for w in result.windows),
                        ipopt_seconds=sum(s.seconds for w in result.windows for s in w.stages),
                        build_seconds=sum(w.build_seconds for w in result.windows)))
        print(f"scaling {seconds:4.1f} s: {out[-1]['wall_seconds']:.1f} s wall, {out[-1]['windows']} window(s), "
              f"converged {out[-1]['converged_fraction']:.2f}", flush=True)
    return out


def loop_indices(frames: int, total: int) -> np.ndarray:
    """(total,) frame indices that play a clip of `frames` forwards, backwards, forwards...: positions stay
    continuous at the turns, and a motion played backwards has the same accelerations (and so forces)."""
    period = 2 * (frames - 1)
    k = np.arange(total) % period
    return np.where(k < frames, k, period - k)


def cpu_seconds() -> float:
    """CPU seconds of this process and of its finished children (the worker processes of parallel windows)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def long_scaling(lengths: list[float], settings_trajopt: TrajoptSettings) -> list[dict]:
    """Time against clip length up to minutes: the B.4-refined motion of LONG_CLIP (a dance) looped by
    `loop_indices` to each length, run_trajopt alone; wall and CPU seconds (this process), the load average
    before and after, and every window's frames, iterations, seconds and restarts; with
    settings_trajopt.parallel_windows the CPU seconds include the worker processes'."""
    obs, truth, settings = observe(LONG_CLIP, 0, 10.0)
    motion = fit_motion(obs, settings)
    contacts, _, _ = predict_contacts(obs, "centred")
    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings_trajopt)
    out = []
    for seconds in lengths:
        idx = loop_indices(len(refined.motion.qpos), int(round(seconds * obs.fps)))
        load_before = os.getloadavg()[0]
        wall, cpu = time.perf_counter(), cpu_seconds()
        result = run_trajopt(refined.motion.body, refined.motion.qpos[idx], obs.fps, refined.contacts[idx],
                             settings_trajopt)
        wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
        windows = [dict(frames=w.stop - w.start + 1, kept=w.keep - w.start, seconds=w.seconds,
                        build_seconds=w.build_seconds, restarted=w.restarted, converged=w.converged,
                        contact_switches=int(np.abs(np.diff(result.contacts[w.start:w.stop + 1].astype(int),
                                                            axis=0)).sum()),
                        iterations={st.name: st.iterations for st in w.stages},
                        ipopt_seconds=sum(st.seconds for st in w.stages), variables=w.variables)
                   for w in result.windows]
        out.append(dict(seconds=seconds, frames=len(idx), wall_seconds=wall, cpu_seconds=cpu,
                        parallel_windows=settings_trajopt.parallel_windows,
                        load_before=load_before, load_after=os.getloadavg()[0], windows=windows,
                        ik_seconds=result.ik_seconds, converged_fraction=float(result.converged.mean())))
        r = out[-1]
        print(f"long {seconds:5.0f} s: wall {wall:6.1f} s ({wall / seconds:.2f} s/s), CPU {cpu:6.1f} s "
              f"({cpu / seconds:.2f} s/s), load {load_before:.1f}-{r['load_after']:.1f}, {len(windows)} windows, "
              f"iterations/window {np.mean([sum(w['iterations'].values()) for w in windows]):.0f}, build "
              f"{sum(w['build_seconds'] for w in windows):.1f} s, "
              f"IPOPT {sum(w['ipopt_seconds'] for w in windows):.1f} s, "
              f"IK {result.ik_seconds:.1f} s, restarts {sum(w['restarted'] for w in windows)}, converged "
              f"{r['converged_fraction']:.2f}", flush=True)
    return out


def contact_slip(result) -> float:
    """The largest move (m) of a heel or toe between two consecutive converged frames in which it is in contact:
    zero when no contact slips, junctions between windows included."""
    both = result.contacts[1:] & result.contacts[:-1] & (result.converged[1:] & result.converged[:-1])[:, None]
    moves = np.linalg.norm(np.diff(result.feet, axis=0), axis=-1)
    return float(moves[both].max()) if both.any() else 0.0


def compare_parallel(lengths: list[float], repeats: int) -> list[dict]:
    """Windows one after another against two at a time (trajopt.parallel_windows) on the looped dance of
    `long_scaling`, the runs interleaved (off, on, off, on, ...) so that both see the same machine load: median
    wall and CPU seconds (workers included), the largest difference of the motion's joints and of the optimised
    COM between the two, and the converged share of each."""
    obs, truth, settings = observe(LONG_CLIP, 0, 10.0)
    motion = fit_motion(obs, settings)
    contacts, _, _ = predict_contacts(obs, "centred")
    refined = refine_kinematics(obs, motion, contacts, settings.fit, TrajoptSettings())
    body = refined.motion.body
    out = []
    for seconds in lengths:
        idx = loop_indices(len(refined.motion.qpos), int(round(seconds * obs.fps)))
        runs = {False: [], True: []}
        results = {}
        for _ in range(repeats):
            for parallel in (False, True):
                wall, cpu = time.perf_counter(), cpu_seconds()
                results[parallel] = run_trajopt(body, refined.motion.qpos[idx], obs.fps, refined.contacts[idx],
                                                TrajoptSettings(parallel_windows=parallel))
                runs[parallel].append((time.perf_counter() - wall, cpu_seconds() - cpu, os.getloadavg()[0]))
        joints = [kin.forward_kinematics(body, results[p].qpos).points for p in (False, True)]
        row = dict(seconds=seconds, windows=len(results[False].windows), runs={str(k): v for k, v in runs.items()},
                   joint_difference_max_m=float(np.linalg.norm(joints[0] - joints[1], axis=-1).max()),
                   com_difference_max_m=float(np.nanmax(np.linalg.norm(results[False].com - results[True].com,
                                                                        axis=-1))),
                   converged={str(k): float(v.converged.mean()) for k, v in results.items()},
                   slip_max_m={str(k): contact_slip(v) for k, v in results.items()})
        for parallel in (False, True):
            row[f"{'parallel' if parallel else 'sequential'}_wall_seconds"] = statistics.median(
                r[0] for r in runs[parallel])
            row[f"{'parallel' if parallel else 'sequential'}_cpu_seconds"] = statistics.median(
                r[1] for r in runs[parallel])
        out.append(row)
        print(f"compare {seconds:.0f} s, {row['windows']} windows: wall {row['sequential_wall_seconds']:.1f} s "
              f"sequential, {row['parallel_wall_seconds']:.1f} s two at a time "
              f"({row['sequential_wall_seconds'] / row['parallel_wall_seconds']:.2f}x); CPU "
              f"{row['sequential_cpu_seconds']:.1f} / {row['parallel_cpu_seconds']:.1f} s; joints differ by at most "
              f"{1000 * row['joint_difference_max_m']:.0f} mm, COM {1000 * row['com_difference_max_m']:.0f} mm; "
              f"converged {row['converged']}; largest slip of a contact between frames (m) {row['slip_max_m']}; "
              f"load {[round(r[2], 1) for p in runs.values() for r in p]}",
              flush=True)
    return out


def framerate(validation: bool) -> list[dict]:
    """Issue 17's frame-rate target for trajopt: bench_physics_limits' framerate cases (a clip's 60 fps offline fit
    refined by B.4, that motion resampled to 10, 24, 30 and 120 fps: the same motion), trajopt at each rate with its
    defaults; converged share, largest contact force, and the joints against the 60 fps run at common times from
    0.5 s on (mean, 95th percentile, root-relative, and both over frames converged at both rates)."""
    import bench_physics_limits as limits

    clips = (limits.VALIDATION_CLIPS if validation else limits.CLIPS)[:2]
    rows = []
    for name in clips:
        case = limits.build_case(name, 0, 60.0, online=False)
        refined = case["refined"]
        body = refined.motion.body
        runs = {}
        for fps in limits.RATES:
            qpos, source = limits.resample_motion(body, refined.motion.qpos, 60.0, fps)
            cpu = cpu_seconds()
            result = run_trajopt(body, qpos, fps, refined.contacts[source], TrajoptSettings())
            runs[fps] = dict(result=result, cpu=cpu_seconds() - cpu, times=np.arange(len(qpos)) / fps,
                             points=kin.forward_kinematics(body, result.qpos).points)
        reference = runs[60.0]
        for fps in limits.RATES:
            run, result = runs[fps], runs[fps]["result"]
            index, match, distance, relative = limits.against_reference(run, reference)
            both = result.converged[index] & reference["result"].converged[match]
            weight = body.mass * metrics.GRAVITY
            rows.append(dict(clip=name.split("/")[-1], fps=fps, frames=len(result.qpos), cpu_seconds=run["cpu"],
                             finite=bool(np.isfinite(result.qpos).all() and np.isfinite(result.grf).all()),
                             converged_percent=100 * float(result.converged.mean()),
                             largest_force_bw=float(np.linalg.norm(result.grf.sum(axis=1), axis=-1).max() / weight),
                             vs_60_mm=1000 * float(distance.mean()),
                             vs_60_p95_mm=1000 * float(np.percentile(distance, 95)),
                             root_relative_vs_60_mm=1000 * float(relative.mean()),
                             both_converged_percent=100 * float(both.mean()),
                             vs_60_both_converged_mm=1000 * float(distance[both].mean()) if both.any() else None))
            r = rows[-1]
            print(f"framerate {r['clip']} {fps:.0f} fps: converged {r['converged_percent']:.0f}%, largest force "
                  f"{r['largest_force_bw']:.2f} BW, vs 60 fps {r['vs_60_mm']:.1f} mm (p95 {r['vs_60_p95_mm']:.1f}, "
                  f"root-relative {r['root_relative_vs_60_mm']:.1f}; {r['vs_60_both_converged_mm']} mm over the "
                  f"{r['both_converged_percent']:.0f}% converged at both), CPU {r['cpu_seconds']:.1f} s", flush=True)
    return rows


def one_window(seconds: float, first: int, last: int) -> dict:
    """Frames first..last of the looped dance of `long_scaling` (looped to `seconds`) as one window from a free
    start (its start velocity the input's), solved as run_trajopt solves a window: every IPOPT run's status,
    iterations and CPU seconds. The windows that cost most on long clips can be studied alone this way."""
    from physmocap.contacts.flights import held_flights_in_runs
    from physmocap.trajopt.formulation import Window
    from physmocap.trajopt.phases import clean_flags, contact_phases, split_drifting
    from physmocap.trajopt.reduced import boundary_velocity, reduced_motion
    from physmocap.trajopt.solve import solve_window

    obs, truth, settings = observe(LONG_CLIP, 0, 10.0)
    motion = fit_motion(obs, settings)
    contacts, _, _ = predict_contacts(obs, "centred")
    s = TrajoptSettings()
    refined = refine_kinematics(obs, motion, contacts, settings.fit, s)
    idx = loop_indices(len(refined.motion.qpos), int(round(seconds * obs.fps)))
    red = reduced_motion(refined.motion.body, refined.motion.qpos[idx], obs.fps)
    min_frames = max(1, int(np.ceil(s.min_phase_seconds * obs.fps - 1e-9)))
    flags = np.stack([clean_flags(refined.contacts[idx, i], min_frames) for i in range(4)], axis=1)
    flags = held_flights_in_runs(flags, np.ones(len(idx), bool), red.com, red.feet, red.times, s.gravity,
                                 np.repeat(red.foot_length, 2), "trajopt")[0]  # as run_trajopt relabels them
    flags = split_drifting(flags, red.feet[..., :2], s.contact_drift, min_frames)
    part = red.frames(slice(first, last + 1))
    window = Window(part, [contact_phases(flags[first:last + 1, i], part.times) for i in range(4)],
                    start_velocity=boundary_velocity(red.com[first:], obs.fps, s.boundary_seconds, end=False))
    cpu = time.process_time()
    result = solve_window(window, s)
    cpu = time.process_time() - cpu
    print(f"window {first}-{last} of the {seconds:.0f} s loop: CPU {cpu:.1f} s, " + "; ".join(
        f"{st.name} {st.status} {st.iterations} iterations" for st in result.stages), flush=True)
    return dict(cpu_seconds=cpu, stages=[dataclasses.asdict(st) for st in result.stages])


def scaling_fit(rows: list[dict]) -> dict:
    """The growth of solve time with clip length from the scaling rows: the least-squares line through
    (log length, log median wall time), t = a L^b (exponent b: 1 linear, 2 quadratic), and the cost per second of
    clip at each length with the ratio of the largest to the smallest. Marginal slopes between consecutive lengths
    (differences of two noisy times) would amplify the timing noise."""
    length = np.array([r["seconds"] for r in rows])
    wall = np.array([r["wall_seconds"] for r in rows])
    b, log_a = np.polyfit(np.log(length), np.log(wall), 1)
    per_second = wall / length
    return dict(exponent=float(b), coefficient_seconds=float(np.exp(log_a)),
                seconds_per_clip_second=[float(v) for v in per_second],
                per_second_ratio=float(per_second.max() / per_second.min()))


def summarise(cases: list[dict]) -> dict:
    summary = {}
    for method in METHODS:
        summary[method] = {k: float(np.nanmean([c["rows"][method][k] for c in cases])) for k in KEYS}
    pieces = [p for c in cases for p in c["pieces"]]
    summary["convergence"] = {} if not pieces else dict(
        pieces=len(pieces), converged=int(sum(p["converged"] for p in pieces)),
        share=float(np.mean([p["converged"] for p in pieces])) if pieces else float("nan"),
        piece_seconds_median=float(np.median([p["seconds"] for p in pieces])) if pieces else float("nan"),
        whole_clips_converged=float(np.mean([c["converged_fraction"] == 1.0 for c in cases])),
        whole_clips_converged_true_floor=float(np.mean([c["converged_fraction_true_floor"] == 1.0 for c in cases])))
    flights = [c["true_flight"] for c in cases if c["true_flight"]["frames"]]
    summary["truth_feet"] = {k: float(np.mean([c["true_flight"][k] for c in cases]))
                             for k in ("floating_percent", "penetration_percent", "skate_percent")}
    summary["true_flight"] = dict(
        cases=len(flights), frames=int(sum(f["frames"] for f in flights)),
        touching_frames=int(sum(f["touching_frames"] for f in flights)),
        **{key: float(np.nanmean([f[key] for f in flights])) if flights else float("nan")
           for key in ("ballistic_percent_bw", "trajopt_touching_percent_bw", "trajopt_airborne_percent_bw")})
    return summary


def flight_forces(flight: dict) -> str:
    """'n: 0, 41t, ...' for the per-case table: trajopt's force in each true flight frame, t where it touches."""
    forces = [f"{f:.0f}{'t' if t else ''}" for f, t in zip(flight["flight_trajopt_percent_bw"],
                                                          flight["flight_touching"], strict=True)]
    return f"{flight['frames']}" + (": " + ", ".join(forces) if forces else "")


def method_table(summary: dict) -> str:
    """The accuracy rows: one per method, the means over the cases."""
    lines = ["| method | global MPJPE mm | first-frame aligned mm | root-rel. MPJPE mm | floating % | penetration % "
             "| skate % | GRF mean % BW | GRF max % BW | ballistic GRF % BW | e_smooth mm |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for method in METHODS:
        lines.append(f"| {method} | " + " | ".join(f"{summary[method][k]:.1f}" for k in KEYS) + " |")
    return "\n".join(lines)


def markdown(out: dict) -> str:
    s = out["summary"]
    lines = ["# Trajectory optimisation (Rempe et al. 2020) on the synthetic set", "",
             f"{out['machine']}, revision {out['revision']}. {len(out['cases'])} cases (clips x seeds), "
             f"{SECONDS:.0f} s each at most, {FPS:.0f} fps; contacts from the centred network; floor metrics "
             "against the true floor and true contacts. Rows 'true floor': the true floor given to the kinematic "
             "stage and kept (the paper's table 2 protocol); the others estimate it (its table E3).", "",
             method_table(s)]
    c, flight = s["convergence"], s["true_flight"]
    lines += ["", f"Ballistic GRF: median force over the frames in flight by the true labels, averaged over the "
              f"{flight['cases']} cases that have any ({flight['frames']} frames in all). The true motion itself "
              f"implies {flight['ballistic_percent_bw']:.0f}% of body weight there by the same metric (its centre "
              "of mass from its joints and the body model's segment masses). Not every label flight is a flight: "
              f"in {flight['touching_frames']} of the {flight['frames']} frames a heel or toe is within "
              f"{100 * TOUCHING:.0f} cm of the floor, in the air by the labels only because it moves faster than "
              f"{LabelSettings().contact_max_speed:.1f} m/s (a rolling push-off). Trajopt's median there: "
              f"{flight['trajopt_touching_percent_bw']:.0f}% BW; in the other flight frames: {flight['trajopt_airborne_percent_bw']:.0f}% BW (means over the "
              "cases that have such frames).", "",
              "The motion capture's own feet against its labels, by the same metrics: floating "
              f"{s['truth_feet']['floating_percent']:.1f}%, penetration {s['truth_feet']['penetration_percent']:.2f}%, "
              f"skate {s['truth_feet']['skate_percent']:.1f}%.", "",
              f"Converged: {c['converged']} of {c['pieces']} two-second clips ({100 * c['share']:.1f}%; the paper: "
              f"94.9%), median {c['piece_seconds_median']:.1f} s per 2 s clip; whole {SECONDS:.0f} s clips fully "
              f"converged: {100 * c['whole_clips_converged']:.0f}% (with the true floor: "
              f"{100 * c['whole_clips_converged_true_floor']:.0f}%).", "",
              f"Time against clip length (CMU 001_01, run_trajopt alone, median of {len(out['scaling'][0]['runs'])} "
              "run(s) each):", "",
              "| clip length s | frames | wall s | windows | converged | largest window program (variables / "
              "constraints) | IPOPT s | build s |", "|---|---|---|---|---|---|---|---|"]
    for r in out["scaling"]:
        lines.append(f"| {r['seconds']:.0f} | {r['frames']} | {r['wall_seconds']:.1f} | {r['windows']} | "
                     f"{100 * r['converged_fraction']:.0f}% | {r['largest_program_variables']} / "
                     f"{r['largest_program_constraints']} | {r['ipopt_seconds']:.1f} | {r['build_seconds']:.1f} |")
    fit = out["scaling_fit"]
    lines += ["", f"Least-squares fit t = a L^b over the lengths: b = {fit['exponent']:.2f} (1: linear), a = "
              f"{fit['coefficient_seconds']:.2f} s; seconds per second of clip "
              + " / ".join(f"{v:.2f}" for v in fit["seconds_per_clip_second"])
              + f" (largest / smallest {fit['per_second_ratio']:.2f})."]
    lines += ["", "Per case (last column: trajopt's net force in each frame in flight by the true labels, % BW, "
              "t where a heel or toe touches):", "", "| clip | seed | frames | trajopt s | converged frames | global "
              "MPJPE kin / refined / trajopt mm | 2 s pieces converged | true flight frames: force % BW |",
              "|---|---|---|---|---|---|---|---|"]
    for case in out["cases"]:
        g = [case["rows"][m]["global_mpjpe_mm"] for m in ("kinematic offline", "kinematic refined (B.4)", "trajopt")]
        done = sum(p["converged"] for p in case["pieces"])
        lines.append(f"| {case['clip']} | {case['seed']} | {case['frames']} | {case['trajopt_seconds']:.1f} | "
                     f"{100 * case['converged_fraction']:.0f}% | {g[0]:.0f} / {g[1]:.0f} / {g[2]:.0f} | "
                     f"{done}/{len(case['pieces'])} | {flight_forces(case['true_flight'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="three clips, one seed, scaling to 10 s")
    parser.add_argument("--repeats", type=int, default=1, help="runs per scaling length (median reported)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="camera and noise seeds per clip")
    parser.add_argument("--scaling-only", action="store_true",
                        help="measure only the time against clip length, keeping the cases of the --json file")
    parser.add_argument("--json", default=str(RESULTS / "trajopt.json"))
    parser.add_argument("--clips", nargs="+", help="these clips of the set only (file names, e.g. 131_01.bvh)")
    parser.add_argument("--set", choices=tuple(CLIP_SETS), default="issue3",
                        help="the synthetic clips (bench_synthetic.py --set): issue3, subjects 6 and 131; issue18, "
                             "subjects 9 and 94")
    parser.add_argument("--accuracy-only", action="store_true",
                        help="only the accuracy rows of the cases (no 2 s pieces, no scaling); writes --json")
    parser.add_argument("--long", type=float, nargs="+", metavar="SECONDS",
                        help="only the time against clip length on a looped dance, at these lengths (s)")
    parser.add_argument("--window", type=float, nargs=3, metavar=("SECONDS", "FIRST", "LAST"),
                        help="only one window (frames FIRST..LAST) of the looped dance at SECONDS, from a free start")
    parser.add_argument("--videos", nargs="+", metavar="RUN_FOLDER",
                        help="only trajopt on these capture run folders' refined motion: forces against implied")
    parser.add_argument("--flights", action="store_true",
                        help="only the whole-body flights of the labels on validation clips, at 24 and 30 fps")
    parser.add_argument("--validation", type=float, nargs="+", metavar="WEIGHT",
                        help="only the validation clips, trajopt with each force_rate weight given")
    parser.add_argument("--compare-parallel", type=float, nargs="+", metavar="SECONDS",
                        help="only windows one after another against two at a time on the looped dance, "
                             "interleaved --repeats times")
    parser.add_argument("--framerate", choices=("test", "validation"),
                        help="only the same motion at 10, 24, 30, 60 and 120 fps (bench_physics_limits' framerate cases "
                             "of that set): joints against the 60 fps run")
    parser.add_argument("--parallel-windows", choices=("on", "off"),
                        help="trajopt.parallel_windows for the accuracy rows and --long (default: the setting's)")
    args = parser.parse_args(argv)
    chosen = (TrajoptSettings() if args.parallel_windows is None
              else TrajoptSettings(parallel_windows=args.parallel_windows == "on"))
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    if args.long:
        rows = long_scaling(args.long, chosen)
        fit = scaling_fit([dict(seconds=r["seconds"], wall_seconds=r["cpu_seconds"]) for r in rows])
        print(f"CPU seconds against length: t = {fit['coefficient_seconds']:.2f} L^{fit['exponent']:.2f}")
        write_text(RESULTS / f"trajopt_long{'_parallel' if chosen.parallel_windows else ''}.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows, cpu_fit=fit), indent=2, default=float))
        return dict(rows=rows)
    if args.compare_parallel:
        rows = compare_parallel(args.compare_parallel, args.repeats)
        write_text(RESULTS / "trajopt_parallel.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows), indent=2, default=float))
        return dict(rows=rows)
    if args.framerate:
        rows = framerate(args.framerate == "validation")
        write_text(RESULTS / f"trajopt_framerate_{args.framerate}.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows), indent=2, default=float))
        return dict(rows=rows)
    if args.window:
        return one_window(args.window[0], int(args.window[1]), int(args.window[2]))
    if args.videos:
        rows = videos(args.videos)
        write_text(RESULTS / "trajopt_videos.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows), indent=2, default=float))
        return dict(rows=rows)
    if args.flights:
        rows = flights([24.0, 30.0])
        write_text(RESULTS / "trajopt_flights.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows), indent=2, default=float))
        return dict(rows=rows)
    if args.validation:
        rows = validation(args.validation, [24.0, 30.0])
        RESULTS.mkdir(parents=True, exist_ok=True)
        write_text(RESULTS / "trajopt_validation.json", json.dumps(dict(
            machine=machine_description(), revision=git_revision(), rows=rows), indent=2, default=float))
        return dict(rows=rows)
    global SCALING_SECONDS
    if args.quick:
        SCALING_SECONDS = SCALING_SECONDS[:3]
    settings = chosen
    if args.scaling_only:
        out = json.loads(Path(args.json).read_text())
        out["scaling"] = scaling(settings, args.repeats)
        out["scaling_fit"] = scaling_fit(out["scaling"])
        Path(args.json).write_text(json.dumps(out, indent=2, default=float))
        Path(args.json).with_suffix(".md").write_text(markdown(out))
        return out
    clip_set = CLIP_SETS[args.set]
    clips = clip_set[:3] if args.quick else clip_set
    if args.clips:
        clips = tuple(name for name in clip_set if name.split("/")[-1] in args.clips)
    seeds = (0,) if args.quick else tuple(args.seeds)
    cases = []
    for name in clips:
        for seed in seeds:
            case = evaluate_case(name, seed, settings, pieces=not args.accuracy_only)
            cases.append(case)
            r = case["rows"]
            kin, ref, traj = (r[m] for m in ("kinematic offline", "kinematic refined (B.4)", "trajopt"))
            print(f"{case['clip']:>11} seed {seed}: trajopt {case['trajopt_seconds']:5.1f} s, converged "
                  f"{case['converged_fraction']:.2f}, pieces {sum(p['converged'] for p in case['pieces'])}/"
                  f"{len(case['pieces'])} | global mm kin {kin['global_mpjpe_mm']:.0f} refined "
                  f"{ref['global_mpjpe_mm']:.0f} trajopt {traj['global_mpjpe_mm']:.0f} | GRF mean "
                  f"{traj['grf_mean_percent_bw']:.0f}% max {traj['grf_max_percent_bw']:.0f}%", flush=True)
    out = dict(machine=machine_description(), revision=git_revision(), settings=dataclasses.asdict(settings),
               fps=FPS, seconds=SECONDS, clips=list(clips), seeds=list(seeds), cases=cases)
    out["summary"] = summarise(cases)
    if args.accuracy_only:
        write_text(args.json, json.dumps(out, indent=2, default=float))
        print(method_table(out["summary"]))
        return out
    out["scaling"] = scaling(settings, args.repeats)
    out["scaling_fit"] = scaling_fit(out["scaling"])
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2, default=float))
    Path(args.json).with_suffix(".md").write_text(markdown(out))
    print(markdown(out))
    return out


if __name__ == "__main__":
    main()
