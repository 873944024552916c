"""The fitted skeleton drawn over the input video: an H.264 MP4 to check a reconstruction by eye.

Colours (BGR): the body's left side blue, its right side orange, the centre line white; detector keypoints small
yellow dots; foot contact points green, filled while in contact and hollow otherwise; ground reaction forces
magenta arrows from the contact points (one body weight is FORCE_ARROW_BODY_HEIGHTS body heights long in the
world). Frames that could not be reconstructed carry a red banner at the top instead of a skeleton; frames that
physics could not explain carry one at the bottom.

The video is decoded (in a thread), drawn and encoded frame by frame at the output size, never held whole;
`start_overlay` runs all of it in a worker thread beside whatever the caller writes meanwhile. The frames stay in
the decoder's yuv420p from decoding to encoding: the markers are drawn in Y, U, V colours on the region they
cover. A long video is rendered as two halves at once, each with its own decoder, drawing and x264 in its own
thread, and the halves are joined without re-encoding (docs/decisions/overlay-speed.md).
"""

from __future__ import annotations

import functools
import logging
import os
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np

from ..body.model import CONTACT_POINTS, BodyModel
from ..cores import may_use_two_cores
from ..io.video import (
    FrameReader,
    PartsDiffer,
    VideoWriter,
    copy_yuv420,
    iter_frames,
    join_video_parts,
    mp4_output_path,
    yuv420_planes,
)
from ..metrics import GRAVITY

logger = logging.getLogger(__name__)

Colour = tuple[int, int, int]  # BGR, 0-255

LEFT_COLOUR: Colour = (235, 150, 40)
RIGHT_COLOUR: Colour = (30, 140, 255)
CENTRE_COLOUR: Colour = (255, 255, 255)
KEYPOINT_COLOUR: Colour = (0, 230, 255)
CONTACT_COLOUR: Colour = (60, 210, 60)
BANNER_COLOUR: Colour = (30, 30, 200)
FORCE_COLOUR: Colour = (96, 27, 216)
BANNER_TEXT = "frame not reconstructed"
UNEXPLAINED_TEXT = "physics cannot explain this frame"

DEFAULT_OVERLAY_WIDTH = 1280  # px: wider videos are drawn and encoded at this width (None: native); 160 .. 7680
OVERLAY_PRESET = "ultrafast"  # libx264 speed preset of overlay.mp4 (docs/decisions/overlay-speed.md)
OVERLAY_QP = 21  # libx264 constant quantiser: about CRF 23's quality, less CPU (docs/decisions/overlay-speed.md)
PREFETCH_FRAMES = 8  # frames decoded ahead of the drawing, in the reader's thread
MAX_DRAWN_COORDINATE = 1e5  # px: cv2 takes coordinates * 2**SHIFT as int32; points farther out are not drawn
MIN_FRAMES_FOR_PARTS = 150  # frames a video needs before two parts pay (docs/decisions/overlay-speed.md, round 3)
X264_KEYINT = 250  # frames between libx264's keyframes (its default; OVERLAY_PRESET makes no others)

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

# Pixels around the drawn points that the markers may cover, in line widths: force arrow heads (at most 6 line
# widths long, see _draw_in_place) plus half a line; 2 px more for the anti-aliased edge.
DRAWN_MARGIN_LINE_WIDTHS = 7
DRAWN_MARGIN_PX = 2


def skeleton_edges(body: BodyModel) -> list[tuple[int, int]]:
    """Bones as (i, j) index pairs into `body.point_names` (see SKELETON_EDGE_NAMES)."""
    return [(int(i), int(j)) for i, j in map(body.point_index, SKELETON_EDGE_NAMES)]


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


def _as_is(colour: Colour) -> Colour:
    return colour


