"""Retargeting onto characters (issue 19): every test rig on synthetic clips and real videos, with and without
physics on the character.

Sources (result.npz of the default capture, PhysCap on the B.4-refined motion, which is what a user retargets;
`--source-physics none` for the kinematic fit alone; run here through the pipeline and cached in the work folder):
synthetic clips (CMU motion capture seen by a random camera with detector-like noise, as bench_synthetic) and real
videos. Rigs: a Mixamo-named rig (our own motion.bvh export, "mixamorig:" names, centimetres), the Daz skeleton of
cmu_daz_cgspeed and the Character Creator skeleton of cmu_iclone_cc3_retarget (tests/data), a cartoon (short legs,
large head, long arms) with de Leva's mass distribution and with 40 % of 36.5 kg in its head (Rempe E.6's Ty), and
a skinned GLB mannequin. Figures per source x rig x physics: foot skate and penetration on the character (Rempe's
metrics against the source's contacts), contact point-frames kept, mean bone-direction cosine to the source (rig
joints), largest bone-length change, mean GRF in the character's body weights, centre-of-mass height over hip
height, how far the character's path leaves the source's (pelvis along the floor, at the source's size), time per
frame of the retargeting (IK) and of the physics.

    .venv/bin/python benchmarks/bench_retarget.py [--quick] [--trajopt] [--source-physics physcap|none] [--work DIR]
        [--set test|validation|every] [--step-adjustment LEG_LENGTHS]

Writes benchmarks/results/retarget.json and retarget.md (retarget_SET.* with another --set; with --quick,
retarget[_SET]_quick.*, so that a quick look leaves the stored full tables alone).
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_synthetic import CLIPS as SYNTHETIC_TEST_SET  # noqa: E402
from common import MOCAP, RESULTS, VIDEOS, machine_description  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.body.model import CONTACT_POINTS, SkeletonLengths, build_body_model, template_lengths  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.export import body_from_result  # noqa: E402
from physmocap.io.bvh_export import write_bvh  # noqa: E402
from physmocap.io.glb import write_glb  # noqa: E402
from physmocap.metrics import GRAVITY, foot_contact_errors, mean_acceleration  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import make_observations, random_camera, resample  # noqa: E402
from physmocap.motion import valid_runs  # noqa: E402
from physmocap.pipeline import run_capture  # noqa: E402
from physmocap.result import load_result  # noqa: E402
from physmocap.retarget import retarget_result, solve  # noqa: E402
from physmocap.retarget.stage import follows_gap  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TEST_DATA = REPO / "tests" / "data"
SYNTHETIC = ("cmu_raw_cgspeed/131_01.bvh", "cmu_iclone_cc3_retarget/006_01.bvh")
REAL = ("hybrik_taiji.mp4", "sports2d_demo.mp4", "intel_highcam_walk_stand.mp4")
# Where retargeting's own constants are chosen: walks of CMU training subjects 2 and 7, and taiji.
VALIDATION_SYNTHETIC = ("cmu_raw_cgspeed/02_01.bvh", "cmu_iclone_cc3_retarget/007_01.bvh")
VALIDATION_REAL = ("hybrik_taiji.mp4",)
# --set every: the whole synthetic test set and every shared video (about 15 minutes).
EVERY_SYNTHETIC = SYNTHETIC_TEST_SET
EVERY_REAL = REAL + ("mmhuman3d_single_person_demo.mp4", "sam2_soccer_juggling.mp4",
                     "pose2sim_demo_singleperson/cam01.mp4")
FPS, SECONDS = 30.0, 8.0
CARTOON = dict(hip_width=0.16, thigh=0.22, shank=0.20, ankle_height=0.05, heel_back=0.03, toe_front=0.12,
               spine_low=0.06, spine_up=0.30, shoulder_width=0.30, upper_arm=0.33, forearm=0.31, hand_length=0.09,
               hand_width=0.04, head_height=0.20, head_top=0.22, ear_width=0.16, nose_forward=0.14, nose_down=-0.02,
               eye_forward=0.11, eye_up=0.06, eye_width=0.04)
TRAJOPT_RIGS = ("mixamo", "cartoon 40% head")  # trajopt takes about 0.25 s per frame: two rigs, two sources
TRAJOPT_SOURCES = ("synthetic 131_01", "real hybrik_taiji")
HEAVY_HEAD = "[mass]\ntotal = 36.5\n[mass.fractions]\nhead = 0.40\n"


def make_rigs(work: Path) -> dict[str, tuple[Path, Path | None]]:
    """Rig name -> (character file, TOML map or None)."""
    rigs = work / "rigs"
    rigs.mkdir(parents=True, exist_ok=True)
    human = build_body_model(template_lengths(1.60), 60.0)
    write_bvh(rigs / "mixamo.bvh", human, human.rest_qpos[None], 30.0, units="cm")
    text = (rigs / "mixamo.bvh").read_text()
    (rigs / "mixamo.bvh").write_text(text.replace("ROOT ", "ROOT mixamorig:").replace("JOINT ", "JOINT mixamorig:"))
    cartoon = build_body_model(SkeletonLengths(**CARTOON), 36.5)
    write_bvh(rigs / "cartoon.bvh", cartoon, cartoon.rest_qpos[None], 30.0, units="cm")
    (rigs / "heavy_head.toml").write_text(HEAVY_HEAD)
    mannequin = build_body_model(template_lengths(1.58), 55.0)
    write_glb(rigs / "mannequin.glb", mannequin, mannequin.rest_qpos[None], 30.0)
    return {"mixamo": (rigs / "mixamo.bvh", None), "daz": (TEST_DATA / "rig_daz_cgspeed.bvh", None),
            "cc3": (TEST_DATA / "rig_cc3_iclone.bvh", None), "cartoon de Leva": (rigs / "cartoon.bvh", None),
            "cartoon 40% head": (rigs / "cartoon.bvh", rigs / "heavy_head.toml"),
            "glb mannequin": (rigs / "mannequin.glb", None)}


def source_settings(physics: str) -> Settings:
    """The capture settings of a source: the defaults, with the physics method `physics`."""
    return Settings().replace("physics", method=physics)


def synthetic_source(name: str, work: Path, physics: str, seed: int = 0) -> Path:
    """result.npz of the pipeline (offline fit, then `physics`) on synthetic observations of a mocap clip."""
    out = work / f"sources_{physics}" / Path(name).stem
    if (out / "result.npz").is_file():
        return out / "result.npz"
    clip = resample(load_mocap(MOCAP / name), FPS)
    frames = int(SECONDS * FPS)
    import dataclasses

    clip = dataclasses.replace(clip, positions=clip.positions[:frames], head_rotation=clip.head_rotation[:frames],
                               hand_rotations=clip.hand_rotations[:frames])
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, _ = make_observations(clip, K, R, t, rng)
    out.mkdir(parents=True, exist_ok=True)
    obs.save(out / "observations.npz")
    run_capture(out, source_settings(physics), observations=out / "observations.npz", overlay=False)
    return out / "result.npz"


def real_source(video: str, work: Path, physics: str) -> Path:
    """result.npz of `capture VIDEO --physics PHYSICS --no-overlay`."""
    out = work / f"sources_{physics}" / Path(video).stem
    if not (out / "result.npz").is_file():
        run_capture(out, source_settings(physics), video=VIDEOS / video, overlay=False)
    return out / "result.npz"


def source_feet(result: dict) -> dict:
    """The source capture's own heel and toe points against its own contact labels, frames with a person: Rempe's
    skate and penetration, its contact runs whose point slid more than 10 cm from where it touched down, and its
    joints' jitter."""
    body = body_from_result(result)
    feet = kin.forward_kinematics(body, result["qpos"]).points[:, body.point_index(CONTACT_POINTS)]
    valid, contacts = np.asarray(result["valid"], bool), np.asarray(result["contacts"], bool)
    errors = foot_contact_errors(feet[valid], contacts[valid], float(result["fps"]), breaks=follows_gap(valid))
    drifts = [float(np.linalg.norm(feet[s:e, k, :2] - feet[s, k, :2], axis=1).max())
              for k in range(len(CONTACT_POINTS)) for s, e in valid_runs(contacts[:, k])]
    return dict(skate_percent=errors["skate_percent"], penetration_percent=errors["penetration_percent"],
                contact_runs=len(drifts), runs_sliding_over_10cm=sum(d > 0.1 for d in drifts),
                largest_slide_m=max(drifts, default=0.0), jitter=jitter(result))


