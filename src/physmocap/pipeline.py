"""A capture as a short list of stages (physmocap.stages) run into a run folder.

    OUT/
      cache/observations.npz  detection (reused while the video's bytes, the detect settings and code are the same)
      cache/kinematics.npz    calibrated skeleton, camera, floor and fitted motion
      cache/refined.npz       the B.4-refined kinematics (trajopt, offline PhysCap)
      cache/physics.npz       the PhysCap motion, or cache/trajopt.npz: the trajopt motion
      cache/<stage>.key       each entry's key and checksum (see stages.py)
      result.npz              the contract of DESIGN.md
      motion.bvh, motion.glb  Mixamo-named skeleton, Y up, metres
      markers.trc, grf.mot, external_loads.xml   OpenSim
      overlay.mp4             the fit drawn on the input video (H.264), unless --no-overlay
      viewer.html, report.html, summary.json

Every file is written atomically, so an interrupted run leaves only complete files and resumes from them; one run
at a time holds the folder (run_folder.py), and outputs an earlier run wrote but this one did not are removed.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .config import Settings
from .contacts.footlock import lock_feet
from .detect.repeats import interpolate_repeated
from .errors import InputError
from .io.atomic import write_text
from .io.finite import json_text
from .kinematics.calibration import height_line
from .kinematics.clock import ClockCheck, check_clock
from .kinematics.stage import KinematicMotion
from .motion import Observations, frame_ranges
from .result import RESULT_POINTS, build_result, save_result
from .run_folder import locked_run_folder, previous_outputs, remove_stale_outputs
from .stages import (
    DETECT,
    KINEMATICS,
    PHYSCAP,
    REFINE,
    TRAJOPT,
    ProgressFactory,
    Runner,
    arrays_digest,
    file_digest,
    motion_digest,
    observations_digest,
)

if TYPE_CHECKING:
    from .dynamics.stage import PhysicsMotion
    from .trajopt.stage import TrajoptMotion

log = logging.getLogger("physmocap")

__all__ = ["RunSummary", "run_capture", "detect_stage", "contacts_stage", "write_outputs", "ProgressFactory"]


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
    repeated_frames: list[str] = field(default_factory=list)  # frames showing the picture before them again
    repeated_frame_count: int = 0  # how many; offline their detections are interpolated (detect/repeats.py)
    physics_report: dict = field(default_factory=dict)  # B.4 refinement; trajopt: summary line, window reports
    median_reprojection_error_final_px: float = float("nan")  # of the final (physics) motion
    physics_strayed_frames: list[str] = field(default_factory=list)  # final joints farther than
    # physics.stray_distance on average from the kinematic motion's
    files: dict[str, str] = field(default_factory=dict)
    removed_stale_outputs: list[str] = field(default_factory=list)  # an earlier run's outputs this run did not write

    physics_unexplained_frames: list[str] = field(default_factory=list)  # frames the feet on the floor cannot
    # explain (hands, a knee, a seat or a raised floor carrying weight, a jump off an object, a diverged step):
    # kinematics kept
    physics_unexplained_frame_count: int = 0
    body_height_m: float = float("nan")  # the standing height the skeleton was scaled to
    body_height_source: str = "given"  # "given" (settings, the 1.70 m default included) or "estimated"
    body_height_note: str = ""  # the line that says which height was assumed and how to set it
    floor: dict = field(default_factory=dict)  # the floor's confidence (camera.Floor.confidence)
    overlay_parts: int = 0  # parts overlay.mp4 was drawn and encoded in at once (0: no overlay)
    video_clock: dict = field(default_factory=dict)  # the jumps against the frame rate (kinematics.clock.ClockCheck)

    def to_json(self) -> str:
        return json_text(asdict(self), indent=2)


def run_capture(out_dir: str | os.PathLike, settings: Settings, *, video: str | os.PathLike | None = None,
                observations: str | os.PathLike | None = None, overlay: bool = True,
                progress: ProgressFactory | None = None) -> RunSummary:
    """Video (or observations file) -> run folder with result.npz, the exports, overlay.mp4 (unless `overlay` is
    False), viewer, report and summary.json. Stages whose inputs, settings and code are unchanged come from the
    folder's cache. OutputLocationError when another run holds the folder."""
    out_dir = Path(out_dir)
    video = None if video is None else Path(video)
    with locked_run_folder(out_dir):
        runner = Runner(out_dir, settings, progress)
        obs, motion = _observe_and_fit(runner, video, observations)
        runner.seconds["kinematics"] = motion.seconds
        started = time.perf_counter()
        predicted, stationary = contacts_stage(obs, settings)
        contacts = lock_feet(predicted, motion.body, motion.qpos, settings.physics)
        runner.seconds["contacts"] = time.perf_counter() - started
        motion, contacts, physics, report = _physics(runner, obs, motion, contacts, stationary)
        return write_outputs(out_dir, str(video if observations is None else observations), obs, motion, contacts,
                             stationary, physics, settings, runner.seconds, runner.cached,
                             video if overlay else None, progress, predicted, report)


