"""OUT/report.html: one page per run that links every output and shows the run's metrics.

The metrics need no ground truth (all from `physmocap.metrics`), each for the final motion and for the kinematic
motion before physics: jitter (mean joint acceleration), foot floating / penetration / skate against the floor
z = 0 and the contacts used, penetration error, ground reaction forces (solved by physics, and implied by the
centre of mass), the share of supported frames whose centre of mass is over the support polygon, the root force
physics could not explain, and the reprojection error against the detected keypoints.
"""

from __future__ import annotations

import html
import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import metrics
from ..body.kinematics import center_of_mass, forward_kinematics
from ..body.model import CONTACT_POINTS, JOINT_NAMES, BodyModel
from ..export import body_from_result
from ..io.atomic import write_text
from ..io.finite import finite_result, json_text
from ..landmarks import LANDMARK_INDEX
from .plots import write_plots
from .viewer import com_over_support, support_polygons

KEYPOINT_MIN_CONFIDENCE = 0.5  # detections below this confidence do not count for the reprojection error

# Output files a run folder may hold, in the order the report lists them: file name -> what it is.
RUN_FILES: dict[str, str] = {
    "viewer.html": "3D viewer (opens offline in a browser)",
    "overlay.mp4": "overlay video: skeleton, contacts and forces on the input",
    "result.npz": "result file (every array of the run)",
    "motion.bvh": "BVH animation (Mixamo names, Y up)",
    "motion.glb": "glTF binary: skinned mannequin (metres, Y up)",
    "markers.trc": "OpenSim marker trajectories",
    "grf.mot": "OpenSim ground reaction forces (one force plate per foot)",
    "external_loads.xml": "OpenSim ExternalLoads applying grf.mot to calcn_r / calcn_l",
    "summary.json": "run summary",
    "metrics.json": "the metrics below, as JSON",
}


@dataclass(frozen=True)
class Metric:
    """One row of the report: values of the final and the kinematic motion (None: does not apply)."""

    key: str
    section: str
    label: str
    unit: str
    final: float | None
    kinematic: float | None
    meaning: str


def _point_ids(result: dict[str, np.ndarray], names) -> list[int]:
    all_names = [str(n) for n in result["joint_names"]]
    return [all_names.index(n) for n in names]


def _keypoint_pairs(result: dict[str, np.ndarray]) -> tuple[list[int], list[int]]:
    """Result points and the detector landmarks at the same place (the toe is MediaPipe's foot_index)."""
    points, landmarks = [], []
    for index, name in enumerate(str(n) for n in result["joint_names"]):
        landmark = name.replace("_toe", "_foot_index")
        if landmark in LANDMARK_INDEX:
            points.append(index)
            landmarks.append(LANDMARK_INDEX[landmark])
    return points, landmarks


METRIC_ROWS: tuple[tuple[str, str, str, str, str], ...] = (  # key, section, label, unit, meaning; in report order
    ("mean_acceleration", "Smoothness", "mean joint acceleration", "m/s²",
     "jitter without ground truth: mean |second difference| × fps² over the 20 joints; lower is smoother"),
    ("floating_percent", "Feet and floor", "floating", "% foot-frames",
     "in contact yet more than 3 cm above the floor (Rempe et al. 2020)"),
    ("penetration_percent", "Feet and floor", "penetration", "% foot-frames",
     "more than 3 cm below the floor at any time (Rempe et al. 2020)"),
    ("skate_percent", "Feet and floor", "skate", "% foot-frames",
     "in contact in two frames and sliding more than 2 cm per 1/30 s (Rempe et al. 2020)"),
    ("mpe", "Feet and floor", "mean penetration error", "mm",
     "mean distance of the contact points from the floor while in contact (PhysCap MPE)"),
    ("pnp_percent", "Feet and floor", "non-penetration", "% frames",
     "frames with no foot point below the floor (PhysCap PNP)"),
    ("grf_mean_percent_bw", "Forces", "solved GRF, mean", "% body weight",
     "net ground reaction force from physics, mean over frames (about 100 over a whole clip)"),
    ("grf_max_percent_bw", "Forces", "solved GRF, maximum", "% body weight", "its largest value"),
    ("grf_ballistic_percent_bw", "Forces", "solved GRF in flight", "% body weight",
     "median over frames without contact (ideal 0)"),
    ("implied_grf_mean_percent_bw", "Forces", "implied GRF, mean", "% body weight",
     "net external force m (a_com − g) the motion's centre of mass implies (Rempe et al. 2020)"),
    ("implied_grf_max_percent_bw", "Forces", "implied GRF, maximum", "% body weight",
     "its largest value: spikes mean jitter"),
    ("implied_grf_ballistic_percent_bw", "Forces", "implied GRF in flight", "% body weight",
     "median over frames without contact (ideal 0)"),
    ("residual_force_percent_bw", "Forces", "residual root force", "% body weight",
     "mean force physics had to apply directly to the pelvis (unexplained by contacts)"),
    ("com_over_support_percent", "Balance", "centre of mass over support", "% supported frames",
     "the centre of mass projects within 5 cm of the support polygon of the contact points"),
    ("reprojection_error", "Image agreement", "reprojection error", "px",
     "mean distance of the projected points to the detected keypoints (confidence ≥ 0.5)"),
)