def jitter(result: dict) -> float:
    """m/s^2: mean acceleration of the result's joints (metrics.mean_acceleration) over the frames with a person."""
    valid = np.asarray(result["valid"], bool)
    return float(mean_acceleration(result["joints_world"][valid], float(result["fps"])))


def needed_force_percent_bw(result: dict, frames: int = 9) -> float:
    """Mean magnitude of the net external force the result's centre of mass needs, m |a + g|, in body weights (%),
    its path averaged over `frames` frames first so that no frame-to-frame chatter counts; frames with a person."""
    com = result["center_of_mass"]
    kernel = np.ones(frames) / frames
    smooth = np.stack([np.convolve(com[:, i], kernel, "same") for i in range(3)], axis=1)
    acceleration = np.zeros_like(smooth)
    acceleration[1:-1] = (smooth[2:] - 2 * smooth[1:-1] + smooth[:-2]) * float(result["fps"]) ** 2
    keep = np.asarray(result["valid"], bool).copy()
    keep[:frames], keep[-frames:] = False, False  # the average is cut short at the ends
    need = acceleration[keep] + np.array([0.0, 0.0, GRAVITY])
    return float(100 * np.linalg.norm(need, axis=1).mean() / GRAVITY)


def run(work: Path, quick: bool, trajopt: bool, source_physics: str, source_set: str = "test") -> dict:
    rigs = make_rigs(work)
    synthetic, real = {"test": (SYNTHETIC, REAL), "validation": (VALIDATION_SYNTHETIC, VALIDATION_REAL),
                       "every": (EVERY_SYNTHETIC, EVERY_REAL)}[source_set]
    sources = {f"synthetic {Path(n).stem}": synthetic_source(n, work, source_physics)
               for n in synthetic[: 1 if quick else None]}
    sources.update({f"real {Path(v).stem}": real_source(v, work, source_physics) for v in real[: 1 if quick else None]})
    methods = ["none", "physcap"] + (["trajopt"] if trajopt else [])
    rows = []
    for source_name, source in sources.items():
        for rig_name, (rig, toml) in rigs.items():
            for method in methods:
                if method == "trajopt" and (rig_name not in TRAJOPT_RIGS or source_name not in TRAJOPT_SOURCES):
                    continue
                out = (work / f"out_{source_physics}" / source_name.replace(" ", "_") / rig_name.replace(" ", "_")
                       / method)
                started = time.perf_counter()
                report = retarget_result(source, rig, out, character_map=toml, physics=method)
                wall = time.perf_counter() - started
                result = load_result(report.files["result"])
                hips = result["joints_world"][:, [10, 15], 2].mean()
                row = dict(source=source_name, rig=rig_name, **report.metrics,
                           com_over_hip_height=float(result["center_of_mass"][:, 2].mean() / hips),
                           needed_force_percent_bw=needed_force_percent_bw(result),
                           jitter=jitter(result),
                           mass_kg=report.character["mass_kg"], height_m=report.character["height_m"],
                           wall_seconds=wall)
                rows.append(row)
                print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()}),
                      flush=True)
    com = []
    for source_name in sources:
        paths = {}
        for rig_name in ("mixamo", "cartoon de Leva", "cartoon 40% head"):
            out = (work / f"out_{source_physics}" / source_name.replace(" ", "_") / rig_name.replace(" ", "_")
                   / "physcap")
            result = load_result(out / "result.npz")
            paths[rig_name] = result["center_of_mass"] / float(result["retarget_scale"])  # at the source's size
        com.append(dict(source=source_name, **{
            f"{a} vs {b} mean COM distance at source size (cm)": float(100 * np.linalg.norm(
                paths[a] - paths[b], axis=1).mean())
            for a, b in (("cartoon 40% head", "mixamo"), ("cartoon de Leva", "mixamo"),
                         ("cartoon 40% head", "cartoon de Leva"))}))
    own = {name: source_feet(load_result(path)) for name, path in sources.items()}
    return dict(machine=machine_description(), source_set=source_set,
                source_physics=source_physics, rows=rows, com_paths=com, sources=own)


