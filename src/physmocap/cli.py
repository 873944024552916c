"""The command line: `physmocap --help` teaches it."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import physmocap  # noqa: F401 - sets single-threaded BLAS before numpy loads

EXAMPLES = """\
examples:
  physmocap capture video.mp4 -o runs/walk               # offline: whole clip at once (best quality)
  physmocap capture video.mp4 -o runs/walk --online      # causal, frame by frame (live use)
  physmocap capture video.mp4 --height 1.82 --mass 80 --fov 70
  physmocap capture video.mp4 --person-box 100,50,400,700   # follow the person inside this box
  physmocap detect video.mp4 -o obs.npz                  # only the detector; any other detector can
  physmocap capture --observations obs.npz -o runs/x     # ...write this file format and be fitted
  physmocap capture video.mp4 --physics physcap          # PhysCap physics on the offline fit
  physmocap live 0 -o runs/cam                           # live from camera 0: detection, fit, contacts, physics
  physmocap live video.mp4 --max-frames 200              # a file played at its own frame rate, as a camera
  physmocap export runs/walk/result.npz --to glb         # BVH, GLB or OpenSim files from any earlier run
  physmocap evaluate runs/walk/result.npz [--truth truth.npz]   # every metric of a run

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
            raise argparse.ArgumentTypeError(f"{name} must be {count} comma-separated numbers, got '{text}'")
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"{name} must be {count} comma-separated numbers, got '{text}'")
        return values
    return parse


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="physmocap",
        description="Physics-based monocular 3D human motion capture: one person, one static camera, "
                    "global 3D motion out.",
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXAMPLES)
    parser.add_argument("--version", action="version", version=f"physmocap {physmocap.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    cap = sub.add_parser("capture", help="video (or observations file) -> 3D motion, BVH, overlay",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                         description="Capture the 3D motion of one person in a video.")
    cap.add_argument("video", nargs="?", type=Path, help="input video file (mp4, mov, webm, ...)")
    cap.add_argument("-o", "--output", type=Path, default=None,
                     help="run folder (default: runs/<video name>)")
    cap.add_argument("--observations", type=Path, help="fit this observations .npz instead of detecting")
    cap.add_argument("--online", action="store_true", help="causal frame-by-frame fit (live use)")
    cap.add_argument("--physics", choices=("none", "physcap", "trajopt"), default=None,
                     help="physics after the kinematic fit: PhysCap's real-time tracker (default with --online), "
                          "Rempe et al.'s trajectory optimisation of the whole clip, or none (default offline)")
    _add_settings_arguments(cap)
    cap.add_argument("--no-overlay", action="store_true", help="skip rendering overlay.mp4")
    cap.add_argument("--overlay-size", type=int, default=argparse.SUPPRESS, metavar="WIDTH",
                     help="width of overlay.mp4 in pixels: wider videos are scaled down to it, which renders much "
                          "faster than 1080p (0: the video's own width; default 1280)")
    cap.add_argument("--accept-truncated", action="store_true",
                     help="capture the frames a truncated video still holds instead of stopping")

    live = sub.add_parser("live", help="live capture from a camera or a video played at its frame rate",
                          formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                          description="Detection, causal fit, contacts and PhysCap physics frame by frame, with "
                                      "latency and frames per second reported at the end.")
    live.add_argument("source", help="camera index (0, 1, ...) or a video file")
    live.add_argument("-o", "--output", type=Path, default=None,
                      help="folder for live.jsonl (one line per frame as it arrives) and, at the end, result.npz, "
                           "motion.bvh and summary.json")
    live.add_argument("--as-fast-as-possible", action="store_true",
                      help="feed a video file as fast as the pipeline goes instead of at its own frame rate")
    live.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    live.add_argument("--physics", choices=("none", "physcap"), default="physcap")
    live.add_argument("--online", action="store_true", default=True, help=argparse.SUPPRESS)
    _add_settings_arguments(live)

    exp = sub.add_parser("export", help="BVH, GLB or OpenSim files from a result.npz of any earlier run",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    exp.add_argument("result", type=Path, help="a result.npz")
    exp.add_argument("--to", choices=("bvh", "glb", "opensim"), required=True)
    exp.add_argument("-o", "--output", type=Path, default=None, help="folder (default: the result's folder)")
    exp.add_argument("--units", default=None, help="bvh: m or cm; opensim: m or mm")
    exp.add_argument("--root-at-origin", action="store_true", help="bvh, glb: start the root above the origin")

    ev = sub.add_parser("evaluate", help="every metric of a run, against ground truth if given",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ev.add_argument("result", type=Path, help="a result.npz")
    ev.add_argument("--truth", type=Path, default=None,
                    help="truth .npz (joint_names, joints_world, camera_R, camera_t, fps), e.g. a synthetic case")
    ev.add_argument("-o", "--output", type=Path, default=None,
                    help="evaluation JSON to write (default: evaluation.json beside the result)")

    train = sub.add_parser("train-contacts", help="rebuild the contact networks' weights from motion capture",
                           formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                           description="Deterministic training of the causal and centred contact networks on "
                                       "synthetic observations of CMU motion capture (needs torch; about 10 "
                                       "minutes on one core). The same data and seed give the same weights; "
                                       "training.json beside them records the recipe and the held-out scores.")
    train.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[3] / "shared" / "data",
                       help="the shared data folder (with mocap/)")
    train.add_argument("--out", type=Path, default=argparse.SUPPRESS,
                       help="weights folder (default: the shipped weights inside the package, replaced)")
    train.add_argument("--seed", type=int, default=0,
                       help="seed of every random draw (synthetic data, initial weights, batches)")

    det = sub.add_parser("detect", help="run only the 2D/3D keypoint detector and write an observations file",
                         formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    det.add_argument("video", type=Path)
    det.add_argument("-o", "--output", type=Path, required=True, help="observations .npz to write")
    det.add_argument("--person-box", type=_floats(4, "--person-box"), metavar="X0,Y0,X1,Y1",
                     help="follow the person inside this box (pixels)")
    det.add_argument("--max-width", type=int, default=None,
                     help="downscale what the detector sees to this width, pixels (default: native)")
    return parser


def _add_settings_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--height", type=float, default=None, help="person's height in metres (default 1.70)")
    p.add_argument("--mass", type=float, default=None, help="person's mass in kg (default 70)")
    p.add_argument("--focal", type=float, default=None, help="focal length in pixels")
    p.add_argument("--fov", type=float, default=None,
                   help="field of view in degrees across the longer image side (default 60)")
    p.add_argument("--floor", type=_floats(4, "--floor"), metavar="NX,NY,NZ,D",
                   help="floor plane n.x + d = 0 in camera coordinates, metres (default: estimated from the feet)")
    p.add_argument("--person-box", type=_floats(4, "--person-box"), metavar="X0,Y0,X1,Y1",
                   help="follow the person inside this box (pixels)")
    p.add_argument("--one-euro", action="store_true", help="One-Euro filter the fitted pose")
    p.add_argument("--preset", choices=("walking", "running", "jumping", "dancing", "standing"),
                   help="settings suited to the activity (see physmocap/presets.py)")
    p.add_argument("--smoothing", type=float, default=None,
                   help="smoothing strength, 1 = default, 0 = none, up to 100")
    p.add_argument("--foot-lock", choices=("auto", "always", "never"), default=None,
                   help="contacts for physics: predicted (auto), whenever a sole is near the floor (always), "
                        "or none, e.g. airborne or swimming motion (never)")
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
    camera = {k: v for k, v in (("focal", args.focal), ("fov", args.fov), ("floor", args.floor)) if v is not None}
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
    physics = getattr(args, "physics", None) or ("physcap" if s.online else None)
    if physics is not None:
        s = s.replace("physics", method=physics)
    return s.check()


def _progress_factory(enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    bars = []

    def factory(name: str, total: int):
        bar = tqdm(total=total or None, desc=f"{name:>8}", unit="frame", leave=True, file=sys.stderr,
                   dynamic_ncols=True)
        bars.append(bar)

        def update(done: int, total_now: int):
            if total_now and bar.total != total_now:
                bar.total = total_now
            bar.update(done - bar.n)
            if total_now and done >= total_now:
                bar.close()
        return update
    return factory


def cmd_capture(args) -> int:
    from .errors import InputError
    from .io.video import probe_video
    from .pipeline import run_capture

    if args.video is None and args.observations is None:
        raise InputError("capture needs a video file or --observations FILE.")
    settings = settings_from_args(args)
    if args.video is not None:
        probe_video(args.video)  # fail fast, before any folder is made
    name = (args.video or args.observations).stem
    out = args.output or Path("runs") / name
    summary = run_capture(out, settings, video=args.video, observations=args.observations,
                          overlay=not args.no_overlay, progress=_progress_factory(sys.stderr.isatty()))
    invalid = summary.frames - summary.valid_frames
    print(f"captured {summary.valid_frames}/{summary.frames} frames at {summary.fps:.1f} fps "
          f"({'online' if summary.online else 'offline'} fit, physics: {summary.physics})")
    if invalid:
        details = "; ".join(f"{reason}: frames {_first_ranges(r)}" for reason, r in summary.invalid_frames.items())
        print(f"warning: {invalid} frames could not be reconstructed and are flagged invalid ({details})")
    _note_foot_swaps(summary)
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
    print(f"median reprojection error {summary.median_reprojection_error_px:.1f} px "
          f"({summary.median_reprojection_error_percent_of_height:.2f}% of the person's height)"
          + (f"; after physics {summary.median_reprojection_error_final_px:.1f} px" if summary.physics != "none"
             else ""))
    times = ", ".join(f"{k} {v:.1f} s" for k, v in summary.stage_seconds.items())
    print(f"time: {times}" + (f" (cached: {', '.join(summary.cached_stages)})" if summary.cached_stages else ""))
    print(f"results in {out}/: " + ", ".join(Path(p).name for p in summary.files.values()))
    return 0


def cmd_live(args) -> int:
    import json
    import time

    import numpy as np

    from .errors import InputError
    from .live import stream_capture
    from .pipeline import write_outputs

    settings = settings_from_args(args)
    if args.max_frames is not None and args.max_frames < 1:
        raise InputError(f"--max-frames must be at least 1, got {args.max_frames}.")
    source = args.source
    if not source.isdigit():
        from .io.video import probe_video

        probe_video(source)
    stream = None
    if args.output is not None:
        args.output.mkdir(parents=True, exist_ok=True)
        stream = open(args.output / "live.jsonl", "w")  # a log written as frames arrive, not a result file
    started = time.perf_counter()

    def on_pose(index, qpos, details):
        if stream is None:
            return
        line = dict(frame=index, seconds=round(time.perf_counter() - started, 4), root=qpos[:3].round(4).tolist(),
                    contacts=details["contacts"].tolist(), stationary=details["stationary"])
        if "grf" in details:
            line["grf_total_n"] = details["grf"].sum(axis=0).round(2).tolist()
        stream.write(json.dumps(line) + "\n")
        stream.flush()

    try:
        report = stream_capture(source, settings, realtime=not args.as_fast_as_possible,
                                max_frames=args.max_frames, on_pose=on_pose)
    finally:
        if stream is not None:
            stream.close()
    T = report.observations.num_frames
    print(f"live: {T} frames at {report.frames_per_second:.1f} frames per second; latency median "
          f"{report.latency_median_ms:.0f} ms, 95th percentile {report.latency_p95_ms:.0f} ms "
          f"(after the {report.warmup_frames}-frame calibration warm-up)")
    print(f"per frame: detect {report.detect_ms_per_frame:.1f} ms, fit {report.fit_ms_per_frame:.1f} ms, "
          f"contacts and physics {report.contacts_physics_ms_per_frame:.1f} ms")
    if args.output is not None:
        seconds = {"detect": report.detect_ms_per_frame * T / 1000, "kinematics": report.motion.seconds,
                   "contacts_physics": report.contacts_physics_ms_per_frame * T / 1000}
        summary = write_outputs(args.output, str(source), report.observations, report.motion, report.contacts,
                                report.stationary, report.physics, settings, seconds, [])
        if report.physics is not None and np.any(report.physics.qp_failures):
            print(f"warning: the physics QP fell back on {int(np.sum(report.physics.qp_failures > 0))} frames")
        _note_foot_swaps(summary)
        _warn_strayed(summary, settings)
        print(f"results in {args.output}/: live.jsonl, " + ", ".join(Path(p).name for p in summary.files.values()))
    return 0


def _first_ranges(ranges: list[str], shown: int = 6) -> str:
    """'0-2, 170-181, ...': the first `shown` frame ranges of a summary list, for a terminal line."""
    return ", ".join(ranges[:shown]) + (" ..." if len(ranges) > shown else "")


def _note_foot_swaps(summary) -> None:
    if summary.foot_swap_frame_count:
        print(f"note: the detector swapped the left and right feet on {summary.foot_swap_frame_count} frames, fitted "
              f"the other way round (frames {_first_ranges(summary.foot_swap_frames)})")


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
    files = export_result(args.result, args.to, args.output or args.result.parent, **options)
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return 0


def cmd_evaluate(args) -> int:
    from .evaluation import evaluate, write_evaluation

    evaluation = evaluate(args.result, args.truth)
    print(f"{'metric':<48} {'final':>12} {'kinematic':>12}")
    for row in evaluation["run"].values():
        final, kinematic = (_number(row[k]) for k in ("final", "kinematic"))
        print(f"{row['label'] + (' (' + row['unit'] + ')' if row['unit'] else ''):<48} {final:>12} {kinematic:>12}")
    for motion, scores in evaluation.get("truth", {}).items():
        print(f"against the truth, {motion} motion: " + ", ".join(f"{k} {_number(v)}" for k, v in scores.items()))
    out = args.output or args.result.parent / "evaluation.json"
    write_evaluation(out, evaluation)
    print(f"written to {out}")
    return 0


def _number(value) -> str:
    return "-" if value is None or value != value else f"{value:.4g}"


def cmd_train_contacts(args) -> int:
    from .contacts.predict import WEIGHTS_DIR
    from .contacts.train import train_contacts
    from .errors import InputError

    if not (args.data / "mocap").is_dir():
        raise InputError(f"{args.data}: no mocap/ folder of training data here (give --data).")
    out = getattr(args, "out", WEIGHTS_DIR)
    train_contacts(args.data, out, seed=args.seed)
    print(f"weights written to {out}")
    return 0


def cmd_detect(args) -> int:
    from .config import DetectSettings
    from .detect.mediapipe_pose import detect_video

    DetectSettings(max_width=args.max_width, person_box=args.person_box).check()
    factory = _progress_factory(sys.stderr.isatty())
    obs = detect_video(args.video, person_box=args.person_box, max_width=args.max_width,
                       progress=factory("detect", 0) if factory else None)
    obs.save(args.output)
    print(f"{int(obs.valid.sum())}/{obs.num_frames} frames with a person; observations in {args.output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    from .errors import InputError, ReconstructionError

    logging.basicConfig(level=logging.WARNING, format="physmocap: %(message)s")
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        commands = {"capture": cmd_capture, "live": cmd_live, "export": cmd_export, "evaluate": cmd_evaluate,
                    "train-contacts": cmd_train_contacts, "detect": cmd_detect}
        return commands[args.command](args)
    except InputError as exc:
        print(f"physmocap: error: {exc}", file=sys.stderr)
        return 2
    except ReconstructionError as exc:
        print(f"physmocap: could not reconstruct: {exc}", file=sys.stderr)
        return 3
    except KeyboardInterrupt:
        print("physmocap: interrupted; finished stages are cached and a re-run resumes from them.",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