def _observe_and_fit(runner: Runner, video: Path | None,
                     observations: str | os.PathLike | None) -> tuple[Observations, KinematicMotion]:
    """The observations (detected, cached or read from `observations`) and the kinematic motion. Online and
    without cached detections, detection and the causal fit run together in live order (`_stream`). The
    observations and settings are checked for sense (`plausibility`) before the fit, or in live order right
    after it."""
    from .plausibility import check_observations

    source = str(video if observations is None else observations)
    if observations is not None:  # with a video too, the video is only drawn over (the overlay)
        obs = at_filmed_rate(Observations.load(observations), runner.settings)
        if video is not None:
            check_observations_fit_video(video, obs, observations)
    else:
        assert video is not None, "run_capture needs a video or an observations file"
        video_key = (file_digest(video),)
        cached = runner.lookup(DETECT, video_key) if runner.settings.online else None
        if cached is None and runner.settings.online:
            obs, motion = _stream(runner, video, video_key)
            runner.seconds["detect"] = obs.seconds_per_frame * obs.num_frames
            for warning in check_observations(obs, runner.settings, source):
                log.warning(warning)
            return obs, motion
        obs = at_filmed_rate(runner.run(DETECT, video_key, video) if cached is None else cached, runner.settings)
        check_truncation(video, obs, runner.settings)
        runner.seconds["detect"] = obs.seconds_per_frame * obs.num_frames
    if not runner.settings.online:  # online, a repeat's next new picture is still to come
        obs = interpolate_repeated(obs)
    for warning in check_observations(obs, runner.settings, source):
        log.warning(warning)
    return obs, runner.run(KINEMATICS, (observations_digest(obs),), obs)


def at_filmed_rate(obs: Observations, settings: Settings) -> Observations:
    """The observations at the rate the camera filmed them (settings.camera.fps), where the file plays them at
    another (slow motion): every velocity, acceleration and force follows from it."""
    fps = settings.camera.fps
    return obs if fps is None else dataclasses.replace(obs, fps=float(fps))


def _stream(runner: Runner, video: Path, video_key: tuple[str]) -> tuple[Observations, KinematicMotion]:
    """Detection and causal fit together (live order); both outputs are cached like the separate stages'."""
    from .io.video import probe_video
    from .live import stream_capture

    # Physics runs as its own cached stage afterwards; here only what the detector and the fit produce.
    report = stream_capture(str(video), runner.settings.replace("physics", method="none"))
    check_truncation(video, report.observations, runner.settings)
    stored = report.observations
    if runner.settings.camera.fps is not None:  # cached at the file's rate, as detection caches it
        stored = dataclasses.replace(stored, fps=probe_video(video).fps)
    runner.store(DETECT, video_key, stored)
    runner.store(KINEMATICS, (observations_digest(report.observations),), report.motion)
    return report.observations, report.motion