def markdown(data: dict) -> str:
    lines = ["# Retargeting (issue 19)", "", f"Machine: {data['machine']}", "",
             f"Sources ({data.get('source_set', 'test')} set): capture with physics {data['source_physics']}. "
             "GRF % BW: mean magnitude of the net force (Rempe's measure); vertical: its vertical component; "
             "explained: the magnitude / the vertical component over the frames the character's physics explains "
             "(flagged frames, handed back as kinematic motion, left out; their count in brackets); "
             "residual: the root's vertical residual force; needed: the mean net external force the character's "
             "centre of mass needs, its path averaged over 9 frames (no GRF within 95-105% is possible where it is "
             "outside).", "",
             "| source | rig | physics | skate % | penetration % | contacts kept % | bone cos | bone length err (m) "
             "| GRF % BW | vertical | explained (flagged) | residual | needed | COM / hip height "
             "| path departure mean / max (m) | jitter m/s² | IK ms/frame | physics ms/frame |",
             "|" + "---|" * 18]
    for r in data["rows"]:
        explained = [r.get(k) for k in ("grf_explained_mean_percent_bw", "grf_vertical_explained_mean_percent_bw")]
        grf = "- | - | - | - | -" if r["grf_mean_percent_bw"] is None else (
            f"{r['grf_mean_percent_bw']:.1f} | {r['grf_vertical_mean_percent_bw']:.1f} | "
            f"{' / '.join('-' if e is None else f'{e:.1f}' for e in explained)} ({r.get('unexplained_frames', 0)}) | "
            f"{r['residual_vertical_mean_percent_bw']:.1f} | {r['needed_force_percent_bw']:.1f}")
        kept = "-" if r["contact_frames_kept"] is None else f"{100 * r['contact_frames_kept']:.1f}"
        lines.append(f"| {r['source']} | {r['rig']} | {r['physics']} | {r['skate_percent']:.2f} | "
                     f"{r['penetration_percent']:.2f} | {kept} | {r['bone_cosine_rig']:.4f} | "
                     f"{r['bone_length_error_m']:.1e} | {grf} | {r['com_over_hip_height']:.3f} | "
                     f"{r['path_departure_mean_m']:.2f} / {r['path_departure_max_m']:.2f} | "
                     f"{r.get('jitter', np.nan):.1f} | {r['retarget_ms_per_frame']:.1f} | {r['physics_ms_per_frame']:.1f} |")
    lines += ["", "The sources' own feet (their heel and toe points against their own contact labels, frames with a "
              "person):", "",
              "| source | skate % | penetration % | contact runs sliding > 10 cm / all | largest slide (m) | jitter m/s² |",
              "|---|---|---|---|---|---|"]
    for name, own in data.get("sources", {}).items():
        lines.append(f"| {name} | {own['skate_percent']:.2f} | {own['penetration_percent']:.2f} | "
                     f"{own['runs_sliding_over_10cm']} / {own['contact_runs']} | {own['largest_slide_m']:.2f} | "
                     f"{own.get('jitter', np.nan):.1f} |")
    lines += ["", "Centre-of-mass paths (PhysCap), both scaled back to the source's size:", ""]
    for c in data["com_paths"]:
        lines.append(f"- {c['source']}: " + "; ".join(f"{k} {v:.1f}" for k, v in c.items() if k != "source"))
    physcap = [r for r in data["rows"] if r["physics"] == "physcap"]
    lines += ["", f"Median IK {statistics.median(r['retarget_ms_per_frame'] for r in physcap):.1f} ms/frame, "
                  f"PhysCap {statistics.median(r['physics_ms_per_frame'] for r in physcap):.1f} ms/frame."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="one synthetic clip and one video")
    parser.add_argument("--set", choices=("test", "validation", "every"), default="test",
                        help="sources: the test clips and videos; the validation clips (CMU subjects 2 and 7) and "
                             "taiji, where retargeting's constants are chosen; or every clip of the synthetic test "
                             "set and every shared video")
    parser.add_argument("--trajopt", action="store_true",
                        help="also trajectory optimisation (two rigs on two sources; several minutes)")
    parser.add_argument("--source-physics", choices=("physcap", "none"), default=Settings().physics.method,
                        help="physics of the sources' capture (default: the pipeline's default)")
    parser.add_argument("--step-adjustment", type=float, default=None,
                        help="leg lengths a footstep may land nearer the source's footprint (retarget.solve."
                             "STEP_ADJUSTMENT, default its value): to choose it on --set validation")
    parser.add_argument("--work", type=Path, default=Path("/tmp/physmocap_bench_retarget"),
                        help="folder for the sources' runs and the outputs (reused when present)")
    args = parser.parse_args(argv)
    if args.step_adjustment is not None:
        solve.STEP_ADJUSTMENT = args.step_adjustment
    data = run(args.work, args.quick, args.trajopt, args.source_physics, args.set)
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = ("retarget" if args.set == "test" else f"retarget_{args.set}") + ("_quick" if args.quick else "")
    (RESULTS / f"{stem}.json").write_text(json.dumps(data, indent=1))
    (RESULTS / f"{stem}.md").write_text(markdown(data))
    print(markdown(data))
    return data


if __name__ == "__main__":
    main()
