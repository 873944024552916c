"""The fitted skeleton drawn over the input video: an H.264 MP4 to check a reconstruction by eye.

Colours (BGR): the body's left side blue, its right side orange, the centre line white; detector keypoints small
yellow dots; foot contact points green, filled while in contact and hollow otherwise; ground reaction forces
magenta arrows from the contact points (one body weight is FORCE_ARROW_BODY_HEIGHTS body heights long in the
world). Frames that could not be reconstructed carry a red banner instead of a skeleton.
"""

from __future__ import annotations

import os
from typing import Callable, Sequence

import cv2
import numpy as np

from ..body.model import CONTACT_POINTS, BodyModel
from ..io.video import VideoWriter, iter_frames, scaled_height
from ..metrics import GRAVITY

Colour = tuple[int, int, int]  # BGR, 0-255

LEFT_COLOUR: Colour = (235, 150, 40)
RIGHT_COLOUR: Colour = (30, 140, 255)
CENTRE_COLOUR: Colour = (255, 255, 255)
KEYPOINT_COLOUR: Colour = (0, 230, 255)
CONTACT_COLOUR: Colour = (60, 210, 60)
BANNER_COLOUR: Colour = (30, 30, 200)
FORCE_COLOUR: Colour = (96, 27, 216)
BANNER_TEXT = "frame not reconstructed"

FORCE_ARROW_BODY_HEIGHTS = 0.4  # an arrow of one body weight is this many body heights long
MIN_DRAWN_FORCE = 1.0  # N: weaker forces get no arrow

# Detector keypoints below this confidence are not drawn.
KEYPOINT_MIN_CONFIDENCE = 0.5

# Bones between the body model's named points (JOINT_NAMES and the face and hand landmarks).
SKELETON_EDGE_NAMES: tuple[tuple[str, str], ...] = (
    ("pelvis", "spine"), ("spine", "neck"), ("neck", "head"),
    ("head", "nose"), ("nose", "left_eye"), ("nose", "right_eye"),
    ("left_eye", "left_ear"), ("right_eye", "right_ear"),
) + tuple(
    edge
    for side in ("left", "right")
    for edge in (
        ("neck", f"{side}_shoulder"), (f"{side}_shoulder", f"{side}_elbow"), (f"{side}_elbow", f"{side}_wrist"),
        (f"{side}_wrist", f"{side}_index"), (f"{side}_wrist", f"{side}_pinky"), (f"{side}_index", f"{side}_pinky"),
        ("pelvis", f"{side}_hip"), (f"{side}_hip", f"{side}_knee"), (f"{side}_knee", f"{side}_ankle"),
        (f"{side}_ankle", f"{side}_heel"), (f"{side}_ankle", f"{side}_toe"), (f"{side}_heel", f"{side}_toe"),
    )
)

# cv2 draws at sub-pixel precision with coordinates in fixed point: pixel * 2**SHIFT.
SHIFT = 4


def skeleton_edges(body: BodyModel) -> list[tuple[int, int]]:
    """Bones as (i, j) index pairs into `body.point_names` (see SKELETON_EDGE_NAMES)."""
    return [tuple(int(i) for i in body.point_index(pair)) for pair in SKELETON_EDGE_NAMES]


def side_colour(name: str) -> Colour:
    """Colour of a point from its name: left_*, right_* or the centre line."""
    if name.startswith("left_"):
        return LEFT_COLOUR
    if name.startswith("right_"):
        return RIGHT_COLOUR
    return CENTRE_COLOUR


def edge_colour(edge: tuple[int, int], labels: Sequence[str] | None) -> Colour:
    """A bone takes the colour of its side; one from the centre line to a side (neck-shoulder) counts as that side."""
    if labels is None:
        return CENTRE_COLOUR
    colours = {side_colour(labels[i]) for i in edge} - {CENTRE_COLOUR}
    return colours.pop() if len(colours) == 1 else CENTRE_COLOUR


def line_width(image: np.ndarray) -> int:
    """Bone thickness in pixels for an image: 2 px up to 480 lines, growing with the size beyond."""
    return max(2, round(min(image.shape[:2]) / 240))


def _fixed(point: np.ndarray) -> tuple[int, int]:
    return int(round(point[0] * (1 << SHIFT))), int(round(point[1] * (1 << SHIFT)))


def _circle(image: np.ndarray, centre: np.ndarray, radius: float, colour: Colour, thickness: int) -> None:
    cv2.circle(image, _fixed(centre), int(round(radius * (1 << SHIFT))), colour, thickness, cv2.LINE_AA, SHIFT)


