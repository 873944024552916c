"""The 3D viewer: one self-contained HTML file per run (its JavaScript and the motion inside it, works offline).

It shows the floor, the final skeleton with its contact points and ground reaction force arrows, the kinematic
motion as a faint ghost beside it (or overlaid), the centre of mass with its projection and the support polygon,
and the run's overlay video beside the 3D view, synchronised, with play/pause and a time slider. The renderer is a
small canvas-2D perspective projector in `physmocap/data/viewer/viewer.js`; the page template is `viewer.html`.

The motion travels as base64 little-endian float32 / uint8 arrays in a JSON block, which the page decodes in a few
milliseconds even for long clips (a 1-minute clip at 30 fps is about 2 MB).
"""

from __future__ import annotations

import base64
import json
import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..body.kinematics import center_of_mass, forward_kinematics
from ..body.model import CONTACT_POINTS
from ..body.support import convex_hull_2d
from ..export import body_from_result
from ..io.atomic import write_text
from ..io.finite import finite_result
from ..metrics import GRAVITY
from .overlay import SKELETON_EDGE_NAMES, force_arrow_scale

SUPPORT_MARGIN = 0.05  # m: a centre of mass this close to the support polygon still counts as over it
GHOST_OFFSET = 1.0  # m beside the final motion, to the right as the video camera sees it
DATA_PLACEHOLDER = "/*PHYSMOCAP_DATA*/"
SCRIPT_PLACEHOLDER = "/*PHYSMOCAP_SCRIPT*/"


def distance_to_polygon(point: np.ndarray, polygon: np.ndarray) -> float:
    """Distance (m) from a 2D point to a convex polygon given counter-clockwise (0 inside), or to a segment or a
    point when it has fewer than three vertices; inf for an empty polygon."""
    if len(polygon) == 0:
        return float("inf")
    if len(polygon) >= 3:
        edges = np.roll(polygon, -1, axis=0) - polygon
        if np.all(np.cross(edges, point - polygon) >= 0):
            return 0.0
    starts = polygon
    ends = np.roll(polygon, -1, axis=0) if len(polygon) > 1 else polygon
    along = ends - starts
    length2 = np.maximum(np.einsum("ij,ij->i", along, along), 1e-18)
    s = np.clip(np.einsum("ij,ij->i", point - starts, along) / length2, 0.0, 1.0)
    return float(np.min(np.linalg.norm(starts + s[:, None] * along - point, axis=1)))


def support_polygons(contact_points: np.ndarray, contacts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the convex hull on the floor of the contact points in contact.

    contact_points: (T, 4, 3) world metres; contacts: (T, 4) bool. Returns vertices (T, 4, 2) (x, y metres,
    counter-clockwise, unused rows zero) and counts (T,) of vertices per frame (0 without contact).
    """
    T = len(contact_points)
    vertices, counts = np.zeros((T, 4, 2)), np.zeros(T, dtype=np.uint8)
    for t in range(T):
        hull = np.array(convex_hull_2d(contact_points[t, np.asarray(contacts[t], bool), :2]), float).reshape(-1, 2)
        vertices[t, :len(hull)], counts[t] = hull, len(hull)
    return vertices, counts


def com_over_support(com: np.ndarray, vertices: np.ndarray, counts: np.ndarray,
                     margin: float = SUPPORT_MARGIN) -> np.ndarray:
    """(T,) bool: the centre of mass (T, 3) projects onto the floor within `margin` metres of the support polygon
    (see `support_polygons`); False without contact."""
    return np.array([distance_to_polygon(c[:2], v[:n]) <= margin
                     for c, v, n in zip(com, vertices, counts, strict=True)])


def _base64(array: np.ndarray, dtype: str) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype=dtype).tobytes()).decode("ascii")


def viewer_payload(result: dict[str, np.ndarray], video: str | None) -> dict:
    """What the page needs from a result (see the module docstring); `video` is the path of the overlay video
    relative to the HTML file (None: no video panel)."""
    body = body_from_result(result)
    names = [str(n) for n in result["joint_names"]]
    final, kinematic = result["joints_world"], result["joints_world_kinematic"]
    T = len(final)
    com = center_of_mass(body, forward_kinematics(body, result["qpos"]))
    contact_ids = [names.index(n) for n in CONTACT_POINTS]
    contacts = np.asarray(result["contacts"], bool)
    vertices, counts = support_polygons(final[:, contact_ids], contacts)
    edges = [[names.index(a), names.index(b)] for a, b in SKELETON_EDGE_NAMES if a in names and b in names]
    camera_right = np.asarray(result["camera_R"], float)[0] * np.array([1.0, 1.0, 0.0])
    ghost = GHOST_OFFSET * camera_right / max(np.linalg.norm(camera_right), 1e-9)
    weight = float(result["body_mass"]) * GRAVITY
    return {
        "fps": float(result["fps"]),
        "frames": T,
        "names": names,
        "edges": edges,
        "contactIds": contact_ids,
        "final": _base64(final, "<f4"),
        "kinematic": _base64(kinematic, "<f4"),
        "contacts": _base64(contacts, "u1"),
        "grf": _base64(result["grf"], "<f4"),
        "hasForces": bool(np.any(result["grf"] != 0)),
        "com": _base64(com, "<f4"),
        "comOverSupport": _base64(com_over_support(com, vertices, counts), "u1"),
        "support": _base64(vertices, "<f4"),
        "supportCounts": _base64(counts, "u1"),
        "valid": _base64(np.asarray(result["valid"], bool), "u1"),
        "metresPerNewton": force_arrow_scale(float(result["body_mass"]), float(result["body_height"])),
        "bodyWeight": weight,
        "ghostOffset": ghost.tolist(),
        "cameraCentre": np.nan_to_num(-np.asarray(result["camera_R"]).T @ np.asarray(result["camera_t"])).tolist(),
        "video": video,
    }


def _asset(name: str) -> str:
    return resources.files("physmocap").joinpath("data", "viewer", name).read_text(encoding="utf-8")


def viewer_html(result: dict[str, np.ndarray], video: str | None = "overlay.mp4", title: str = "physmocap") -> str:
    """The complete page for `result` (see `viewer_payload` for `video`)."""
    data = json.dumps(viewer_payload(result, video), separators=(",", ":")).replace("</", "<\\/")
    script = _asset("viewer.js")
    page = _asset("viewer.html").replace("{{TITLE}}", title.replace("<", "&lt;"))
    return page.replace(DATA_PLACEHOLDER, data).replace(SCRIPT_PLACEHOLDER, script)


def write_viewer(result: dict[str, np.ndarray], out_path: str | os.PathLike,
                 video: str | os.PathLike | None = "overlay.mp4") -> None:
    """Write the viewer page for `result` to `out_path` (atomically). video: the overlay video as a path relative
    to the page's folder (the run folder's overlay.mp4 by default), or None for no video panel. A video that is
    missing when the page opens leaves a note in its panel and the 3D view plays on its own clock."""
    out_path = Path(out_path)
    result = finite_result(result, str(out_path))
    title = f"physmocap · {out_path.parent.name or 'run'}"
    write_text(out_path, viewer_html(result, None if video is None else Path(video).as_posix(), title))
