"""Still figures for the README and reports, drawn with matplotlib's Agg canvas (no display, no pyplot state)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io.atomic import atomic_path
from .overlay import CENTRE_COLOUR, Colour, draw_overlay, edge_colour

if TYPE_CHECKING:
    from matplotlib.axes import Axes

FLOOR_COLOUR = "0.6"
TRAJECTORY_COLOUR = "tab:green"
CENTRE_LINE_3D = (0.2, 0.2, 0.2)  # the overlay's white centre line would vanish on the white 3D view


def _colour_3d(colour_bgr: Colour) -> tuple[float, float, float]:
    """An overlay BGR 0-255 colour as matplotlib RGB 0-1 for the white 3D view."""
    if colour_bgr == CENTRE_COLOUR:
        return CENTRE_LINE_3D
    b, g, r = colour_bgr
    return r / 255, g / 255, b / 255


def _floor_grid_step(extent: float) -> float:
    """A round grid spacing (0.1, 0.2, 0.5, 1, 2, ... m) giving about 8 cells across `extent` metres."""
    raw = max(extent, 1e-3) / 8
    decade = 10 ** np.floor(np.log10(raw))
    return float(decade * min(m for m in (1, 2, 5, 10) if m * decade >= raw))


def result_figure(
    frame_bgr: np.ndarray,
    points_2d_frame: np.ndarray,
    edges: Sequence[tuple[int, int]],
    joints_world_clip: np.ndarray,
    frame_index: int,
    out_png: str | os.PathLike,
    *,
    labels: Sequence[str] | None = None,
    root_index: int = 0,
) -> None:
    """A PNG: the video frame with the fitted skeleton (left) beside a 3D view of the same pose (right).

    frame_bgr: (H, W, 3) uint8 video frame. points_2d_frame: (P, 2) fitted points in that frame's pixels.
    edges: bones as index pairs into the P points; the same indices address joints_world_clip.
    joints_world_clip: (T, P, 3) world positions over the clip, metres, Z up, floor z = 0; the 3D view shows frame
    `frame_index`, the floor as a grid and the path of point `root_index` (the pelvis in JOINT_NAMES order) over
    the whole clip. labels: (P,) point names for the left/right colours. Written atomically.
    """
    joints_world_clip = np.asarray(joints_world_clip, dtype=float)
    if joints_world_clip.ndim != 3 or joints_world_clip.shape[2] != 3:
        raise ValueError(f"joints_world_clip must have shape (T, P, 3), got {joints_world_clip.shape}.")
    if not 0 <= frame_index < len(joints_world_clip):
        raise ValueError(f"frame_index {frame_index} is outside the clip of {len(joints_world_clip)} frames.")

    overlay = draw_overlay(frame_bgr, np.asarray(points_2d_frame, dtype=float), edges, labels=labels)
    height, width = overlay.shape[:2]
    figure = Figure(figsize=(12.0, 12.0 * 0.5 * max(height / width, 0.75)), dpi=120, layout="constrained")
    FigureCanvasAgg(figure)
    image_axes = figure.add_subplot(1, 2, 1)
    image_axes.imshow(overlay[:, :, ::-1])
    image_axes.set_axis_off()
    image_axes.set_title(f"frame {frame_index}")

    view = figure.add_subplot(1, 2, 2, projection="3d")
    centre, half = _floor_and_bounds(view, joints_world_clip)
    root = joints_world_clip[:, root_index]
    view.plot(*root.T, color=TRAJECTORY_COLOUR, linewidth=1.2, label="root path")
    view.plot(root[:, 0], root[:, 1], np.zeros(len(root)), color=TRAJECTORY_COLOUR, linewidth=0.8, alpha=0.4)
    pose = joints_world_clip[frame_index]
    for i, j in edges:
        view.plot(*pose[[i, j]].T, color=_colour_3d(edge_colour((i, j), labels)), linewidth=2.5)
    view.scatter(*root[frame_index], color=TRAJECTORY_COLOUR, s=25, depthshade=False)
    view.set_xlim(centre[0] - half, centre[0] + half)
    view.set_ylim(centre[1] - half, centre[1] + half)
    view.set_zlim(0.0, 2 * half)
    view.set_box_aspect((1.0, 1.0, 1.0))
    view.grid(False)  # the floor grid is the only grid
    view.set_xlabel("x (m)")
    view.set_ylabel("y (m)")
    view.set_zlabel("z (m)")
    view.view_init(elev=15, azim=-60)
    view.legend(loc="upper left")
    with atomic_path(out_png) as tmp:
        figure.savefig(tmp, format="png")


def _floor_and_bounds(view: Axes, joints_world_clip: np.ndarray) -> tuple[np.ndarray, float]:
    """Draw the floor grid under the clip's points (T, P, 3) on `view`; the centre (3,) and half side, metres,
    of the cube that holds the clip."""
    finite = joints_world_clip[np.all(np.isfinite(joints_world_clip), axis=2)]
    low, high = finite.min(axis=0), finite.max(axis=0)
    centre = (low + high) / 2
    half = max(high[0] - low[0], high[1] - low[1], high[2], 1.0) / 2 + 0.2
    step = _floor_grid_step(2 * half)
    ticks = np.arange(np.floor((centre[0] - half) / step), np.ceil((centre[0] + half) / step) + 1) * step
    y_ticks = np.arange(np.floor((centre[1] - half) / step), np.ceil((centre[1] + half) / step) + 1) * step
    for x in ticks:
        view.plot([x, x], [y_ticks[0], y_ticks[-1]], [0.0, 0.0], color=FLOOR_COLOUR, linewidth=0.6)
    for y in y_ticks:
        view.plot([ticks[0], ticks[-1]], [y, y], [0.0, 0.0], color=FLOOR_COLOUR, linewidth=0.6)
    return centre, half