def _physics(runner: Runner, obs: Observations, motion: KinematicMotion, contacts: np.ndarray,
             stationary: np.ndarray) -> tuple[KinematicMotion, np.ndarray, PhysicsMotion | TrajoptMotion | None, dict]:
    """The physics the settings ask for: (kinematic motion, contacts, physics motion or None, physics report).
    Trajopt and offline PhysCap start from the B.4-refined motion and its contacts; PhysCap's motion and the
    kinematic one are moved onto the floor the physics refined (online), so that both stand on z = 0."""
    from .dynamics.stage import onto_refined_floor

    settings, report = runner.settings, dict[str, Any]()
    method = settings.physics.method
    if settings.refines_before_physics:
        refined = runner.run(REFINE, (observations_digest(obs), motion_digest(motion), _flags_digest(contacts)),
                             obs, motion, contacts)
        motion, contacts, report["refinement"] = refined.motion, refined.contacts, refined.report
        runner.seconds["refine"] = refined.report["seconds"]
    inputs = (observations_digest(obs), motion_digest(motion))
    physics: PhysicsMotion | TrajoptMotion
    if method == "trajopt":
        physics = runner.run(TRAJOPT, (*inputs, _flags_digest(contacts)), obs, motion, contacts)
        report.update(physics.report())
    elif method == "physcap":
        tracked = runner.run(PHYSCAP, (*inputs, _flags_digest(contacts, stationary)), obs, motion, contacts,
                             stationary)
        motion, physics = onto_refined_floor(motion, tracked)
    else:
        return motion, contacts, None, report
    runner.seconds["physics"] = physics.seconds
    return motion, contacts, physics, report


def _flags_digest(*flags: np.ndarray) -> str:
    return arrays_digest({str(i): np.asarray(f, bool) for i, f in enumerate(flags)})


def detect_stage(video: str | os.PathLike, out_dir: str | os.PathLike, settings: Settings,
                 progress: ProgressFactory | None = None) -> tuple[Observations, bool]:
    """The observations of `video`, from out_dir's cache when its bytes, the detect settings and the code are
    unchanged; and whether they came from the cache."""
    runner = Runner(Path(out_dir), settings, progress)
    with locked_run_folder(out_dir):
        obs = runner.run(DETECT, (file_digest(Path(video)),), Path(video))
    check_truncation(Path(video), obs, settings)
    return obs, runner.cached == ["detect"]


def check_truncation(video: Path, obs: Observations, settings: Settings) -> None:
    """InputError when fewer frames decoded than the video announces (unless detect.accept_truncated)."""
    from .io.video import probe_video

    announced = probe_video(video).frame_count
    if obs.num_frames < announced - max(2, 0.02 * announced) and not settings.detect.accept_truncated:
        raise InputError(f"{video}: the video is truncated: only {obs.num_frames} of the {announced} frames it "
                         "announces decode (use --accept-truncated to capture those).")


def check_observations_fit_video(video: Path, obs: Observations, observations: str | os.PathLike) -> None:
    """InputError when an observations file was not made from `video`: other frame count or picture size."""
    from .io.video import probe_video

    info = probe_video(video)
    if obs.num_frames != info.frame_count or tuple(obs.image_size) != (info.width, info.height):
        raise InputError(f"{observations}: {obs.num_frames} frames of {obs.image_size[0]}x{obs.image_size[1]} px, "
                         f"but {video} has {info.frame_count} frames of {info.width}x{info.height}: give the "
                         "observations made from this video, or no video.")


def contacts_stage(obs: Observations, settings: Settings) -> tuple[np.ndarray, np.ndarray]:
    """Foot contacts (T, 4) and the stationary flag (T,) from the 2D keypoints, fast enough not to need a cache.

    Contacts: the causal network online, the centred one offline. The stationary flag: the 2D root-speed
    heuristic (causal online), which beats both networks on the hand-labelled real frames
    (BENCHMARKS.md, "Foot contacts")."""
    from .contacts.baselines import velocity_2d
    from .contacts.predict import predict_contacts

    contacts, _, _ = predict_contacts(obs, "causal" if settings.online else "centred")
    return contacts, velocity_2d(obs.keypoints_2d, obs.valid, obs.fps, causal=settings.online)[1]


