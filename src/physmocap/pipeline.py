"""Wiring of the stages into a run folder with cached outputs.

    OUT/
      cache/observations.npz  detection (skipped on re-run while the video and detect settings are unchanged)
      cache/kinematics.npz    calibrated skeleton, camera, floor and fitted motion
      cache/physics.npz       the PhysCap motion, or cache/trajopt.npz: the refined kinematics and trajopt motion
      result.npz              the contract of DESIGN.md
      motion.bvh              Mixamo-named skeleton, Y up, metres
      overlay.mp4             the fit drawn on the input video (H.264)
      summary.json            frames, valid frames, time per stage, reprojection error

Every file is written atomically, so an interrupted run leaves only complete files and resumes from them.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .body.model import SkeletonLengths, build_body_model
from .camera import Camera, Floor
from .config import Settings
from .errors import InputError
from .io.atomic import save_npz, write_text
from .kinematics.calibration import Calibration
from .kinematics.stage import KinematicMotion, fit_motion
from .motion import Observations
from .result import RESULT_POINTS, build_result, save_result

log = logging.getLogger("physmocap")

ProgressFactory = Callable[[str, int], Callable[[int, int], None]]


def _digest(*parts) -> str:
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _file_fingerprint(path: Path) -> dict:
    stat = path.stat()
    return {"path": str(path.resolve()), "size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


@dataclass
class RunSummary:
    """What a run did; also written as summary.json."""

    input: str
    output_dir: str
    frames: int
    valid_frames: int
    invalid_frames: dict[str, list[str]]
    fps: float
    online: bool
    stage_seconds: dict[str, float]
    cached_stages: list[str]
    median_reprojection_error_px: float
    median_reprojection_error_percent_of_height: float
    skeleton_scale_replaced: list[str]
    physics: str
    physics_fallback_frames: list[str]
    foot_swap_frames: list[str]  # frames whose left and right feet the detector swapped, fitted the other way round
    foot_swap_frame_count: int  # how many (offline: found over the whole clip; online: per frame from the past)
    physics_report: dict = field(default_factory=dict)  # B.4 refinement; trajopt: summary line, window reports
    median_reprojection_error_final_px: float = float("nan")  # of the final (physics) motion
    physics_strayed_frames: list[str] = field(default_factory=list)  # final joints farther than
    # physics.stray_distance on average from the kinematic motion's
    files: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)


def _frame_ranges(frames: np.ndarray) -> list[str]:
    """[3, 4, 5, 9] -> ['3-5', '9']"""
    out, start = [], None
    for i, f in enumerate(frames):
        if start is None:
            start = f
        if i + 1 == len(frames) or frames[i + 1] != f + 1:
            out.append(str(start) if start == f else f"{start}-{f}")
            start = None
    return out


def detect_stage(video: Path, out_dir: Path, settings: Settings,
                 progress: ProgressFactory | None = None) -> tuple[Observations, bool]:
    """Observations of the video, from the cache when the video and detect settings are unchanged."""
    from .detect.mediapipe_pose import detect_video

    cache, key_file, key = _detection_cache(video, out_dir, settings)
    was_cached = _detections_cached(video, out_dir, settings)
    if was_cached:
        obs = Observations.load(cache)
    else:
        bar = progress("detect", 0) if progress else None
        obs = detect_video(video, person_box=settings.detect.person_box, max_width=settings.detect.max_width,
                           progress=bar)
        obs.save(cache)
        write_text(key_file, key)
    _check_truncation(video, obs, settings)
    return obs, was_cached


def _detection_cache(video: Path, out_dir: Path, settings: Settings) -> tuple[Path, Path, str]:
    detect_settings = asdict(settings.detect)
    detect_settings.pop("accept_truncated")
    key = _digest("detect", 1, _file_fingerprint(video), detect_settings)
    return out_dir / "cache" / "observations.npz", out_dir / "cache" / "observations.key", key


def _detections_cached(video: Path, out_dir: Path, settings: Settings) -> bool:
    cache, key_file, key = _detection_cache(video, out_dir, settings)
    return cache.is_file() and key_file.is_file() and key_file.read_text() == key


def _check_truncation(video: Path, obs: Observations, settings: Settings) -> None:
    from .io.video import probe_video

    announced = probe_video(video).frame_count
    if obs.num_frames < announced - max(2, 0.02 * announced) and not settings.detect.accept_truncated:
        raise InputError(f"{video}: the video is truncated: only {obs.num_frames} of the {announced} frames it "
                         "announces decode (use --accept-truncated to capture those).")


def stream_stage(video: Path, out_dir: Path, settings: Settings) -> tuple[Observations, KinematicMotion]:
    """Detection and causal fit together (live order); both outputs are cached like the separate stages'."""
    from .live import stream_capture

    # Physics runs as its own cached stage afterwards; here only what the detector and the fit produce.
    report = stream_capture(str(video), settings.replace("physics", method="none"))
    _check_truncation(video, report.observations, settings)
    cache, key_file, key = _detection_cache(video, out_dir, settings)
    report.observations.save(cache)
    write_text(key_file, key)
    _save_motion(out_dir, report.observations, settings, report.motion)
    return report.observations, report.motion


