"""The command line: `physmocap --help` teaches it."""

from __future__ import annotations

import argparse
import errno
import logging
import math
import os
import re
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

import physmocap  # noqa: F401 - sets single-threaded BLAS before numpy loads

from .config import Settings
from .errors import (
    EXIT_BUG,
    EXIT_INTERRUPTED,
    InputError,
    OutputLocationError,
    PhysmocapError,
    check_output_folder,
    output_error,
)
from .presets import PRESETS, SMOOTHING_LIMITS
from .settings_fields import declaration, describe

if TYPE_CHECKING:
    from .live import LiveReport

EXAMPLES = """\
examples:
  physmocap capture video.mp4 -o runs/walk               # offline: whole clip at once (best quality)
  physmocap capture video.mp4 -o runs/walk --online      # causal, frame by frame (live use)
  physmocap capture video.mp4 --height 1.82 --mass 80 --fov 70
  physmocap capture video.mp4 --person-box 100,50,400,700   # follow the person inside this box
  physmocap detect video.mp4 -o obs.npz                  # only the detector; any other detector can
  physmocap capture --observations obs.npz -o runs/x     # ...write this file format and be fitted
  physmocap capture video.mp4 --physics trajopt          # Rempe et al.'s trajectory optimisation instead
  physmocap live 0 -o runs/cam                           # live from camera 0: detection, fit, contacts, physics
  physmocap live video.mp4 --max-frames 200              # a file played at its own frame rate, as a camera
  physmocap export runs/walk/result.npz --to glb         # BVH, GLB or OpenSim files from any earlier run
  physmocap evaluate runs/walk/result.npz [--truth truth.npz]   # every metric of a run
  physmocap batch videos/ -o runs/season                 # many videos at once; resumes, survives bad files
  physmocap retarget runs/walk/result.npz --character hero.glb  # the motion on your own character (BVH/GLB rig)
  physmocap capture video.mp4 --character hero.bvh       # capture, then retarget into runs/video/character/

outputs of capture (in the -o folder):
  result.npz    joints, generalised coordinates, camera, floor, flags (see README "Result file")
  motion.bvh    Mixamo-named skeleton, Y up, metres; imports into Blender upright and to scale
  overlay.mp4   the fitted skeleton drawn on the input video (H.264, plays in browsers)
  summary.json  frames, valid frames, time per stage, median reprojection error
Re-running with the same folder reuses the finished stages (cache/) whose inputs and settings are unchanged.
"""


def _floats(count: int, name: str):
    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(x) for x in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{name} must be {count} comma-separated numbers, got '{text}'") from None
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{name} must be {count} comma-separated finite numbers, got '{text}'")
        return values
    return parse


# Options whose value is a comma-separated list of numbers that may begin with a minus sign.
NUMBER_LIST_OPTIONS = ("--floor", "--person-box")