@functools.cache
def yuv_colour(colour: Colour) -> Colour:
    """(Y, U, V) of a BGR colour as swscale writes yuv420p from BGR: ITU-R BT.601, limited range (Y 16-235)."""
    blue, green, red = colour
    y = 16 + (65.481 * red + 128.553 * green + 24.966 * blue) / 255
    u = 128 + (-37.797 * red - 74.203 * green + 112.0 * blue) / 255
    v = 128 + (112.0 * red - 93.786 * green - 18.214 * blue) / 255
    return round(y), round(u), round(v)


def _fixed(points: np.ndarray) -> list[tuple[int, int]]:
    """(..., 2) pixel positions (drawable ones) as cv2's fixed-point (x, y) tuples, flattened."""
    scaled = np.round(np.asarray(points, dtype=float).reshape(-1, 2) * (1 << SHIFT)).astype(np.int64)
    return [tuple(point) for point in scaled.tolist()]


def _circle(image: np.ndarray, centre: tuple[int, int], radius: float, colour: Colour, thickness: int) -> None:
    cv2.circle(image, centre, int(round(radius * (1 << SHIFT))), colour, thickness, cv2.LINE_AA, SHIFT)


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
    unexplained: bool = False,
) -> np.ndarray:
    """One annotated frame: a copy of BGR `frame` (H, W, 3) with the skeleton and markers drawn on it.

    points_2d: (P, 2) pixel positions in this frame's resolution (non-finite points and their bones are skipped).
    edges: bones as index pairs into points_2d. labels: (P,) point names (body.point_names), for the side colours
    and to find the contact points. keypoints: (K, 3) detector x, y in pixels and confidence. contacts: (4,) bool
    for the points named in CONTACT_POINTS (left heel, left toe, right heel, right toe); needs `labels`.
    force_arrows: (C, 2, 2) start and tip pixels of force arrows (see `force_arrows_2d`); non-finite ones are
    skipped. valid: False draws the top banner and no skeleton, contacts or forces. unexplained: True draws the
    bottom banner (physics could not explain the frame) under the skeleton.
    """
    image = frame.copy()
    _draw_in_place(image, points_2d, edges, labels, keypoints, contacts, force_arrows, valid, unexplained)
    return image


def drawable(points: np.ndarray) -> np.ndarray:
    """(...,) True where the (..., 2) pixel positions are finite and within MAX_DRAWN_COORDINATE of the image."""
    points = np.asarray(points, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(points) & (np.abs(points) < MAX_DRAWN_COORDINATE), axis=-1)


@functools.lru_cache(maxsize=8)
def _palette(edges: tuple[tuple[int, int], ...], labels: tuple[str, ...] | None, ink: Callable[[Colour], Colour]
             ) -> tuple[list[Colour], list[tuple[int, Colour]]]:
    """The colours of the bones, and the points drawn with their colours, in `ink`; the same every frame."""
    points = sorted({i for edge in edges for i in edge})
    return ([ink(edge_colour(edge, labels)) for edge in edges],
            [(i, ink(CENTRE_COLOUR if labels is None else side_colour(labels[i]))) for i in points])


def _seen_keypoints(keypoints: np.ndarray) -> np.ndarray:
    """(K, 3) the detector keypoints that are drawn: finite, near the image, confident enough."""
    return keypoints[drawable(keypoints[:, :2]) & (keypoints[:, 2] >= KEYPOINT_MIN_CONFIDENCE)]


def _draw_in_place(image: np.ndarray, points_2d: np.ndarray, edges: Sequence[tuple[int, int]],
                   labels: Sequence[str] | None, keypoints: np.ndarray | None, contacts: np.ndarray | None,
                   force_arrows: np.ndarray | None, valid: bool, unexplained: bool,
                   ink: Callable[[Colour], Colour] = _as_is, width: int | None = None) -> None:
    """Draw on `image` in place; `ink` turns each BGR colour into the image's colour space (e.g. yuv_colour);
    width: the line width in pixels (default: line_width(image); a part of a frame takes the whole frame's).
    The markers first, the banners over them."""
    _draw_markers(image, points_2d, edges, labels, keypoints, contacts, force_arrows, valid, ink, width)
    for text, at_top in _banners(valid, unexplained):
        _draw_banner(image, text, at_top, ink=ink)