def _observations_key(obs: Observations) -> str:
    # float32, as the observations file stores them: fresh and reloaded detections give the same key
    data = obs.keypoints_2d.astype(np.float32).tobytes() + obs.landmarks_3d.astype(np.float32).tobytes()
    return _digest(hashlib.sha256(data + obs.valid.tobytes()).hexdigest(), obs.fps, obs.image_size,
                   None if obs.camera_K is None else obs.camera_K.tolist())


def kinematics_stage(obs: Observations, out_dir: Path, settings: Settings,
                     progress: ProgressFactory | None = None) -> tuple[KinematicMotion, bool]:
    """The fitted kinematic motion, from the cache when observations and settings are unchanged."""
    cache, key = _kinematics_cache(out_dir, obs, settings)
    motion = _read_cache(cache, key, _motion_from_cache)
    if motion is not None:
        return motion, True
    bar = progress("fit", obs.num_frames) if progress else None
    motion = fit_motion(obs, settings, bar)
    _save_motion(out_dir, obs, settings, motion)
    return motion, False


def _read_cache(path: Path, key: str, build: Callable):
    """build(arrays) of a stage's cache file when it exists and was written under `key`, else None: a stale,
    foreign or damaged cache file is simply recomputed."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            return build(data) if str(data["key"]) == key else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _kinematics_cache(out_dir: Path, obs: Observations, settings: Settings) -> tuple[Path, str]:
    key = _digest("kinematics", 2, _observations_key(obs), asdict(settings.body), asdict(settings.camera),
                  asdict(settings.fit), settings.online)
    return out_dir / "cache" / "kinematics.npz", key


def _save_motion(out_dir: Path, obs: Observations, settings: Settings, motion: KinematicMotion) -> None:
    cache, key = _kinematics_cache(out_dir, obs, settings)
    save_npz(cache, key=np.str_(key), **_motion_arrays(motion))


def _motion_arrays(motion: KinematicMotion) -> dict:
    """The arrays `_motion_from_cache` rebuilds a kinematic motion from."""
    return dict(qpos=motion.qpos, lengths=np.str_(json.dumps(motion.body.lengths.__dict__)),
                mass=motion.body.mass, camera_K=motion.camera.K, camera_R=motion.camera.R, camera_t=motion.camera.t,
                image_size=np.array(motion.camera.image_size), floor=motion.floor.plane,
                floor_inliers=motion.floor.inlier_fraction, reprojection_error=motion.reprojection_error,
                valid=motion.valid, seconds=motion.seconds, online=motion.online,
                landmark_scale=motion.calibration.landmark_scale, frames_used=motion.calibration.frames_used,
                replaced=np.array(motion.calibration.replaced, dtype=str),
                foot_swaps=np.zeros(len(motion.qpos), bool) if motion.foot_swaps is None else motion.foot_swaps)


def _motion_from_cache(data) -> KinematicMotion:
    lengths = SkeletonLengths(**json.loads(str(data["lengths"])))
    body = build_body_model(lengths, float(data["mass"]))
    size = data["image_size"]
    camera = Camera(data["camera_K"], data["camera_R"], data["camera_t"], (int(size[0]), int(size[1])))
    floor = Floor.from_plane(data["floor"])
    calibration = Calibration(lengths, float(data["landmark_scale"]), int(data["frames_used"]),
                              tuple(str(x) for x in data["replaced"]))
    return KinematicMotion(body, calibration, camera, Floor(floor.normal, floor.offset, float(data["floor_inliers"])),
                           data["qpos"], data["reprojection_error"], data["valid"], float(data["seconds"]),
                           bool(data["online"]), foot_swaps=data.get("foot_swaps"))


def contacts_stage(obs: Observations, settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    """Foot contacts (T, 4) and the stationary flag (T,) from the 2D keypoints, fast enough not to need a cache.

    Online: the causal network for both. Offline: the centred network's contacts, and the stationary flag of
    the 2D root-speed heuristic, which beats both networks on the hand-labelled real frames (0.93 against
    0.72 and 0.86, benchmarks/results/contacts.md)."""
    from .contacts.baselines import velocity_2d
    from .contacts.predict import predict_contacts

    if settings.online:
        contacts, stationary, _ = predict_contacts(obs, "causal")
        return contacts, stationary
    contacts, _, _ = predict_contacts(obs, "centred")
    return contacts, velocity_2d(obs.keypoints_2d, obs.valid, obs.fps)[1]


def _motion_key(motion: KinematicMotion) -> str:
    """A digest of a kinematic motion (pose, skeleton, camera): the key of the stages that start from it."""
    data = motion.qpos.tobytes() + motion.valid.tobytes() + motion.camera.R.tobytes() + motion.camera.t.tobytes()
    return _digest(hashlib.sha256(data).hexdigest(), motion.body.lengths.__dict__, motion.body.mass)


def physics_stage(obs: Observations, motion: KinematicMotion, contacts: np.ndarray, stationary: np.ndarray,
                  out_dir: Path, settings: Settings, progress: ProgressFactory | None = None):
    """The physically tracked motion (None without physics), from the cache when nothing changed. Returns it,
    whether it came from the cache, and the kinematic motion, re-expressed on the floor the physics refined
    (online, when the floor was estimated) so that both stand on z = 0."""
    from .dynamics.stage import PhysicsMotion, onto_refined_floor, run_physcap

    if settings.physics.method == "none":
        return None, False, motion
    cache = out_dir / "cache" / "physics.npz"
    key = _digest("physics", 5, _motion_key(motion),
                  hashlib.sha256(contacts.tobytes() + stationary.tobytes()).hexdigest(), asdict(settings.physics))
    physics = _read_cache(cache, key, lambda data: PhysicsMotion(
        data["qpos"], data["grf"], data["residual"], data["contacts"], data["corrected"], data["qp_failures"],
        float(data["seconds"]), None if np.isnan(data["floor_plane"]).any() else data["floor_plane"]))
    cached = physics is not None
    if not cached:
        bar = progress("physics", obs.num_frames) if progress else None
        # The online floor comes from the warm-up alone; the offline one already from every frame.
        refine_floor = settings.online and settings.camera.floor is None
        physics = run_physcap(motion.body, motion.qpos, obs.fps, contacts, stationary, settings.physics, bar,
                              refine_floor, motion.valid)
        plane = np.full(4, np.nan) if physics.floor_plane is None else physics.floor_plane
        save_npz(cache, key=np.str_(key), qpos=physics.qpos, grf=physics.grf, residual=physics.residual,
                 contacts=physics.contacts, corrected=physics.corrected, qp_failures=physics.qp_failures,
                 seconds=physics.seconds, floor_plane=plane)
    motion, physics = onto_refined_floor(motion, physics)
    return physics, cached, motion


def refine_stage(obs: Observations, motion: KinematicMotion, contacts: np.ndarray, out_dir: Path,
                 settings: Settings) -> tuple[KinematicMotion, np.ndarray, dict, bool]:
    """Rempe et al.'s three-stage kinematic refinement (B.4) of the offline fit, which trajopt and offline
    PhysCap start from, from the cache when the motion, contacts and settings are unchanged. Returns the refined
    motion (its world sits on the refitted floor), the contact flags after relabelling, the refinement's report
    (seconds, contact flags removed as floor outliers or added in false flights, the floor's plane in the camera
    frame) and whether it came from the cache."""
    from .trajopt.kinematic import refine_kinematics

    cache = out_dir / "cache" / "refined.npz"
    key = _digest("refine", 1, _motion_key(motion), hashlib.sha256(np.asarray(contacts, bool).tobytes()).hexdigest(),
                  asdict(settings.fit), asdict(settings.trajopt), settings.camera.floor)
    stored = _read_cache(cache, key, lambda data: (_motion_from_cache(data), data["refined_contacts"],
                                                   json.loads(str(data["refinement"]))))
    if stored is not None:
        return (*stored, True)
    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings.trajopt,
                                keep_floor=settings.camera.floor is not None)
    refinement = dict(seconds=refined.seconds, contacts_removed=int(refined.relabelled.sum()),
                      contacts_added=int(refined.added.sum()), floor=refined.motion.floor.plane.tolist())
    save_npz(cache, key=np.str_(key), **_motion_arrays(refined.motion), refined_contacts=refined.contacts,
             refinement=np.str_(json.dumps(refinement)))
    return refined.motion, refined.contacts, refinement, False


def trajopt_stage(obs: Observations, motion: KinematicMotion, contacts: np.ndarray, out_dir: Path,
                  settings: Settings, progress: ProgressFactory | None = None):
    """Rempe et al.'s trajectory optimisation over the whole clip from the B.4-refined motion and contacts
    (`refine_stage`), from the cache when they and the settings are unchanged. Returns the physics motion and
    whether it came from the cache. Frames whose optimisation did not converge keep the kinematic motion and are
    flagged (qp_failures > 0)."""
    from .trajopt.stage import TrajoptMotion, WindowReport, run_trajopt

    cache = out_dir / "cache" / "trajopt.npz"
    key = _digest("trajopt", 2, _motion_key(motion), hashlib.sha256(np.asarray(contacts, bool).tobytes()).hexdigest(),
                  asdict(settings.trajopt))
    arrays = ("qpos", "grf", "residual", "contacts", "converged", "corrected", "qp_failures", "com",
              "com_acceleration", "euler", "feet")
    physics = _read_cache(cache, key, lambda data: TrajoptMotion(
        **{k: data[f"trajopt_{k}"] for k in arrays},
        windows=[WindowReport.from_dict(w) for w in json.loads(str(data["trajopt_windows"]))],
        seconds=float(data["trajopt_seconds"])))
    if physics is not None:
        return physics, True
    bar = progress("trajopt", obs.num_frames) if progress else None
    physics = run_trajopt(motion.body, motion.qpos, obs.fps, contacts, settings.trajopt, bar, obs.valid)
    save_npz(cache, key=np.str_(key), trajopt_seconds=physics.seconds,
             trajopt_windows=np.str_(json.dumps([w.to_dict() for w in physics.windows])),
             **{f"trajopt_{k}": getattr(physics, k) for k in arrays})
    return physics, False


def run_capture(out_dir: str | os.PathLike, settings: Settings, *, video: str | os.PathLike | None = None,
                observations: str | os.PathLike | None = None, overlay: bool = True,
                progress: ProgressFactory | None = None) -> RunSummary:
    """Video (or observations file) -> run folder with result.npz, motion.bvh, overlay.mp4, summary.json."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    cached: list[str] = []
    video = None if video is None else Path(video)

    # Cached stages report the time they took when they ran.
    motion: KinematicMotion | None = None
    if observations is not None:
        obs = Observations.load(observations)
        source = str(observations)
    elif settings.online and not _detections_cached(video, out_dir, settings):
        # Live order: the detector and the causal fit run concurrently, frame by frame.
        obs, motion = stream_stage(video, out_dir, settings)
        source = str(video)
        seconds["detect"] = obs.seconds_per_frame * obs.num_frames
    else:
        obs, detect_cached = detect_stage(video, out_dir, settings, progress)
        source = str(video)
        seconds["detect"] = obs.seconds_per_frame * obs.num_frames
        if detect_cached:
            cached.append("detect")
    if motion is None:
        motion, kinematics_cached = kinematics_stage(obs, out_dir, settings, progress)
        if kinematics_cached:
            cached.append("kinematics")
    seconds["kinematics"] = motion.seconds

    started = time.perf_counter()
    predicted, stationary = contacts_stage(obs, settings)
    contacts = lock_feet(predicted, motion, settings)
    seconds["contacts"] = time.perf_counter() - started
    physics_report: dict = {}
    method = settings.physics.method
    if method == "trajopt" or (method == "physcap" and settings.physics.refine_offline and not settings.online):
        motion, contacts, refinement, refine_cached = refine_stage(obs, motion, contacts, out_dir, settings)
        seconds["refine"] = refinement["seconds"]
        physics_report["refinement"] = refinement
        if refine_cached:
            cached.append("refine")
    if method == "trajopt":
        physics, physics_cached = trajopt_stage(obs, motion, contacts, out_dir, settings, progress)
        physics_report.update(physics.report())
    else:
        physics, physics_cached, motion = physics_stage(obs, motion, contacts, stationary, out_dir, settings,
                                                        progress)
    if physics is not None:
        seconds["physics"] = physics.seconds
        if physics_cached:
            cached.append("physics")
    return write_outputs(out_dir, source, obs, motion, contacts, stationary, physics, settings, seconds, cached,
                         video if overlay else None, progress, predicted, physics_report)