def write_outputs(out_dir: Path, source: str, obs: Observations, motion: KinematicMotion, contacts: np.ndarray,
                  stationary: np.ndarray, physics, settings: Settings, seconds: dict[str, float], cached: list[str],
                  overlay_video: Path | None = None, progress: ProgressFactory | None = None,
                  predicted: np.ndarray | None = None, physics_report: dict | None = None) -> RunSummary:
    """result.npz, the exports (motion.bvh, motion.glb, OpenSim markers.trc, grf.mot, external_loads.xml),
    overlay.mp4 (when `overlay_video` is given), viewer.html, summary.json (with `physics_report`, the physics
    stage's own account, e.g. trajopt's solver reports) and report.html. An earlier run's outputs that this one
    does not write (overlay.mp4 after --no-overlay) are removed before the report links what exists."""
    from .viz.report import write_report, write_report_parts

    out_dir = Path(out_dir)
    with locked_run_folder(out_dir):
        earlier = previous_outputs(out_dir)
        started = time.perf_counter()
        result = build_result(obs, motion, seconds, settings.as_dict(), contacts, stationary, physics, predicted,
                              settings.physics.method)
        files, overlay_parts = _write_files(out_dir, obs, motion, result, overlay_video, progress, settings)
        # the report's plots and metrics count in the stage; its page comes last, once every output exists
        report_parts = write_report_parts(out_dir, result)
        clock = _video_clock(obs, motion, contacts, source)
        seconds["outputs"] = time.perf_counter() - started
        summary = _summary(out_dir, source, obs, motion, result, settings, seconds, cached, physics_report or {},
                           files)
        summary.overlay_parts = overlay_parts
        if clock.warning:
            log.warning(clock.warning)
        summary.video_clock = clock.to_dict()
        files["summary"] = str(out_dir / "summary.json")
        summary.removed_stale_outputs = [str(p) for p in remove_stale_outputs(earlier, files)]
        write_text(files["summary"], summary.to_json())
        write_report(out_dir, result, report_parts)  # last: it links every output that exists
    return summary


def _video_clock(obs: Observations, motion: KinematicMotion, contacts: np.ndarray, source: str) -> ClockCheck:
    """The kinematic motion's jumps against the frame rate (kinematics.clock.check_clock)."""
    from .body.kinematics import center_of_mass, forward_kinematics
    from .body.model import CONTACT_POINTS

    pose = forward_kinematics(motion.body, motion.qpos)
    soles = pose.points[:, motion.body.point_index(CONTACT_POINTS), 2]
    return check_clock(center_of_mass(motion.body, pose)[:, 2], soles, contacts, motion.valid, obs.fps, source)


def _write_files(out_dir: Path, obs: Observations, motion: KinematicMotion, result: dict[str, np.ndarray],
                 overlay_video: Path | None, progress: ProgressFactory | None,
                 settings: Settings) -> tuple[dict[str, str], int]:
    """Every output file but summary.json and the report; returns {kind: path} and the parts the overlay was
    rendered in (0 without one). The overlay renders in a worker thread while the other files are written (an
    error or Ctrl-C cancels it and leaves no overlay.mp4)."""
    from .export import export_result
    from .io.bvh_export import write_bvh
    from .io.glb import write_glb
    from .viz.viewer import write_viewer

    files = {"result": str(out_dir / "result.npz"), "bvh": str(out_dir / "motion.bvh"),
             "glb": str(out_dir / "motion.glb")}
    if overlay_video is not None:
        files["overlay"] = str(out_dir / "overlay.mp4")
    with _start_overlay(files.get("overlay"), overlay_video, obs, motion, result, progress, settings) as job:
        save_result(files["result"], result)
        write_bvh(files["bvh"], motion.body, result["qpos"], obs.fps)
        write_glb(files["glb"], motion.body, result["qpos"], obs.fps)
        files.update(export_result(files["result"], "opensim", out_dir))
        files["viewer"] = str(out_dir / "viewer.html")
        write_viewer(result, files["viewer"], video="overlay.mp4" if overlay_video is not None else None)
        report = None if job is None else job.result()
    if report is not None and report.nonfinite_frames:
        log.warning("overlay.mp4: frames %s drawn without some fitted points (non-finite or far outside the image)",
                    ", ".join(frame_ranges(np.asarray(report.nonfinite_frames))[:6]))
    files["report"] = str(out_dir / "report.html")
    return files, 0 if report is None else report.parts