def _banners(valid: bool, unexplained: bool) -> list[tuple[str, bool]]:
    """(text, at the top) of the banners a frame carries: not reconstructed (top), else unexplained (bottom)."""
    if not valid:
        return [(BANNER_TEXT, True)]
    return [(UNEXPLAINED_TEXT, False)] if unexplained else []


def _draw_markers(image: np.ndarray, points_2d: np.ndarray, edges: Sequence[tuple[int, int]],
                  labels: Sequence[str] | None, keypoints: np.ndarray | None, contacts: np.ndarray | None,
                  force_arrows: np.ndarray | None, valid: bool, ink: Callable[[Colour], Colour] = _as_is,
                  width: int | None = None) -> None:
    """_draw_in_place without the banners: keypoints, and for a reconstructed frame the skeleton, contacts and
    force arrows."""
    width = line_width(image) if width is None else width
    if keypoints is not None:
        for centre in _fixed(_seen_keypoints(keypoints)[:, :2]):
            _circle(image, centre, width, ink(KEYPOINT_COLOUR), cv2.FILLED)
    if not valid:
        return
    finite = drawable(points_2d)
    fixed = _fixed(np.where(finite[:, None], points_2d, 0.0))
    edge_colours, point_colours = _palette(tuple((int(i), int(j)) for i, j in edges),
                                           None if labels is None else tuple(labels), ink)
    for (i, j), colour in zip(edges, edge_colours, strict=True):
        if finite[i] and finite[j]:
            cv2.line(image, fixed[i], fixed[j], colour, width, cv2.LINE_AA, SHIFT)
    for i, colour in point_colours:
        if finite[i]:
            _circle(image, fixed[i], width, colour, cv2.FILLED)
    if contacts is not None:
        for index, in_contact in zip(contact_point_indices(labels), contacts, strict=True):
            if finite[index]:
                _circle(image, fixed[index], 2.5 * width, ink(CONTACT_COLOUR),
                        cv2.FILLED if in_contact else max(1, width // 2))
    if force_arrows is not None:
        force_arrows = np.asarray(force_arrows, dtype=float)
        arrows = force_arrows[drawable(force_arrows).all(axis=-1)]
        ends = _fixed(arrows)
        for (start, tip), start_fixed, tip_fixed in zip(arrows, ends[0::2], ends[1::2], strict=True):
            length = float(np.linalg.norm(tip - start))
            if length > 0.5:
                # The head is at most 6 line widths long: DRAWN_MARGIN_LINE_WIDTHS counts on it.
                cv2.arrowedLine(image, start_fixed, tip_fixed, ink(FORCE_COLOUR), width, cv2.LINE_AA, SHIFT,
                                tipLength=min(0.3, 6.0 * width / length))


def _even_box(size: tuple[int, int], x0: float, y0: float, x1: float, y1: float) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) widened to even pixel bounds within the (width, height) image (yuv420p's chroma covers
    2 x 2 pixels); None when empty."""
    width, height = size
    x0, y0 = int(np.clip(np.floor(x0), 0, width)), int(np.clip(np.floor(y0), 0, height))
    x1, y1 = int(np.clip(np.ceil(x1), 0, width)), int(np.clip(np.ceil(y1), 0, height))
    if x1 <= x0 or y1 <= y0:
        return None
    return x0 // 2 * 2, y0 // 2 * 2, min(width, -(-x1 // 2) * 2), min(height, -(-y1 // 2) * 2)


def _drawn_box(size: tuple[int, int], line: int, points_2d: np.ndarray, keypoints: np.ndarray | None,
               force_arrows: np.ndarray | None, valid: bool) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1), even pixel bounds within the (width, height) image, of all that _draw_markers draws
    with these inputs and lines `line` pixels wide; None when it draws nothing."""
    margin = DRAWN_MARGIN_LINE_WIDTHS * line + DRAWN_MARGIN_PX
    drawn = [] if keypoints is None else [_seen_keypoints(keypoints)[:, :2]]
    if valid:
        drawn.append(points_2d[drawable(points_2d)])
        if force_arrows is not None:
            drawn.append(force_arrows[drawable(force_arrows).all(axis=-1)].reshape(-1, 2))
    points = np.concatenate(drawn) if drawn else np.zeros((0, 2))
    if not len(points):
        return None
    low, high = points.min(axis=0) - margin, points.max(axis=0) + margin
    return _even_box(size, low[0], low[1], high[0], high[1])


def _banner_box(size: tuple[int, int], text: str, at_top: bool) -> tuple[int, int, int, int] | None:
    """Even pixel bounds of a banner's band: the whole width, from the image's top or bottom edge, so that
    _draw_banner places it alike in the box and in the image."""
    width, height = size
    band = _banner_layout(text, width, height)[-1]
    return _even_box(size, 0, 0 if at_top else height - band, width, band if at_top else height)


class YuvScratch:
    """Full-size work images for _draw_yuv420, reused frame after frame (fresh megabyte arrays cost page faults
    every frame): the drawn box as Y, U, V per pixel, and its chroma at full resolution."""

    def __init__(self, width: int, height: int) -> None:
        self.yuv = np.empty((height, width, 3), np.uint8)
        self.chroma = [np.empty((height, width), np.uint8) for _ in range(2)]


def _draw_yuv420(planes: tuple[np.ndarray, np.ndarray, np.ndarray], scratch: YuvScratch, points_2d: np.ndarray,
                 edges: Sequence[tuple[int, int]], labels: Sequence[str] | None, keypoints: np.ndarray | None,
                 contacts: np.ndarray | None, force_arrows: np.ndarray | None, valid: bool,
                 unexplained: bool) -> None:
    """_draw_in_place on a yuv420p picture's planes (Y (H, W), U and V (H/2, W/2), modified in place).

    Only the boxes the markers and each banner cover are touched (a banner spans the width: one box for both
    would cover everything between the skeleton and the frame's edge), markers first, banners over them.
    """
    height, width = planes[0].shape
    line = line_width(planes[0])  # the whole frame's, not the box's
    box = _drawn_box((width, height), line, points_2d, keypoints, force_arrows, valid)
    if box is not None:
        origin = np.array(box[:2], dtype=float)
        _draw_box_yuv420(planes, scratch, box, lambda region: _draw_markers(
            region, points_2d - origin, edges, labels,
            None if keypoints is None else keypoints - np.append(origin, 0.0), contacts,
            None if force_arrows is None else force_arrows - origin, valid, ink=yuv_colour, width=line))
    for text, at_top in _banners(valid, unexplained):
        band = _banner_box((width, height), text, at_top)
        if band is not None:
            _draw_box_yuv420(planes, scratch, band,
                             functools.partial(_draw_banner, text=text, at_top=at_top, ink=yuv_colour))


def _draw_box_yuv420(planes: tuple[np.ndarray, np.ndarray, np.ndarray], scratch: YuvScratch,
                     box: tuple[int, int, int, int], draw: Callable[[np.ndarray], None]) -> None:
    """`draw` on the (x0, y0, x1, y1) box (even bounds) of a yuv420p picture's planes: there the planes are merged
    into one Y, U, V image (chroma repeated 2 x 2), drawn on with the colours in Y, U, V (blending is linear, so
    this equals drawing in BGR and converting) and split back, chroma averaged 2 x 2 (unchanged where nothing was
    drawn)."""
    y_plane, u_plane, v_plane = planes
    x0, y0, x1, y1 = box
    size = (x1 - x0, y1 - y0)
    luma = y_plane[y0:y1, x0:x1]
    halves = [plane[y0 // 2:y1 // 2, x0 // 2:x1 // 2] for plane in (u_plane, v_plane)]
    full = [chroma[:size[1], :size[0]] for chroma in scratch.chroma]
    region = scratch.yuv[:size[1], :size[0]]
    for half, chroma in zip(halves, full, strict=True):
        cv2.resize(half, size, dst=chroma, interpolation=cv2.INTER_NEAREST)
    cv2.merge([luma, *full], dst=region)
    draw(region)
    cv2.extractChannel(region, 0, dst=luma)
    for channel, (half, chroma) in enumerate(zip(halves, full, strict=True), start=1):
        cv2.extractChannel(region, channel, dst=chroma)
        cv2.resize(chroma, (size[0] // 2, size[1] // 2), dst=half, interpolation=cv2.INTER_AREA)


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


def _banner_layout(text: str, width: int, height: int) -> tuple[float, int, int, int, int]:
    """Font scale, stroke thickness, text width and height, and the band's height in pixels of a banner."""
    font_scale = max(0.4, width / 1200)
    thickness = max(1, round(font_scale * 2))
    (text_width, text_height), baseline = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, font_scale, thickness)
    return font_scale, thickness, text_width, text_height, min(height, text_height + baseline + 2 * thickness + 8)


def _draw_banner(image: np.ndarray, text: str, at_top: bool, ink: Callable[[Colour], Colour] = _as_is) -> None:
    """A red band across the top or bottom of the image with `text` centred in it."""
    height, width = image.shape[:2]
    font_scale, thickness, text_width, text_height, band = _banner_layout(text, width, height)
    top = 0 if at_top else height - band
    cv2.rectangle(image, (0, top), (width - 1, top + band - 1), ink(BANNER_COLOUR), cv2.FILLED)
    origin = (max(0, (width - text_width) // 2), top + (band + text_height) // 2)
    cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, font_scale, ink(CENTRE_COLOUR), thickness,
                cv2.LINE_AA)


@dataclass(frozen=True)
class OverlayReport:
    """What render_overlay wrote: frames, the video's size in pixels, the frames drawn without some of their fitted
    points because those were non-finite or absurdly far out (sorted indices; reconstructed frames only), the
    seconds it took and the parts it was rendered in at once (1 or 2)."""

    frames: int
    width: int
    height: int
    nonfinite_frames: list[int]
    seconds: float
    parts: int = 1


class OverlayCancelled(Exception):
    """The overlay's worker was asked to stop; nothing was written."""


def overlay_parts(requested: int | None, frames: int) -> int:
    """Parts render_overlay draws and encodes at once for a video of `frames` frames: `requested` (1 or 2; one part
    for fewer than 3 frames); None takes 2 from MIN_FRAMES_FOR_PARTS frames on, where this process may use two
    cores (`cores.may_use_two_cores`: not in a pool or batch worker)."""
    if requested not in (None, 1, 2):
        raise ValueError(f"parts must be 1, 2 or None (automatic), got {requested}.")
    if requested is None:
        requested = 2 if frames >= MIN_FRAMES_FOR_PARTS and may_use_two_cores() else 1
    return requested if frames >= 3 else 1


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
    unexplained: np.ndarray | None = None,
    max_width: int | None = DEFAULT_OVERLAY_WIDTH,
    fps: float | None = None,
    parts: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: threading.Event | None = None,
) -> OverlayReport:
    """Draw the skeleton over the first T frames of `video_path` and write them as H.264 MP4 `out_path`.

    points_2d: (T, P, 2) fitted points in pixels of the video's native (upright) resolution. edges: bones as index
    pairs into the P points (e.g. skeleton_edges(body)). valid: (T,) bool, False marks frames not reconstructed.
    keypoints: (T, K, 3) detector x, y (native pixels) and confidence. contacts: (T, 4) bool for left heel, left
    toe, right heel, right toe. labels: (P,) point names (body.point_names), for side colours and to find the
    contact points (required with `contacts`). force_arrows: (T, C, 2, 2) ground reaction force arrows in native
    pixels (see `force_arrows_2d`). unexplained: (T,) bool, True marks frames physics could not explain.
    max_width: frames wider than this are scaled down to it, in pixels (None: native size).
    fps: the output's frame rate, frames/s (None: the input's; the result's keeps a slow-motion file in its time).
    parts: 2 draws and encodes the two halves of the video at once, in two threads, and joins them without
    re-encoding (the same frames as one part, within the encoder's noise); 1 renders it in one pass; None
    chooses (see `overlay_parts`). Parts that cannot be joined are rendered again in one pass.
    progress: called as progress(frames_done, T) after each frame, one count over the parts. cancel: once set,
    rendering stops with OverlayCancelled and writes nothing.
    The output keeps the input's (constant, see io.video) frames, one for one. A video with fewer than T frames raises
    ValueError (and writes nothing). Non-finite points and arrows are not drawn; the report lists the frames.
    """
    started = time.perf_counter()
    drawing = _overlay_drawing(points_2d, edges, valid, keypoints, contacts, labels, force_arrows, unexplained, fps)
    out_path = mp4_output_path(out_path)
    frames = iter_frames(video_path, max_width=max_width, prefetch=PREFETCH_FRAMES, pixel_format="yuv420p")
    count = _FrameCount(progress, drawing.frames)
    parts = overlay_parts(parts, drawing.frames)
    try:
        if parts == 2:
            try:
                _render_two_parts(video_path, out_path, drawing, max_width, count, cancel)
            except PartsDiffer as why:
                logger.warning("%s: its two parts cannot be joined (%s); rendering it again in one part.",
                               out_path, why)
                parts, count = 1, _FrameCount(progress, drawing.frames, already=count.done)
        if parts == 1:
            _render_part(frames, out_path, drawing, drawing.frames, count, () if cancel is None else (cancel,),
                         out_path)
    except _VideoEnded as ended:
        raise ValueError(f"{video_path}: has {ended.frames} frames, fewer than the {drawing.frames} to draw.") \
            from None
    count.finish()
    out_width, out_height = frames.output_size
    return OverlayReport(drawing.frames, out_width, out_height, _nonfinite_frames(drawing).tolist(),
                         time.perf_counter() - started, parts)


@dataclass(frozen=True)
class _OverlayDrawing:
    """What render_overlay draws on each of `frames` frames, checked and as arrays (see render_overlay)."""

    frames: int
    points_2d: np.ndarray
    edges: Sequence[tuple[int, int]]
    valid: np.ndarray
    keypoints: np.ndarray | None
    contacts: np.ndarray | None
    labels: Sequence[str] | None
    force_arrows: np.ndarray | None
    unexplained: np.ndarray
    fps: float | None  # the output's frame rate (None: the input's)


def _overlay_drawing(points_2d, edges: Sequence[tuple[int, int]], valid, keypoints, contacts,
                     labels: Sequence[str] | None, force_arrows, unexplained, fps: float | None) -> _OverlayDrawing:
    """render_overlay's inputs as arrays; ValueError naming the first whose shape or indices do not fit."""
    points_2d = np.asarray(points_2d, dtype=float)
    valid = np.asarray(valid, dtype=bool)
    if points_2d.ndim != 3 or points_2d.shape[2] != 2:
        raise ValueError(f"points_2d must have shape (T, P, 2), got {points_2d.shape}.")
    T, P = points_2d.shape[:2]
    if valid.shape != (T,):
        raise ValueError(f"valid must have shape ({T},), got {valid.shape}.")
    unexplained = np.zeros(T, bool) if unexplained is None else np.asarray(unexplained, dtype=bool)
    if unexplained.shape != (T,):
        raise ValueError(f"unexplained must have shape ({T},), got {unexplained.shape}.")
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
    return _OverlayDrawing(T, points_2d, edges, valid, keypoints, contacts, labels, force_arrows, unexplained, fps)


def _nonfinite_frames(drawing: _OverlayDrawing) -> np.ndarray:
    """Indices of the reconstructed frames with a bone end that cannot be drawn (non-finite or far out)."""
    drawn_points = sorted({i for edge in drawing.edges for i in edge})
    if not drawn_points:
        return np.array([], dtype=int)
    return np.flatnonzero(drawing.valid & ~drawable(drawing.points_2d[:, drawn_points]).all(axis=1))


def _draw_frames(frames: FrameReader[av.VideoFrame], writer: VideoWriter, drawing: _OverlayDrawing, end: int,
                 count: _FrameCount, stops: Sequence[threading.Event], out_path: str | os.PathLike) -> None:
    """Each picture before frame `end` copied, drawn on in place (yuv420p) and written."""
    info = frames.info
    out_width, out_height = frames.output_size
    scale = np.array([out_width / info.width, out_height / info.height])  # native pixels -> output pixels
    canvas = None  # the picture drawn on and encoded, reused frame after frame
    scratch = YuvScratch(out_width, out_height)
    for index, picture in frames:
        if index >= end:
            break
        if any(stop.is_set() for stop in stops):
            raise OverlayCancelled(f"{out_path}: rendering was cancelled.")
        canvas = copy_yuv420(picture, canvas)
        _draw_yuv420(
            yuv420_planes(canvas), scratch, drawing.points_2d[index] * scale, drawing.edges, drawing.labels,
            None if drawing.keypoints is None else drawing.keypoints[index] * np.append(scale, 1.0),
            None if drawing.contacts is None else drawing.contacts[index],
            None if drawing.force_arrows is None else drawing.force_arrows[index] * scale,
            bool(drawing.valid[index]), bool(drawing.unexplained[index]),
        )
        writer.write_yuv420(canvas)
        count.frame_drawn()


class _VideoEnded(Exception):
    """The video ended after `frames` frames, before the last frame to draw."""

    def __init__(self, frames: int) -> None:
        super().__init__(frames)
        self.frames = frames


class _FrameCount:
    """One progress count over all parts: progress(done, total) after each frame drawn, from whichever part's
    thread drew it (one at a time); the last frame is reported by finish(), once the file is complete. already:
    frames reported by an earlier attempt, which count as work done (the count never runs backwards)."""

    def __init__(self, progress: Callable[[int, int], None] | None, total: int, already: int = 0) -> None:
        self.progress, self.total, self.already = progress, total, already
        self.done = already
        self._lock = threading.Lock()

    def frame_drawn(self) -> None:
        with self._lock:
            self.done += 1
            if self.progress is not None and self.done < self.already + self.total:
                self.progress(self.done, self.already + self.total)

    def finish(self) -> None:
        if self.progress is not None:
            self.progress(self.already + self.total, self.already + self.total)


def _render_part(frames: FrameReader[av.VideoFrame], path: str | os.PathLike, drawing: _OverlayDrawing, end: int,
                 count: _FrameCount, stops: Sequence[threading.Event], out_path: str | os.PathLike) -> None:
    """The drawing's frames from frames.start_frame up to `end` drawn and encoded into MP4 `path`; _VideoEnded
    (and no file) where the video ends before `end`, OverlayCancelled once any of `stops` is set."""
    out_width, out_height = frames.output_size
    with VideoWriter(path, drawing.fps or frames.info.fps, out_width, out_height, qp=OVERLAY_QP, preset=OVERLAY_PRESET,
                     faststart=Path(path) == Path(out_path)) as writer:  # a part is only read back by the join
        _draw_frames(frames, writer, drawing, end, count, stops, out_path)
        if writer.frames_written < end - frames.start_frame:
            raise _VideoEnded(frames.start_frame + writer.frames_written)


def _split_frame(frames: int) -> int:
    """The second part's first frame: the middle, or the frame after it where the first part would otherwise end
    on one of x264's keyframes (join_video_parts refuses two keyframes in a row at a joint)."""
    split = frames // 2
    return split + 1 if (split - 1) % X264_KEYINT == 0 else split


def _render_two_parts(video_path: str | os.PathLike, out_path: Path, drawing: _OverlayDrawing,
                      max_width: int | None, count: _FrameCount, cancel: threading.Event | None) -> None:
    """The drawing rendered as two parts at once, the first in this thread and the second in a worker (each
    with its own decoder, drawing and x264), into a temporary folder beside `out_path`, then joined into
    `out_path`. An error or cancel in either part stops both (a video that ends early stops only its part, so
    that the error says where it ends); the folder is removed in any case."""
    split = _split_frame(drawing.frames)
    stop = threading.Event()  # set when a part fails, so that the other stops too
    stops = (stop,) if cancel is None else (cancel, stop)
    outcomes: list[BaseException | None] = [None, None]
    out_path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{out_path.stem}.parts.", dir=out_path.parent) as folder:
        paths = [Path(folder) / "part1.mp4", Path(folder) / "part2.mp4"]

        def render(part: int, first: int, end: int) -> None:
            try:
                frames = iter_frames(video_path, max_width=max_width, prefetch=PREFETCH_FRAMES,
                                     pixel_format="yuv420p", start_frame=first)
                _render_part(frames, paths[part], drawing, end, count, stops, out_path)
            except _VideoEnded as ended:  # the other part goes on: where the video ends is the error's message
                outcomes[part] = ended
            except BaseException as error:  # raised in the calling thread below
                outcomes[part] = error
                stop.set()

        second = threading.Thread(target=render, args=(1, split, drawing.frames), name="physmocap-overlay-part2",
                                  daemon=True)
        second.start()
        try:
            render(0, 0, split)
            while second.is_alive():
                second.join(0.2)  # a timed wait keeps this thread responsive to Ctrl-C
        except BaseException:
            stop.set()
            second.join()
            raise
        _raise_first_error(outcomes)
        join_video_parts(paths, out_path)


def _raise_first_error(outcomes: Sequence[BaseException | None]) -> None:
    """Raise what stopped the parts, if anything: an error of its own before a video that ended early (the
    fewest frames it has) before a cancel, which the other part's stop causes as well."""
    errors = [error for error in outcomes if error is not None]
    own = [error for error in errors if not isinstance(error, _VideoEnded | OverlayCancelled)]
    ended = [error for error in errors if isinstance(error, _VideoEnded)]
    if own:
        raise own[0]
    if ended:
        raise min(ended, key=lambda error: error.frames)
    if errors:
        raise errors[0]


class OverlayJob:
    """render_overlay running in a worker thread (decoding, drawing and encoding release the GIL), so that the
    caller writes its other outputs meanwhile. Use as a context manager: leaving the block through an exception
    (Ctrl-C included) cancels the rendering, waits for the worker and leaves no file behind; leaving it normally
    waits for the rendering and raises its error, if any.

        with start_overlay(video, "overlay.mp4", points_2d, edges, valid, ...) as job:
            ...  # other outputs
            report = job.result()
    """

    def __init__(self, *args, **kwargs) -> None:
        self._cancel = threading.Event()
        self._report: OverlayReport | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=args, kwargs=kwargs, name="physmocap-overlay",
                                        daemon=True)
        self._thread.start()

    def _run(self, *args, **kwargs) -> None:
        try:
            self._report = render_overlay(*args, cancel=self._cancel, **kwargs)
        except BaseException as error:  # raised in the caller's thread by result()
            self._error = error

    def result(self) -> OverlayReport:
        """Wait for the rendering; its report, or the exception it raised."""
        while self._thread.is_alive():
            self._thread.join(0.2)  # a timed wait keeps the caller's thread responsive to Ctrl-C
        if self._error is not None:
            raise self._error
        assert self._report is not None
        return self._report

    def cancel(self) -> None:
        """Stop the rendering at the next frame and wait for the worker; no file is left."""
        self._cancel.set()
        self._thread.join()

    def __enter__(self) -> OverlayJob:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc is not None:
            self.cancel()
        else:
            self.result()  # a block that did not wait still gets the rendering's error


def start_overlay(*args, **kwargs) -> OverlayJob:
    """render_overlay(*args, **kwargs) started in a worker thread; see OverlayJob."""
    return OverlayJob(*args, **kwargs)