def run_metrics(result: dict[str, np.ndarray]) -> list[Metric]:
    """The report's metrics for a result (see the module docstring)."""
    mass = float(result["body_mass"])
    contacts = np.asarray(result["contacts"], bool)
    motions = {"final": (result["joints_world"], result["qpos"]),
               "kinematic": (result["joints_world_kinematic"], result.get("qpos_kinematic", result["qpos"]))}
    values: dict[str, dict[str, float]] = {}
    body = body_from_result(result)
    for motion, (points, qpos) in motions.items():
        for key, value in _motion_metrics(result, body, points, qpos, contacts).items():
            values.setdefault(key, {})[motion] = value
    if np.any(np.asarray(result["grf"]) != 0):  # physics ran
        solved = metrics.grf_statistics(result["grf"], mass, contacts)
        residual = np.linalg.norm(np.asarray(result["residual_root_force"])[:, :3], axis=1)
        for key, value in (("grf_mean_percent_bw", solved["mean_percent_bw"]),
                           ("grf_max_percent_bw", solved["max_percent_bw"]),
                           ("grf_ballistic_percent_bw", solved["ballistic_percent_bw"]),
                           ("residual_force_percent_bw", 100 * residual.mean() / (mass * metrics.GRAVITY))):
            values[key] = {"final": float(value)}
    return [Metric(key, section, label, unit, values[key].get("final"), values[key].get("kinematic"), meaning)
            for key, section, label, unit, meaning in METRIC_ROWS if key in values]


def _motion_metrics(result: dict[str, np.ndarray], body: BodyModel, points: np.ndarray, qpos: np.ndarray,
                    contacts: np.ndarray) -> dict[str, float]:
    """The metrics of one motion of the result: its named points (T, P, 3) and qpos (T, nq)."""
    fps, mass = float(result["fps"]), float(result["body_mass"])
    joints, feet = _point_ids(result, JOINT_NAMES), _point_ids(result, CONTACT_POINTS)
    kp_points, kp_landmarks = _keypoint_pairs(result)
    keypoints = np.asarray(result["keypoints_2d"], dtype=float)[:, kp_landmarks]
    keypoints = np.where(np.asarray(result["valid"], bool)[:, None, None], keypoints, 0.0)
    accelerations = len(contacts) >= 3  # second differences need three frames; shorter runs leave those out
    out: dict[str, float] = {}
    if accelerations:
        out["mean_acceleration"] = metrics.mean_acceleration(points[:, joints], fps)
    foot = metrics.foot_contact_errors(points[:, feet], contacts, fps=fps)
    for name in ("floating_percent", "penetration_percent", "skate_percent"):
        out[name] = foot[name]
    mpe, _, pnp = metrics.mpe_pnp(points[:, feet], contacts)
    out["mpe"], out["pnp_percent"] = 1000 * mpe, pnp
    com = center_of_mass(body, forward_kinematics(body, qpos))
    if accelerations:
        implied = metrics.grf_statistics(metrics.implied_grf(com, mass, fps), mass, contacts)
        out["implied_grf_mean_percent_bw"] = implied["mean_percent_bw"]
        out["implied_grf_max_percent_bw"] = implied["max_percent_bw"]
        out["implied_grf_ballistic_percent_bw"] = implied["ballistic_percent_bw"]
    vertices, counts = support_polygons(points[:, feet], contacts)
    supported = counts > 0
    over = com_over_support(com, vertices, counts)
    out["com_over_support_percent"] = 100 * over[supported].mean() if supported.any() else math.nan
    out["reprojection_error"], _ = metrics.reprojection_error(
        points[:, kp_points], result["camera_K"], result["camera_R"], result["camera_t"], keypoints,
        KEYPOINT_MIN_CONFIDENCE)
    return {key: float(value) for key, value in out.items()}