def lock_feet(predicted: np.ndarray, motion: KinematicMotion, settings: Settings) -> np.ndarray:
    """The contacts physics uses: the predictions (auto), every low sole point (always) or none (never)."""
    from .presets import foot_lock, foot_point_heights

    return foot_lock(predicted, foot_point_heights(motion.body, motion.qpos), settings.physics.foot_lock,
                     settings.physics.contact_height)


def write_outputs(out_dir: Path, source: str, obs: Observations, motion: KinematicMotion, contacts: np.ndarray,
                  stationary: np.ndarray, physics, settings: Settings, seconds: dict[str, float], cached: list[str],
                  overlay_video: Path | None = None, progress: ProgressFactory | None = None,
                  predicted: np.ndarray | None = None, physics_report: dict | None = None) -> RunSummary:
    """result.npz, the exports (motion.bvh, motion.glb, OpenSim markers.trc, grf.mot, external_loads.xml),
    overlay.mp4 (when `overlay_video` is given), viewer.html, summary.json (with `physics_report`, the physics
    stage's own account, e.g. trajopt's solver reports) and report.html."""
    from .export import export_result
    from .io.bvh_export import write_bvh
    from .io.glb import write_glb
    from .viz.report import write_report
    from .viz.viewer import write_viewer

    started = time.perf_counter()
    result = build_result(obs, motion, seconds, settings.as_dict(), contacts, stationary, physics, predicted,
                          settings.physics.method)
    files = {"result": str(out_dir / "result.npz"), "bvh": str(out_dir / "motion.bvh"),
             "glb": str(out_dir / "motion.glb")}
    save_result(files["result"], result)
    write_bvh(files["bvh"], motion.body, result["qpos"], obs.fps)
    write_glb(files["glb"], motion.body, result["qpos"], obs.fps)
    files.update(export_result(files["result"], "opensim", out_dir))
    if overlay_video is not None:
        from .body.model import CONTACT_POINTS
        from .viz.overlay import force_arrow_scale, force_arrows_2d, render_overlay, skeleton_edges

        files["overlay"] = str(out_dir / "overlay.mp4")
        points_2d = motion.camera.project(result["joints_world"])  # result points are the body's points
        soles = result["joints_world"][:, [RESULT_POINTS.index(n) for n in CONTACT_POINTS]]
        arrows = force_arrows_2d(soles, result["grf"], motion.camera.project,
                                 force_arrow_scale(motion.body.mass, motion.body.height))
        bar = progress("overlay", obs.num_frames) if progress else None
        render_overlay(overlay_video, files["overlay"], points_2d, skeleton_edges(motion.body), motion.valid,
                       keypoints=obs.keypoints_2d, contacts=result["contacts"], labels=RESULT_POINTS, progress=bar,
                       force_arrows=arrows)
    files["viewer"] = str(out_dir / "viewer.html")
    write_viewer(result, files["viewer"], video="overlay.mp4" if overlay_video is not None else None)
    files["report"] = str(out_dir / "report.html")
    seconds["outputs"] = time.perf_counter() - started

    error = motion.reprojection_error
    relative = 100 * error / result["person_height_px"]
    invalid = np.flatnonzero(~motion.valid)
    reasons: dict[str, list[str]] = {}
    for reason in sorted(set(obs.invalid_reason[invalid].tolist())):
        reasons[reason or "invalid"] = _frame_ranges(invalid[obs.invalid_reason[invalid] == reason])
    swaps = np.zeros(obs.num_frames, bool) if motion.foot_swaps is None else np.asarray(motion.foot_swaps, bool)
    summary = RunSummary(
        input=source, output_dir=str(out_dir), frames=obs.num_frames, valid_frames=int(motion.valid.sum()),
        invalid_frames=reasons, fps=obs.fps, online=settings.online, stage_seconds=seconds, cached_stages=cached,
        median_reprojection_error_px=_nanmedian(error),
        median_reprojection_error_percent_of_height=_nanmedian(relative),
        skeleton_scale_replaced=list(motion.calibration.replaced), physics=settings.physics.method,
        physics_fallback_frames=_frame_ranges(np.flatnonzero(result["physics_fallback"])),
        foot_swap_frames=_frame_ranges(np.flatnonzero(swaps)), foot_swap_frame_count=int(swaps.sum()),
        physics_report=physics_report or {}, files=files,
        median_reprojection_error_final_px=_nanmedian(result["reprojection_error_final"]),
        physics_strayed_frames=_frame_ranges(np.flatnonzero(motion.valid & (result["physics_deviation"]
                                                                            > settings.physics.stray_distance))))
    files["summary"] = str(out_dir / "summary.json")
    write_text(files["summary"], summary.to_json())
    write_report(out_dir, result)  # last: it links every output that exists
    return summary


def _nanmedian(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.median(x)) if len(x) else float("nan")