def _join_negative_number_lists(argv: list[str]) -> list[str]:
    """`--floor -0.1,1,0,2` as `--floor=-0.1,1,0,2`: argparse would read the value as an unknown option."""
    out: list[str] = []
    for token in argv:
        if out and out[-1] in NUMBER_LIST_OPTIONS and re.fullmatch(r"-[\d.][^\s]*", token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def _add_capture_command(sub: argparse._SubParsersAction) -> None:
    """`capture`: one video or observations file into a run folder."""
    cap = sub.add_parser("capture", help="video (or observations file) -> 3D motion, BVH, overlay",
                         formatter_class=_DefaultsUnlessUnsetFormatter,
                         description="Capture the 3D motion of one person in a video.")
    cap.add_argument("video", nargs="?", type=Path, help="input video file (mp4, mov, webm, ...)")
    cap.add_argument("-o", "--output", type=Path, default=None,
                     help="run folder (default: runs/<video name>)")
    cap.add_argument("--observations", type=Path,
                     help="fit this observations .npz instead of detecting (a video given as well is only drawn over)")
    _add_capture_options(cap)
    _add_character_arguments(cap, required=False)


def _add_batch_command(sub: argparse._SubParsersAction) -> None:
    """`batch`: many inputs, one run folder each, on local processes or Ray."""
    batch = sub.add_parser(
        "batch", help="capture many videos (or observations files): local processes, or a Ray cluster",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Capture every input into OUT/<name>/ as `capture` would, several at once. A broken input is "
                    "recorded with its reason and the batch goes on; re-running the same command skips finished "
                    "runs and resumes unfinished ones from their cached stages; Ctrl-C stops cleanly. "
                    "OUT/batch.csv and OUT/index.html hold one row per input (status, frames, wall time, "
                    "plausibility figures, links to each run's report and viewer), updated as runs finish. "
                    "Exit status: 0 every input done, 1 some failed, 2 bad arguments, 130 interrupted.",
        epilog="examples:\n"
               "  physmocap batch videos/ -o runs/season            # every video under videos/, one per core\n"
               "  physmocap batch list.txt a.mp4 obs.npz -o runs/x  # a list file (one path a line), a video, "
               "observations\n"
               "  physmocap batch videos/ -o runs/x --workers 1     # one at a time\n"
               "  physmocap batch videos/ -o /shared/runs --ray auto   # on the Ray cluster this machine belongs to\n"
               "See README \"Many videos\" for clusters.")
    batch.add_argument("inputs", nargs="+", type=Path, metavar="INPUT",
                       help="video file, observations .npz, folder (searched for videos, subfolders too) or text "
                            "file (.txt, .list) listing such paths one a line")
    batch.add_argument("-o", "--output", type=Path, required=True, help="batch folder: one run folder per input")
    batch.add_argument("--workers", type=int, default=None,
                       help="runs at once (default: one per CPU core this process may use, fewer if memory is "
                            "short; with --ray ADDRESS the cluster's CPUs decide)")
    batch.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                       help="run on Ray: alone, a local Ray instance; with auto or host:port, the existing cluster "
                            "(inputs and OUT on a file system every node shares)")
    _add_capture_options(batch)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="physmocap",
        description="Physics-based monocular 3D human motion capture: one person, one static camera, "
                    "global 3D motion out.",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES)
    parser.add_argument("--version", action="version", version=f"physmocap {physmocap.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    _add_capture_command(sub)
    _add_batch_command(sub)

    live = sub.add_parser("live", help="live capture from a camera or a video played at its frame rate",
                          formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                          description="Detection, causal fit, contacts and PhysCap physics frame by frame, with "
                                      "frames arrived, processed and dropped and the true latency (from a frame's "
                                      "arrival to its pose) reported at the end. Drop policy: after the calibration "
                                      "warm-up, when the pipeline falls behind the source, the detector and the "
                                      "fit skip to the newest frame that has reached them, so the latency stays "
                                      "bounded; a skipped frame is kept in the result as invalid (\"dropped: the "
                                      "pipeline fell behind\"), its pose predicted from the frames before it. A "
                                      "warning says when it happens.")
    live.add_argument("source", help="camera index (0, 1, ...) or a video file")
    live.add_argument("-o", "--output", type=Path, default=None,
                      help="folder for live.jsonl (one line per processed frame as its pose is ready) and, at the "
                           "end, result.npz, motion.bvh and summary.json; without it nothing is saved")
    live.add_argument("--as-fast-as-possible", action="store_true",
                      help="feed a video file as fast as the pipeline goes instead of at its own frame rate (no "
                           "frame is dropped then)")
    live.add_argument("--keep-every-frame", action="store_true",
                      help="turn the drop policy off: process every frame, and let the lag grow while the "
                           "pipeline is slower than the source")
    live.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    live.add_argument("--physics", choices=("none", "physcap"), default="physcap")
    live.add_argument("--online", action="store_true", default=True, help=argparse.SUPPRESS)
    _add_settings_arguments(live)

    _add_export_command(sub)
    _add_evaluate_command(sub)
    _add_train_contacts_command(sub)
    _add_retarget_command(sub)
    _add_detect_command(sub)
    return parser


def _add_export_command(sub: argparse._SubParsersAction) -> None:
    """`export`: BVH, GLB or OpenSim files from a result.npz."""
    exp = sub.add_parser("export", help="BVH, GLB or OpenSim files from a result.npz of any earlier run",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    exp.add_argument("result", type=Path, help="a result.npz")
    exp.add_argument("--to", choices=("bvh", "glb", "opensim"), required=True)
    exp.add_argument("-o", "--output", type=Path, default=None, help="folder (default: the result's folder)")
    exp.add_argument("--units", default=None, help="bvh: m or cm; opensim: m or mm")
    exp.add_argument("--root-at-origin", action="store_true", help="bvh, glb: start the root above the origin")


def _add_evaluate_command(sub: argparse._SubParsersAction) -> None:
    """`evaluate`: every metric of a run."""
    ev = sub.add_parser("evaluate", help="every metric of a run, against ground truth if given",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ev.add_argument("result", type=Path, help="a result.npz")
    ev.add_argument("--truth", type=Path, default=None,
                    help="truth .npz, e.g. a synthetic case: joint_names (J,) with the shoulders, elbows, wrists, "
                         "hips, knees, ankles, heels and toes by the body model's names (left_knee, ...); "
                         "joints_world (T, J, 3) in metres, Z up, floor z = 0, the run's T frames; camera_R (3, 3) "
                         "and camera_t (3,) of the camera (world -> camera); fps")
    ev.add_argument("-o", "--output", type=Path, default=None,
                    help="evaluation JSON to write (default: evaluation.json beside the result)")


def _add_train_contacts_command(sub: argparse._SubParsersAction) -> None:
    """`train-contacts`: the contact networks' weights from motion capture."""
    train = sub.add_parser("train-contacts", help="rebuild the contact networks' weights from motion capture",
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                           description="Deterministic training of the causal and centred contact networks on "
                                       "synthetic observations of CMU motion capture (needs torch; the shipped "
                                       "weights took 15 minutes on a 2-core machine: "
                                       "docs/decisions/contact-training.md). "
                                       "The same data and seed give the same weights on the same processor; "
                                       "training.json beside them records the recipe and the held-out scores.")
    train.add_argument("--data", type=Path, required=True,
                       help="the data folder holding mocap/ (the project's is ../shared/data)")
    train.add_argument("--out", type=Path, required=True,
                       help="folder for causal.npz, centred.npz and training.json (replaced); to ship them, copy "
                            "them into src/physmocap/data/contacts")
    train.add_argument("--seed", type=int, default=0,
                       help="seed of every random draw (synthetic data, initial weights, batches)")
    train.add_argument("--folders", default="all",
                       help="comma-separated folders of mocap/ to train on; 'all': every folder (the shipped "
                            "weights); 'issue3': the CC3 and raw CMU folders of the weights before issue 18")
    train.add_argument("--foot-keypoints", choices=("sole", "mediapipe"), default="mediapipe",
                       help="where the synthetic heel and foot_index keypoints sit: 'mediapipe', where MediaPipe puts "
                            "them, its heel about 4 cm above its foot_index on a flat foot (the shipped weights); "
                            "'sole', the sole points (the weights before issue 18)")


def _add_retarget_command(sub: argparse._SubParsersAction) -> None:
    """`retarget`: a result's motion on the user's character."""
    ret = sub.add_parser("retarget", help="motion of a result.npz on your own character (BVH or glTF/GLB rig)",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                         description="Retarget a run's motion onto a character: uniform scale by the legs, IK with "
                                     "the character's bone lengths and planted feet on its own soles, physics on its "
                                     "own body model (bone lengths and mass distribution); writes character.bvh (the "
                                     "character's hierarchy), character.glb (glTF characters), result.npz and "
                                     "retarget.json. See README 'Your own character'.")
    ret.add_argument("result", type=Path, help="a result.npz")
    _add_character_arguments(ret, required=True)
    ret.add_argument("-o", "--output", type=Path, default=None,
                     help="folder (default: character/ beside the result)")
    ret.add_argument("--physics", choices=("physcap", "trajopt", "none"), default="physcap",
                     help="physics on the character's body model")
    ret.add_argument("--config", type=Path, help="TOML settings file (physics and trajopt settings)")


def _add_detect_command(sub: argparse._SubParsersAction) -> None:
    """`detect`: the keypoint detector alone, into an observations file."""
    det = sub.add_parser("detect", help="run only the 2D/3D keypoint detector and write an observations file",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    det.add_argument("video", type=Path)
    det.add_argument("-o", "--output", type=Path, required=True, help="observations .npz to write")
    det.add_argument("--person-box", type=_floats(4, "--person-box"), metavar="X0,Y0,X1,Y1",
                     help="follow the person inside this box (pixels)")
    det.add_argument("--max-width", type=int, default=None,
                     help="downscale what the detector sees to this width, pixels (default: native)")


class _DefaultsUnlessUnsetFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows an option's default unless it is None or False: a setting's own default is in its help text."""

    def _get_help_string(self, action):
        unset = action.default is None or action.default is False
        return action.help if unset else super()._get_help_string(action)


def _add_capture_options(p: argparse.ArgumentParser) -> None:
    """The options of one capture, shared by `capture` and `batch`; help and choices of those that set a setting
    come from its declaration in config.py."""
    p.add_argument("--online", action="store_true", help=describe(Settings, "online"))
    p.add_argument("--physics", choices=declaration(Settings, "physics.method").metadata["choices"], default=None,
                   help=describe(Settings, "physics.method"))
    _add_settings_arguments(p)
    p.add_argument("--no-overlay", action="store_true", help="skip rendering overlay.mp4")
    p.add_argument("--overlay-size", type=int, default=argparse.SUPPRESS, metavar="WIDTH",
                   help=describe(Settings, "overlay_width"))
    p.add_argument("--accept-truncated", action="store_true", help=describe(Settings, "detect.accept_truncated"))


def _add_character_arguments(p: argparse.ArgumentParser, required: bool) -> None:
    p.add_argument("--character", type=Path, required=required, metavar="RIG",
                   help="your character: a BVH file (its hierarchy and rest pose) or a skinned .glb/.gltf/.vrm"
                        + ("" if required else "; the motion is also retargeted onto it, into OUT/character/"))
    p.add_argument("--character-map", type=Path, default=None, metavar="TOML",
                   help="bones the automatic mapping misses, the file's unit, and the character's mass and its "
                        "distribution (README 'Your own character')")


def _add_settings_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--height", type=float, default=None, help=describe(Settings, "body.height"))
    p.add_argument("--mass", type=float, default=None, help=describe(Settings, "body.mass"))
    p.add_argument("--focal", type=float, default=None, help=describe(Settings, "camera.focal"))
    p.add_argument("--fov", type=float, default=None, help=describe(Settings, "camera.fov"))
    p.add_argument("--floor", type=_floats(4, "--floor"), metavar="NX,NY,NZ,D", help=describe(Settings, "camera.floor"))
    p.add_argument("--fps", type=float, default=None, help=describe(Settings, "camera.fps"))
    p.add_argument("--person-box", type=_floats(4, "--person-box"), metavar="X0,Y0,X1,Y1",
                   help=describe(Settings, "detect.person_box"))
    p.add_argument("--one-euro", action="store_true", help=describe(Settings, "fit.one_euro"))
    p.add_argument("--preset", choices=sorted(PRESETS), help="settings suited to the activity (see "
                                                             "physmocap/presets.py)")
    p.add_argument("--smoothing", type=float, default=None,
                   help="smoothing strength: factor on the fit's temporal weights, 1 the settings', 0 none "
                        f"({SMOOTHING_LIMITS[0]:g} .. {SMOOTHING_LIMITS[1]:g})")
    p.add_argument("--foot-lock", choices=declaration(Settings, "physics.foot_lock").metadata["choices"],
                   default=None, help=describe(Settings, "physics.foot_lock"))
    p.add_argument("--config", type=Path, help="TOML settings file (see README)")


def settings_from_args(args):
    from .config import load_settings
    from .presets import apply_preset, apply_smoothing

    s = load_settings(args.config)
    if args.preset:
        s = apply_preset(s, args.preset)
    if args.smoothing is not None:
        s = apply_smoothing(s, args.smoothing)
    if args.foot_lock is not None:
        s = s.replace("physics", foot_lock=args.foot_lock)
    body = {k: v for k, v in (("height", args.height), ("mass", args.mass)) if v is not None}
    camera = {k: v for k, v in (("focal", args.focal), ("fov", args.fov), ("floor", args.floor), ("fps", args.fps))
              if v is not None}
    if body:
        s = s.replace("body", **body)
    if camera:
        s = s.replace("camera", **camera)
    if args.person_box is not None:
        s = s.replace("detect", person_box=args.person_box)
    if getattr(args, "overlay_size", None) is not None:
        s = s.replace(None, overlay_width=args.overlay_size)
    if getattr(args, "accept_truncated", False):
        s = s.replace("detect", accept_truncated=True)
    if args.one_euro:
        s = s.replace("fit", one_euro=True)
    if args.online:
        s = s.replace(None, online=True)
    if getattr(args, "physics", None) is not None:
        s = s.replace("physics", method=args.physics)
    return s.check()


PLAIN_PROGRESS_SECONDS = 5.0  # s between progress lines when stderr is not a terminal (a log, CI, a batch job)


def _progress_factory(terminal: bool | None = None, stream=None, interval: float = PLAIN_PROGRESS_SECONDS):
    """A factory of progress callbacks: `factory(stage, total, unit)` gives `update(done, total)`, counting `unit`
    (plural; frames unless given: the whole-clip fits count frame passes).

    On a terminal a tqdm bar per stage; otherwise one plain line (stage, count done, rate) every `interval`
    seconds and one when the stage ends, so that a log shows a long run moving."""
    stream = sys.stderr if stream is None else stream
    if terminal is None:
        terminal = stream.isatty()
    if terminal:
        return _bar_factory(stream)

    def factory(name: str, total: int, unit: str = "frames"):
        started = time.monotonic()
        last = [started, -1]  # time of the last line, the count it reported

        def update(done: int, total_now: int):
            now = time.monotonic()
            finished = bool(total_now) and done >= total_now
            if done == last[1] or not (finished or now - last[0] >= interval):
                return
            last[:] = [now, done]
            rate = done / max(now - started, 1e-9)
            of = f"/{total_now}" if total_now else ""
            print(f"physmocap: {name}: {done}{of} {unit}, {rate:.1f} {unit}/s" + (", done" if finished else ""),
                  file=stream, flush=True)
        return update
    return factory


def _bar_factory(stream):
    from tqdm import tqdm

    def factory(name: str, total: int, unit: str = "frames"):
        bar = tqdm(total=total or None, desc=f"{name:>10}", unit=f" {unit}", leave=True, file=stream,
                   dynamic_ncols=True)

        def update(done: int, total_now: int):
            if total_now and bar.total != total_now:
                bar.total = total_now
            bar.update(done - bar.n)
            if total_now and done >= total_now:
                bar.close()
        return update
    return factory


def cmd_capture(args) -> int:
    from .io.video import probe_video
    from .pipeline import run_capture

    if args.video is None and args.observations is None:
        raise InputError("capture needs a video file or --observations FILE.")
    settings = settings_from_args(args)
    if args.video is not None:
        probe_video(args.video)  # fail fast, before any folder is made
    name = (args.video or args.observations).stem
    if args.character_map is not None and args.character is None:
        raise InputError(f"{args.character_map}: --character-map describes a character; give it with --character RIG.")
    if args.character is not None:
        _check_character(args.character, args.character_map)  # fail fast, before the capture
    out = check_output_folder(args.output or Path("runs") / name)
    summary = run_capture(out, settings, video=args.video, observations=args.observations,
                          overlay=not args.no_overlay, progress=_progress_factory())
    invalid = summary.frames - summary.valid_frames
    print(f"captured {summary.valid_frames}/{summary.frames} frames at {summary.fps:.1f} fps"
          + (" (given: --fps or camera.fps)" if settings.camera.fps else "")
          + f" ({'online' if summary.online else 'offline'} fit, physics: {summary.physics})")
    if invalid:
        details = "; ".join(f"{reason}: frames {_first_ranges(r)}" for reason, r in summary.invalid_frames.items())
        print(f"warning: {invalid} frames could not be reconstructed and are flagged invalid ({details})")
    _note_detections(summary)
    if summary.skeleton_scale_replaced:
        print("note: implausible detector lengths replaced by template proportions: "
              + ", ".join(summary.skeleton_scale_replaced))
    report = summary.physics_report
    if report.get("windows"):
        from .trajopt.stage import WindowReport

        print(report["summary"])
        for window in report["windows"]:
            print("  " + WindowReport.from_dict(window).describe())
    if summary.physics_fallback_frames:
        what = ("the trajectory optimisation did not converge or departed far from the input (kinematic motion "
                "kept) on frames "
                if summary.physics == "trajopt" else "the physics QP failed and fell back on frames ")
        print("warning: " + what + _first_ranges(summary.physics_fallback_frames))
    _warn_strayed(summary, settings)
    _note_physics_floor_height(summary)
    print(f"median reprojection error {summary.median_reprojection_error_px:.1f} px "
          f"({summary.median_reprojection_error_percent_of_height:.2f}% of the person's height)"
          + (f"; after physics {summary.median_reprojection_error_final_px:.1f} px" if summary.physics != "none"
             else ""))
    times = ", ".join(f"{k} {v:.1f} s" for k, v in summary.stage_seconds.items())
    print(f"time: {times}" + (f" (cached: {', '.join(summary.cached_stages)})" if summary.cached_stages else ""))
    print(f"results in {out}/: " + ", ".join(Path(p).name for p in summary.files.values()))
    if args.character is not None:
        _retarget(Path(summary.files["result"]), args.character, args.character_map, out / "character",
                  settings.physics.method, settings)
    return 0


def _check_character(path: Path, character_map: Path | None) -> None:
    from .retarget.character import build_character
    from .retarget.mapping import load_character_config
    from .retarget.rig import read_rig

    config = load_character_config(character_map)
    build_character(read_rig(path, config.units_to_metres), config)


def _retarget(result: Path, character: Path, character_map: Path | None, out: Path, physics: str, settings) -> None:
    from .retarget import retarget_result

    report = retarget_result(result, character, out, character_map=character_map, physics=physics,
                             settings=settings)
    m, c = report.metrics, report.character
    print(f"character {Path(character).name}: {c['joints']} joints, {c['height_m']:.2f} m, {c['mass_kg']:.1f} kg; "
          f"scale {m['scale']:.3f}, physics: {m['physics']}")
    explained = m["grf_explained_mean_percent_bw"]
    grf = "" if explained is None else f", mean GRF {explained:.0f}% of its weight on the frames its physics explains"
    kept = "-" if m["contact_frames_kept"] is None else f"{100 * m['contact_frames_kept']:.1f}%"
    print(f"on the character: foot skate {m['skate_percent']:.2f}%, penetration {m['penetration_percent']:.2f}%, "
          f"contacts kept {kept}, bone directions cosine {m['bone_cosine_rig']:.3f}{grf}")
    for note in report.notes:
        print(f"note: {note}")
    print(f"character results in {out}/: " + ", ".join(Path(p).name for p in report.files.values()))


def cmd_retarget(args) -> int:
    from .config import load_settings

    settings = load_settings(args.config).check() if args.config else None
    _retarget(args.result, args.character, args.character_map, args.output or args.result.parent / "character",
              args.physics, settings)
    return 0


def cmd_batch(args) -> int:
    from .batch import expand_inputs, run_batch
    from .errors import InputError

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}.")
    if args.output.exists() and not args.output.is_dir():
        raise InputError(f"{args.output}: is a file, not a batch folder (-o).")
    settings = settings_from_args(args)
    inputs = expand_inputs(args.inputs, args.output)
    address = None if args.ray in (None, "local") else args.ray
    if address is not None and address != "auto" and ":" not in address:
        raise InputError(f"--ray {address}: not a cluster address (auto or host:port); put --ray after the "
                         "inputs, or give it an address.")
    records = run_batch(inputs, args.output, settings, overlay=not args.no_overlay, workers=args.workers,
                        ray=args.ray is not None, ray_address=address)
    done = [r for r in records if r["status"] == "done"]
    failed = [r for r in records if r["status"] == "failed"]
    earlier = sum(int(r["resumed"] or 0) for r in done)
    print(f"batch: {len(done)} of {len(records)} inputs done"
          + (f" ({earlier} finished by an earlier run, skipped)" if earlier else "")
          + (f", {len(failed)} failed" if failed else "") + f"; {sum(int(r['frames'] or 0) for r in done)} frames")
    for record in failed:
        print(f"  failed (exit status {record['exit_status']}): {record['reason']}")
    print(f"summary in {args.output / 'batch.csv'} and {args.output / 'index.html'}")
    return 1 if failed else 0


def cmd_live(args) -> int:
    import time

    from .io.finite import json_text
    from .live import stream_capture

    settings = settings_from_args(args)
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be at least 1, got {args.max_frames}.")
    source = args.source
    if re.match(r"[a-zA-Z][a-zA-Z0-9+.-]+://", source):
        raise InputError(f"{source}: network streams are not read; give a camera index (0, 1, ...) or a video file.")
    if not source.isdigit():
        from .io.video import probe_video

        probe_video(source)
    stream = None
    if args.output is not None:
        check_output_folder(args.output)
        stream = open(args.output / "live.jsonl", "w")  # a log written as frames arrive, not a result file
        print(f"saving to {args.output}/: live.jsonl as poses come, result.npz, motion.bvh and summary.json at the "
              "end", file=sys.stderr)
    else:
        print("note: no -o folder given: nothing will be saved (give -o DIR to keep the result, exports and "
              "live.jsonl)", file=sys.stderr)
    started = time.perf_counter()

    def on_pose(index, qpos, details):
        if stream is None:
            return
        line = dict(frame=index, seconds=round(time.perf_counter() - started, 4), root=qpos[:3].round(4).tolist(),
                    contacts=details["contacts"].tolist(), stationary=details["stationary"],
                    latency_ms=round(details["latency_s"] * 1000, 1))
        if "grf" in details:
            line["grf_total_n"] = details["grf"].sum(axis=0).round(2).tolist()
        stream.write(json_text(line) + "\n")
        stream.flush()

    try:
        report = stream_capture(source, settings, realtime=not args.as_fast_as_possible,
                                max_frames=args.max_frames, on_pose=on_pose,
                                drop_stale_frames=not args.keep_every_frame)
    finally:
        if stream is not None:
            stream.close()
    _print_live_report(report)
    if args.output is not None:
        _write_live_outputs(args.output, str(source), report, settings)
    return 0


def _print_live_report(report: LiveReport) -> None:
    """The frames, the latency and the time per frame of each stage of a live capture, on stdout."""
    latency = (f"true latency from arrival to pose: median {report.latency_median_ms:.0f} ms, 95th percentile "
               f"{report.latency_p95_ms:.0f} ms (after the {report.warmup_frames}-frame calibration warm-up)"
               if math.isfinite(report.latency_median_ms) else
               f"no latency measured: the stream ended within the calibration warm-up ({report.warmup_frames} "
               f"frames), for which every frame waits")
    print(f"live: {report.frames_arrived} frames arrived at {report.observations.fps:.1f} fps, "
          f"{report.frames_processed} processed ({report.frames_per_second:.1f} per second), "
          f"{report.frames_dropped} dropped; {latency}")
    print(f"per frame: detect {report.detect_ms_per_frame:.1f} ms, fit {report.fit_ms_per_frame:.1f} ms, "
          f"contacts and physics {report.contacts_physics_ms_per_frame:.1f} ms")


def _write_live_outputs(output: Path, source: str, report: LiveReport, settings: Settings) -> None:
    """A live capture's result.npz, exports and summary.json in `output`, with the notes and warnings of a
    capture."""
    import numpy as np

    from .pipeline import write_outputs

    T = report.observations.num_frames
    seconds = {"detect": report.detect_ms_per_frame * T / 1000, "kinematics": report.motion.seconds,
               "contacts_physics": report.contacts_physics_ms_per_frame * T / 1000}
    summary = write_outputs(output, source, report.observations, report.motion, report.contacts,
                            report.stationary, report.physics, settings, seconds, [])
    if report.physics is not None and np.any(report.physics.qp_failures):
        print(f"warning: the physics QP fell back on {int(np.sum(report.physics.qp_failures > 0))} frames")
    _note_detections(summary)
    _warn_strayed(summary, settings)
    _note_physics_floor_height(summary)
    print(f"results in {output}/: live.jsonl, " + ", ".join(Path(p).name for p in summary.files.values()))


def _note_physics_floor_height(summary) -> None:
    """Terminal lines for frames the physics could not explain, an untrusted floor, and the assumed height."""
    if summary.physics_unexplained_frame_count:
        print(f"note: physics: {summary.physics_unexplained_frame_count} frames "
              f"({_first_ranges(summary.physics_unexplained_frames)}) could not be explained by the feet on the "
              "floor (hands, a knee, a seat, a raised floor or a jump off an object?); the kinematic motion is kept "
              "there"
              + (", blended at its edges" if summary.physics == "physcap" else "")
              + " (result.npz physics_unexplained)")
    if summary.floor and not summary.floor.get("trusted", True):
        if summary.floor.get("source") == "unseen feet":
            print("warning: the feet are outside the picture on every frame: the floor is fitted to where the fit "
                  "placed them and is not trusted (give --floor if you know it)")
        else:
            print("warning: the floor fitted to the feet disagrees with the person's own vertical by "
                  f"{summary.floor.get('prior_disagreement_degrees') or float('nan'):.0f} degrees: it is not "
                  "trusted, and the person's vertical is taken as the floor's normal (give --floor if you know it)")
    print(summary.body_height_note)


def _first_ranges(ranges: list[str], shown: int = 6) -> str:
    """'0-2, 170-181, ...': the first `shown` frame ranges of a summary list, for a terminal line."""
    return ", ".join(ranges[:shown]) + (" ..." if len(ranges) > shown else "")


def _note_detections(summary) -> None:
    if summary.foot_swap_frame_count:
        print(f"note: the detector swapped the left and right feet on {summary.foot_swap_frame_count} frames, fitted "
              f"the other way round (frames {_first_ranges(summary.foot_swap_frames)})")
    if summary.repeated_frame_count:
        how = ("fitted as detected" if summary.online
               else "their detections are interpolated between the new pictures around them")
        print(f"note: {summary.repeated_frame_count} frames show the picture before them again (a video converted to "
              f"a higher frame rate?): {how} (frames {_first_ranges(summary.repeated_frames)}; result.npz "
              "repeated_picture)")


def _warn_strayed(summary, settings) -> None:
    if summary.physics_strayed_frames:
        print(f"warning: the physics motion strays more than {settings.physics.stray_distance:g} m from the "
              f"kinematic motion on frames {_first_ranges(summary.physics_strayed_frames)}: it could not follow there "
              "(a floor that does not fit the scene, or wrong contacts)")


def cmd_export(args) -> int:
    from .export import export_result

    options = {}
    if args.units is not None:
        options["units"] = args.units
    if args.root_at_origin:
        options["root_at_origin"] = True
    files = export_result(args.result, args.to, check_output_folder(args.output or args.result.parent), **options)
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return 0


def cmd_evaluate(args) -> int:
    from .evaluation import evaluate, write_evaluation

    out = args.output or args.result.parent / "evaluation.json"
    _check_output_file(out)
    evaluation = evaluate(args.result, args.truth)
    print(f"{'metric':<48} {'final':>12} {'kinematic':>12}")
    for row in evaluation["run"].values():
        final, kinematic = (_number(row[k]) for k in ("final", "kinematic"))
        print(f"{row['label'] + (' (' + row['unit'] + ')' if row['unit'] else ''):<48} {final:>12} {kinematic:>12}")
    for motion, scores in evaluation.get("truth", {}).items():
        print(f"against the truth, {motion} motion: " + ", ".join(f"{k} {_number(v)}" for k, v in scores.items()))
    write_evaluation(out, evaluation)
    print(f"written to {out}")
    return 0


def _check_output_file(path: Path) -> None:
    """Refuse, before any work, an output file whose place is a folder or whose folder cannot be written."""
    if path.is_dir():
        raise OutputLocationError(f"{path}: the output file's name is an existing folder (give a file name).")
    check_output_folder(path.parent)


def _number(value) -> str:
    return "-" if value is None or value != value else f"{value:.4g}"


def cmd_train_contacts(args) -> int:
    if not (args.data / "mocap").is_dir():
        raise InputError(f"{args.data}: no mocap/ folder of training data here (give --data).")
    from .contacts.dataset import ISSUE3_FOLDERS, SyntheticSettings
    from .contacts.train import ContactTrainingSettings, train_contacts  # torch only once there is data

    folders = {"issue3": ISSUE3_FOLDERS, "all": None}.get(args.folders,
                                                             tuple(name for name in args.folders.split(",") if name))
    synthetic = SyntheticSettings(foot_keypoints=args.foot_keypoints)
    train_contacts(args.data, args.out, seed=args.seed,  # the out folder is checked by writing: data first
                   settings=ContactTrainingSettings(folders=folders, synthetic=synthetic))
    print(f"weights written to {args.out}")
    return 0


def cmd_detect(args) -> int:
    from .config import DetectSettings
    from .detect.mediapipe_pose import detect_video

    DetectSettings(max_width=args.max_width, person_box=args.person_box).check()
    _check_output_file(args.output)
    obs = detect_video(args.video, person_box=args.person_box, max_width=args.max_width,
                       progress=_progress_factory()("detect", 0))
    obs.save(args.output)
    repeats = f", {int(obs.repeated.sum())} of them repeat the picture before" if obs.repeated.any() else ""
    print(f"{int(obs.valid.sum())}/{obs.num_frames} frames with a person{repeats}; observations in {args.output}")
    return 0


COMMANDS = {"capture": cmd_capture, "live": cmd_live, "export": cmd_export, "evaluate": cmd_evaluate,
            "train-contacts": cmd_train_contacts, "detect": cmd_detect, "batch": cmd_batch, "retarget": cmd_retarget}


def main(argv: list[str] | None = None) -> int:
    """Run one command; every outcome is an exit code (physmocap.errors) and at most one sentence on stderr."""
    logging.basicConfig(level=logging.WARNING, format="physmocap: %(message)s")
    parser = build_parser()
    try:
        args = parser.parse_args(_join_negative_number_lists(sys.argv[1:] if argv is None else list(argv)))
    except SystemExit as exc:  # --help, --version, or a usage error argparse has already explained
        return exc.code if isinstance(exc.code, int) else 2
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return COMMANDS[args.command](args)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else EXIT_BUG
    except KeyboardInterrupt:
        print("physmocap: interrupted; finished stages are cached and a re-run resumes from them.",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    except BaseException as exc:  # noqa: BLE001 - nothing may escape as a traceback
        error = _user_error(exc, _output_locations(args))
        if error is None:
            return _report_bug(exc, _output_locations(args))
        print(f"physmocap: {error.prefix}: {_one_line(str(error))}", file=sys.stderr)
        return error.exit_code


def _user_error(exc: BaseException, outputs: list[Path]) -> PhysmocapError | None:
    """The user-facing error `exc` stands for, or None when it is a bug."""
    if isinstance(exc, PhysmocapError):
        return exc
    loop = re.fullmatch(r"Symlink loop from '(.*)'", str(exc)) if type(exc) is RuntimeError else None
    if loop:  # Path.resolve's way of saying ELOOP before Python 3.13
        exc = OSError(errno.ELOOP, os.strerror(errno.ELOOP), loop.group(1))
    if isinstance(exc, OSError):
        where = _resolved(exc.filename) if isinstance(exc.filename, (str, Path)) else None
        for folder in outputs:
            if where is not None and (where == folder or folder in where.parents):
                return output_error(exc, folder)
        unreachable = exc.errno in (errno.ENAMETOOLONG, errno.ELOOP)  # a path no file can have
        if where is not None and (isinstance(exc, (PermissionError, IsADirectoryError)) or unreachable):
            return InputError(f"{exc.filename}: cannot be read ({exc.strerror}).")
    if isinstance(exc, MemoryError):
        return InputError("the input is too large for this machine's memory (try a shorter clip).")
    return None


def _resolved(path) -> Path:
    """`path` resolved, or only made absolute where it cannot be (a symlink loop; the handler must not fail)."""
    try:
        return Path(path).resolve()
    except (OSError, RuntimeError):
        return Path(os.path.abspath(path))


def _output_locations(args) -> list[Path]:
    """The folders a command writes into (resolved), for telling write failures from bugs."""
    output = getattr(args, "output", None) or getattr(args, "out", None)
    if output is None and getattr(args, "result", None) is not None:
        output = args.result.parent
    if output is None and args.command == "capture":
        output = Path("runs") / (args.video or args.observations or Path("run")).stem
    if output is None:
        return []
    output = _resolved(output)
    return [output] if args.command in ("capture", "live", "export", "train-contacts", "batch", "retarget") \
        else [output.parent]


def _report_bug(exc: BaseException, outputs: list[Path]) -> int:
    """One sentence asking for a bug report; the traceback goes to a crash log in the run folder (or a temp dir)."""
    import tempfile
    import traceback

    text = (f"physmocap {physmocap.__version__}, {time.strftime('%Y-%m-%d %H:%M:%S')}\n"
            f"command: {' '.join(sys.argv)}\n\n" + "".join(traceback.format_exception(exc)))
    crash_log: Path | None = None
    for folder in [*[f for f in outputs if f.is_dir()], Path(tempfile.gettempdir())]:
        candidate = folder / f"physmocap-crash-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.log"
        try:
            candidate.write_text(text)
        except OSError:
            continue
        crash_log = candidate
        break
    where = f"with the crash log {crash_log}" if crash_log else "(no crash log could be written)"
    print(f"physmocap: internal error ({type(exc).__name__}: {_one_line(str(exc))[:200]}); this is a bug, "
          f"please report it {where}.", file=sys.stderr)
    return EXIT_BUG


def _one_line(text: str) -> str:
    return " ".join(text.split())


if __name__ == "__main__":
    sys.exit(main())