def _number(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"


# camera.Floor.source -> what the report says of it
FLOOR_SOURCES = {"feet and posture": "fitted to the feet, its tilt pulled towards the person's vertical",
                 "feet": "fitted to the feet", "contacts": "fitted to the feet in contact (Rempe et al.'s B.4)",
                 "given": "given by the user", "posture": "level with the person's own vertical",
                 "unseen feet": "fitted to where the fit placed feet that were never in the picture"}


def floor_sentence(result: dict[str, np.ndarray]) -> str:
    """One sentence on the floor the motion stands on and how far it is trusted (result.npz floor_confidence;
    empty for a result file without it)."""
    if "floor_confidence" not in result:
        return ""
    floor = json.loads(str(result["floor_confidence"]))
    sentence = f"Floor: {FLOOR_SOURCES.get(floor.get('source'), html.escape(str(floor.get('source'))))}"
    if floor.get("trusted", True):
        return sentence + "."
    why = ("the feet were outside the picture on every frame" if floor.get("source") == "unseen feet" else
           f"the plane of the feet leant {floor.get('prior_disagreement_degrees') or float('nan'):.0f} degrees from it")
    return sentence + f"; <strong>not trusted</strong> ({why}): give it with --floor if it is known."


def report_html(run_dir: Path, result: dict[str, np.ndarray], rows: list[Metric], plots: dict[str, str]) -> str:
    """The report page; links are relative to `run_dir`, where it is written."""
    fps, frames = float(result["fps"]), len(result["joints_world"])
    valid = int(np.asarray(result["valid"], bool).sum())
    physics = str(result.get("physics", "none"))
    stage_seconds = json.loads(str(result["stage_seconds"]))
    links = "\n".join(f'<li><a href="{html.escape(name)}">{html.escape(name)}</a> — {html.escape(what)}</li>'
                      for name, what in RUN_FILES.items() if (run_dir / name).is_file())
    table, section = [], None
    for row in rows:
        if row.section != section:
            section = row.section
            table.append(f'<tr class="section"><th colspan="5">{html.escape(section)}</th></tr>')
        table.append(f"<tr><td>{html.escape(row.label)}</td><td class=num>{_number(row.final)}</td>"
                     f"<td class=num>{_number(row.kinematic)}</td><td>{html.escape(row.unit)}</td>"
                     f"<td class=meaning>{html.escape(row.meaning)}</td></tr>")
    images = "\n".join(f'<figure><img src="{html.escape(Path(path).relative_to(run_dir).as_posix())}" '
                       f'alt="{html.escape(name)}"></figure>' for name, path in plots.items())
    video = ('<video src="overlay.mp4" controls muted playsinline></video>'
             if (run_dir / "overlay.mp4").is_file() else "")
    timings = ", ".join(f"{html.escape(k)} {v:.1f} s" for k, v in stage_seconds.items())
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>physmocap report · {html.escape(run_dir.name)}</title>
<style>
 body {{ font-family: system-ui, sans-serif; margin: 24px auto; max-width: 1100px; color: #222; padding: 0 16px; }}
 h1 {{ font-size: 22px; }} h2 {{ font-size: 17px; margin-top: 28px; }}
 table {{ border-collapse: collapse; width: 100%; font-size: 14px; }}
 td, th {{ border-bottom: 1px solid #e0e0e0; padding: 5px 8px; text-align: left; vertical-align: top; }}
 tr.section th {{ background: #eceff1; }} td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
 td.meaning {{ color: #555; font-size: 13px; }} video {{ max-width: 100%; max-height: 420px; }}
 figure {{ margin: 10px 0; }} figure img {{ max-width: 100%; }}
</style></head><body>
<h1>physmocap run: {html.escape(run_dir.name)}</h1>
<p>{frames} frames at {fps:.4g} fps ({frames / fps:.1f} s), {valid} reconstructed; physics: {html.escape(physics)};
body {float(result["body_height"]):.2f} m, {float(result["body_mass"]):.0f} kg. Time per stage: {timings}.
{floor_sentence(result)}</p>
<h2>Files</h2><ul>{links}</ul>
{video}
<h2>Metrics</h2>
<p>Without ground truth: the final motion against the kinematic motion before physics, the floor z = 0 and the
contacts the run used.</p>
<table><tr><th>metric</th><th>final</th><th>kinematic</th><th>unit</th><th>meaning</th></tr>
{chr(10).join(table)}
</table>
<h2>Plots</h2>
{images}
</body></html>
"""


@dataclass(frozen=True)
class ReportParts:
    """The costly part of a report, written before its page: the plots (kind -> path) and the metric rows (also
    in metrics.json, `metrics_path`)."""

    plots: dict[str, str]
    rows: list[Metric]
    metrics_path: str


def write_report_parts(run_dir: str | os.PathLike, result: dict[str, np.ndarray]) -> ReportParts:
    """The plots (run_dir/plots/*.png) and metrics.json of the report on `result`: they need only the result, so
    the pipeline counts them in its outputs stage and writes the page last (write_report), after summary.json."""
    run_dir = Path(run_dir)
    result = finite_result(result, str(run_dir / "report.html"))
    plots = write_plots(result, run_dir / "plots")
    rows = run_metrics(result)
    metrics_path = run_dir / "metrics.json"
    write_text(metrics_path, json_text({r.key: asdict(r) for r in rows}, indent=1))
    return ReportParts(plots, rows, str(metrics_path))


def write_report(run_dir: str | os.PathLike, result: dict[str, np.ndarray],
                 parts: ReportParts | None = None) -> dict[str, str]:
    """Write report.html into the run folder `run_dir`, linking the outputs already there (write the viewer,
    overlay and exports first), with its plots and metrics.json (`parts` where write_report_parts wrote them
    already). Returns {kind: path}."""
    run_dir = Path(run_dir)
    parts = write_report_parts(run_dir, result) if parts is None else parts
    report_path = run_dir / "report.html"
    write_text(report_path, report_html(run_dir, result, parts.rows, parts.plots))
    return {"report": str(report_path), "metrics": parts.metrics_path, **parts.plots}