def _start_overlay(path: str | None, video: Path | None, obs: Observations, motion: KinematicMotion,
                   result: dict[str, np.ndarray], progress: ProgressFactory | None, settings: Settings):
    """The overlay rendering started in a worker (viz.overlay.start_overlay), or a context of None without one:
    the final motion, keypoints, contacts, forces and the frames physics could not explain, drawn on the input
    video at most settings.overlay_width pixels wide (0: its own width) in settings.overlay_parts parts."""
    import contextlib

    from .body.model import CONTACT_POINTS
    from .viz.overlay import force_arrow_scale, force_arrows_2d, skeleton_edges, start_overlay

    if path is None or video is None:
        return contextlib.nullcontext()
    points_2d = motion.camera.project(result["joints_world"])  # result points are the body's points
    soles = result["joints_world"][:, [RESULT_POINTS.index(n) for n in CONTACT_POINTS]]
    arrows = force_arrows_2d(soles, result["grf"], motion.camera.project,
                             force_arrow_scale(motion.body.mass, motion.body.height))
    bar = progress("overlay", obs.num_frames) if progress else None
    return start_overlay(video, path, points_2d, skeleton_edges(motion.body), motion.valid,
                         keypoints=obs.keypoints_2d, contacts=result["contacts"], labels=RESULT_POINTS, progress=bar,
                         force_arrows=arrows, unexplained=result["physics_unexplained"],
                         max_width=settings.overlay_width or None, fps=obs.fps, parts=settings.overlay_parts)


def _summary(out_dir: Path, source: str, obs: Observations, motion: KinematicMotion, result: dict[str, np.ndarray],
             settings: Settings, seconds: dict[str, float], cached: list[str], physics_report: dict,
             files: dict[str, str]) -> RunSummary:
    error = motion.reprojection_error
    invalid = np.flatnonzero(~motion.valid)
    why = np.asarray(obs.invalid_reason, dtype=object)
    reasons: dict[str, list[str]] = {}
    for reason in sorted(set(why[invalid].tolist())):
        reasons[reason or "invalid"] = frame_ranges(invalid[why[invalid] == reason])
    swaps = np.zeros(obs.num_frames, bool) if motion.foot_swaps is None else np.asarray(motion.foot_swaps, bool)
    strayed = motion.valid & (result["physics_deviation"] > settings.physics.stray_distance)
    return RunSummary(
        input=source, output_dir=str(out_dir), frames=obs.num_frames, valid_frames=int(motion.valid.sum()),
        invalid_frames=reasons, fps=obs.fps, online=settings.online, stage_seconds=seconds, cached_stages=cached,
        median_reprojection_error_px=_nanmedian(error),
        median_reprojection_error_percent_of_height=_nanmedian(100 * error / result["person_height_px"]),
        skeleton_scale_replaced=list(motion.calibration.replaced), physics=settings.physics.method,
        physics_fallback_frames=frame_ranges(np.flatnonzero(result["physics_fallback"])),
        foot_swap_frames=frame_ranges(np.flatnonzero(swaps)), foot_swap_frame_count=int(swaps.sum()),
        repeated_frames=frame_ranges(np.flatnonzero(obs.repeated)), repeated_frame_count=int(obs.repeated.sum()),
        physics_report=physics_report, files=files,
        median_reprojection_error_final_px=_nanmedian(result["reprojection_error_final"]),
        physics_strayed_frames=frame_ranges(np.flatnonzero(strayed)),
        physics_unexplained_frames=frame_ranges(np.flatnonzero(result["physics_unexplained"])),
        physics_unexplained_frame_count=int(np.count_nonzero(result["physics_unexplained"])),
        body_height_m=float(motion.calibration.lengths.standing_height),
        body_height_source=motion.calibration.height_source,
        body_height_note=height_line(motion.calibration, type(settings.body)().height),
        floor=motion.floor.confidence())


def _nanmedian(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.median(x)) if len(x) else float("nan")