def draw_overlay(
    frame: np.ndarray,
    points_2d: np.ndarray,
    edges: Sequence[tuple[int, int]],
    *,
    labels: Sequence[str] | None = None,
    keypoints: np.ndarray | None = None,
    contacts: np.ndarray | None = None,
    force_arrows: np.ndarray | None = None,
    valid: bool = True,
) -> np.ndarray:
    """One annotated frame: a copy of BGR `frame` (H, W, 3) with the skeleton and markers drawn on it.

    points_2d: (P, 2) pixel positions in this frame's resolution (non-finite points and their bones are skipped).
    edges: bones as index pairs into points_2d. labels: (P,) point names (body.point_names), for the side colours
    and to find the contact points. keypoints: (K, 3) detector x, y in pixels and confidence. contacts: (4,) bool
    for the points named in CONTACT_POINTS (left heel, left toe, right heel, right toe); needs `labels`.
    force_arrows: (C, 2, 2) start and tip pixels of force arrows (see `force_arrows_2d`); non-finite ones are
    skipped. valid: False draws the banner and no skeleton, contacts or forces.
    """
    image = frame.copy()
    width = line_width(image)
    if keypoints is not None:
        for x, y, confidence in keypoints:
            if confidence >= KEYPOINT_MIN_CONFIDENCE and np.isfinite(x) and np.isfinite(y):
                _circle(image, np.array([x, y]), width, KEYPOINT_COLOUR, cv2.FILLED)
    if not valid:
        _draw_banner(image)
        return image
    finite = np.all(np.isfinite(points_2d), axis=1)
    for i, j in edges:
        if finite[i] and finite[j]:
            cv2.line(image, _fixed(points_2d[i]), _fixed(points_2d[j]), edge_colour((i, j), labels), width,
                     cv2.LINE_AA, SHIFT)
    for i in sorted({i for edge in edges for i in edge}):
        if finite[i]:
            colour = CENTRE_COLOUR if labels is None else side_colour(labels[i])
            _circle(image, points_2d[i], width, colour, cv2.FILLED)
    if contacts is not None:
        for index, in_contact in zip(contact_point_indices(labels), contacts):
            if finite[index]:
                _circle(image, points_2d[index], 2.5 * width, CONTACT_COLOUR,
                        cv2.FILLED if in_contact else max(1, width // 2))
    if force_arrows is not None:
        for start, tip in np.asarray(force_arrows, dtype=float):
            length = np.linalg.norm(tip - start)
            if np.all(np.isfinite(start)) and np.all(np.isfinite(tip)) and length > 0.5:
                cv2.arrowedLine(image, _fixed(start), _fixed(tip), FORCE_COLOUR, width, cv2.LINE_AA, SHIFT,
                                tipLength=min(0.3, 6.0 * width / length))
    return image


def force_arrow_scale(body_mass: float, body_height: float) -> float:
    """Metres of arrow per newton: one body weight (body_mass kg) is FORCE_ARROW_BODY_HEIGHTS x body_height m."""
    return FORCE_ARROW_BODY_HEIGHTS * body_height / (body_mass * GRAVITY)


def force_arrows_2d(contact_points: np.ndarray, forces: np.ndarray, project: Callable[[np.ndarray], np.ndarray],
                    metres_per_newton: float) -> np.ndarray:
    """Ground reaction force arrows in pixels: (T, C, 2, 2) start and tip (x, y) of each contact force.

    contact_points: (T, C, 3) world positions, metres, where the forces act; forces: (T, C, 3) newtons, world
    frame (result.npz "grf" with C = 4). project: world points (..., 3) -> pixels (..., 2), e.g. Camera.project.
    metres_per_newton: arrow length in the world per newton (see `force_arrow_scale`).
    Arrows of forces below MIN_DRAWN_FORCE are NaN (not drawn).
    """
    contact_points = np.asarray(contact_points, dtype=float)
    forces = np.asarray(forces, dtype=float)
    if contact_points.shape != forces.shape or contact_points.ndim != 3 or contact_points.shape[2] != 3:
        raise ValueError(f"contact_points and forces must both have shape (T, C, 3), got {contact_points.shape} "
                         f"and {forces.shape}.")
    ends = np.stack([contact_points, contact_points + forces * metres_per_newton], axis=2)  # (T, C, 2, 3)
    arrows = np.asarray(project(ends), dtype=float)
    arrows[np.linalg.norm(forces, axis=-1) < MIN_DRAWN_FORCE] = np.nan
    return arrows


def contact_point_indices(labels: Sequence[str] | None) -> list[int]:
    """Indices of the four contact points (CONTACT_POINTS order) in the point names `labels`."""
    if labels is None:
        raise ValueError("drawing contacts needs `labels`, the point names, to find the contact points.")
    missing = [name for name in CONTACT_POINTS if name not in labels]
    if missing:
        raise ValueError(f"labels lack the contact points {missing}.")
    return [list(labels).index(name) for name in CONTACT_POINTS]


def _draw_banner(image: np.ndarray) -> None:
    """A red band across the top of the image with BANNER_TEXT centred in it."""
    height, width = image.shape[:2]
    font_scale = max(0.4, width / 1200)
    thickness = max(1, round(font_scale * 2))
    (text_width, text_height), baseline = cv2.getTextSize(BANNER_TEXT, cv2.FONT_HERSHEY_SIMPLEX, font_scale, thickness)
    band = min(height, text_height + baseline + 2 * thickness + 8)
    cv2.rectangle(image, (0, 0), (width - 1, band - 1), BANNER_COLOUR, cv2.FILLED)
    origin = (max(0, (width - text_width) // 2), (band + text_height) // 2)
    cv2.putText(image, BANNER_TEXT, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale, CENTRE_COLOUR, thickness,
                cv2.LINE_AA)


def render_overlay(
    video_path: str | os.PathLike,
    out_path: str | os.PathLike,
    points_2d: np.ndarray,
    edges: Sequence[tuple[int, int]],
    valid: np.ndarray,
    *,
    keypoints: np.ndarray | None = None,
    contacts: np.ndarray | None = None,
    labels: Sequence[str] | None = None,
    force_arrows: np.ndarray | None = None,
    max_width: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> None:
    """Draw the skeleton over the first T frames of `video_path` and write them as H.264 MP4 `out_path`.

    points_2d: (T, P, 2) fitted points in pixels of the video's native resolution. edges: bones as index pairs into
    the P points (e.g. skeleton_edges(body)). valid: (T,) bool, False marks frames not reconstructed.
    keypoints: (T, K, 3) detector x, y (native pixels) and confidence. contacts: (T, 4) bool for left heel, left
    toe, right heel, right toe. labels: (P,) point names (body.point_names), for side colours and to find the
    contact points (required with `contacts`). force_arrows: (T, C, 2, 2) ground reaction force arrows in native
    pixels (see `force_arrows_2d`). max_width: frames wider than this are scaled down to it.
    progress: called as progress(frames_done, T) after each frame.
    The output keeps the input's frame rate. A video with fewer than T frames raises ValueError (and writes nothing).
    """
    points_2d = np.asarray(points_2d, dtype=float)
    valid = np.asarray(valid, dtype=bool)
    if points_2d.ndim != 3 or points_2d.shape[2] != 2:
        raise ValueError(f"points_2d must have shape (T, P, 2), got {points_2d.shape}.")
    T, P = points_2d.shape[:2]
    if valid.shape != (T,):
        raise ValueError(f"valid must have shape ({T},), got {valid.shape}.")
    keypoints = None if keypoints is None else np.asarray(keypoints, dtype=float)
    if keypoints is not None and (keypoints.ndim != 3 or keypoints.shape[0] != T or keypoints.shape[2] != 3):
        raise ValueError(f"keypoints must have shape ({T}, K, 3), got {keypoints.shape}.")
    if contacts is not None:
        if np.shape(contacts) != (T, len(CONTACT_POINTS)):
            raise ValueError(f"contacts must have shape ({T}, {len(CONTACT_POINTS)}), got {np.shape(contacts)}.")
        contact_point_indices(labels)  # missing contact names fail here, before any decoding
    force_arrows = None if force_arrows is None else np.asarray(force_arrows, dtype=float)
    if force_arrows is not None and (force_arrows.ndim != 4 or force_arrows.shape[0] != T
                                     or force_arrows.shape[2:] != (2, 2)):
        raise ValueError(f"force_arrows must have shape ({T}, C, 2, 2), got {force_arrows.shape}.")
    if labels is not None and len(labels) != P:
        raise ValueError(f"labels must name all {P} points, got {len(labels)} names.")
    if any(not (0 <= i < P and 0 <= j < P) for i, j in edges):
        raise ValueError(f"edges must index the {P} points.")

    frames = iter_frames(video_path, max_width=max_width)
    info = frames.info
    out_width = info.width if max_width is None or info.width <= max_width else max_width
    out_height = scaled_height(info.width, info.height, out_width)
    scale = np.array([out_width / info.width, out_height / info.height])  # native pixels -> output pixels
    with VideoWriter(out_path, info.fps, out_width, out_height) as writer:
        for index, frame in frames:
            if index >= T:
                break
            image = draw_overlay(
                frame, points_2d[index] * scale, edges, labels=labels,
                keypoints=None if keypoints is None else keypoints[index] * np.append(scale, 1.0),
                contacts=None if contacts is None else contacts[index],
                force_arrows=None if force_arrows is None else force_arrows[index] * scale,
                valid=bool(valid[index]),
            )
            writer.write(image)
            if progress is not None:
                progress(index + 1, T)
        if writer.frames_written < T:
            raise ValueError(f"{video_path}: has {writer.frames_written} frames, fewer than the {T} to draw.")
