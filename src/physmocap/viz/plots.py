"""Plots of a run (PNG, matplotlib's Agg canvas, no display): ground reaction forces per foot against body weight,
contact flags, and foot heights above the floor. Each takes the result.npz arrays (see README "The result file")."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..body.kinematics import center_of_mass, forward_kinematics
from ..body.model import CONTACT_POINTS
from ..export import body_from_result
from ..io.atomic import atomic_path
from ..io.finite import finite_result
from ..metrics import GRAVITY, implied_grf

FOOT_COLOURS = {"left": "#1e88e5", "right": "#fb8c00"}
POINT_STYLES = {"left_heel": ("#1e88e5", "-"), "left_toe": ("#1e88e5", "--"),
                "right_heel": ("#fb8c00", "-"), "right_toe": ("#fb8c00", "--")}
PLOT_FILES = {"grf": "grf.png", "contacts": "contacts.png", "foot_heights": "foot_heights.png"}


def _times(result: dict[str, np.ndarray]) -> np.ndarray:
    return np.arange(len(result["joints_world"])) / float(result["fps"])


def _figure(rows: int = 1, height: float = 3.2) -> tuple[Figure, list]:
    figure = Figure(figsize=(10.0, height), dpi=110, layout="constrained")
    FigureCanvasAgg(figure)
    axes = [figure.add_subplot(rows, 1, i + 1) for i in range(rows)]
    return figure, axes


def _save(figure: Figure, path: str | os.PathLike) -> None:
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png")


def plot_grf(result: dict[str, np.ndarray], out_png: str | os.PathLike) -> None:
    """Vertical ground reaction force of each foot (heel + toe) and their sum over time, newtons, against the body
    weight m g. Without physics (all-zero grf) it shows the net vertical force the final motion's centre of mass
    implies, m (a_z + g), and says so."""
    t = _times(result)
    weight = float(result["body_mass"]) * GRAVITY
    grf = np.asarray(result["grf"], dtype=float)
    figure, (axes,) = _figure()
    if np.any(grf != 0):
        for side, (heel, toe) in (("left", (0, 1)), ("right", (2, 3))):
            axes.plot(t, grf[:, heel, 2] + grf[:, toe, 2], color=FOOT_COLOURS[side], label=f"{side} foot")
        axes.plot(t, grf[..., 2].sum(axis=1), color="0.2", linewidth=1.0, label="both feet")
        axes.set_title("Vertical ground reaction force (solved by physics)")
    elif len(t) < 3:
        axes.set_title("No force plot: the motion's acceleration needs at least 3 frames")
    else:
        body = body_from_result(result)
        com = center_of_mass(body, forward_kinematics(body, result["qpos"]))
        axes.plot(t, implied_grf(com, body.mass, float(result["fps"]))[:, 2], color="0.2",
                  label="implied by the centre of mass")
        axes.set_title("Net vertical force implied by the motion (no physics in this run)")
    axes.axhline(weight, color="#43a047", linestyle=":", label=f"body weight ({weight:.0f} N)")
    axes.set_xlabel("time (s)")
    axes.set_ylabel("force (N)")
    axes.set_xlim(t[0], max(t[-1], t[0] + 1e-3))
    axes.legend(loc="upper right", fontsize=8)
    axes.grid(alpha=0.3)
    _save(figure, out_png)


def plot_contacts(result: dict[str, np.ndarray], out_png: str | os.PathLike) -> None:
    """Contact flags over time, one row per contact point: the flags used (filled) and, where the result has them
    and they differ, the contact stage's predictions (thin bar below)."""
    t = _times(result)
    dt = 1.0 / float(result["fps"])
    used = np.asarray(result["contacts"], bool)
    predicted = np.asarray(result.get("contacts_predicted", used), bool)
    show_predicted = not np.array_equal(used, predicted)
    figure, (axes,) = _figure(height=2.4)
    for row, name in enumerate(CONTACT_POINTS):
        colour = POINT_STYLES[name][0]
        y = len(CONTACT_POINTS) - 1 - row
        bars = [(used[:, row], y - 0.3, 0.5, 0.9)]
        if show_predicted:
            bars.append((predicted[:, row], y - 0.42, 0.08, 0.6))
        for flags, bottom, height, alpha in bars:
            starts = np.flatnonzero(flags & ~np.r_[False, flags[:-1]])
            ends = np.flatnonzero(flags & ~np.r_[flags[1:], False])
            axes.broken_barh([(t[s], t[e] - t[s] + dt) for s, e in zip(starts, ends, strict=True)], (bottom, height),
                             facecolors=colour, alpha=alpha)
    axes.set_yticks(range(len(CONTACT_POINTS)), [n.replace("_", " ") for n in reversed(CONTACT_POINTS)])
    axes.set_ylim(-0.6, len(CONTACT_POINTS) - 0.4)
    axes.set_xlim(t[0], t[-1] + dt)
    axes.set_xlabel("time (s)")
    axes.set_title("Foot contacts" + (" (thin: predicted before foot-lock/physics)" if show_predicted else ""))
    axes.grid(axis="x", alpha=0.3)
    _save(figure, out_png)


def plot_foot_heights(result: dict[str, np.ndarray], out_png: str | os.PathLike) -> None:
    """Height above the floor of the heels and toes over time, centimetres, final motion (solid/dashed lines)
    with the frames in contact marked by dots; the kinematic motion's as faint lines."""
    t = _times(result)
    names = [str(n) for n in result["joint_names"]]
    ids = [names.index(n) for n in CONTACT_POINTS]
    final = result["joints_world"][:, ids, 2] * 100
    kinematic = result["joints_world_kinematic"][:, ids, 2] * 100
    used = np.asarray(result["contacts"], bool)
    figure, (axes,) = _figure()
    for k, name in enumerate(CONTACT_POINTS):
        colour, style = POINT_STYLES[name]
        axes.plot(t, kinematic[:, k], color=colour, linestyle=style, alpha=0.25, linewidth=1.0)
        axes.plot(t, final[:, k], color=colour, linestyle=style, label=name.replace("_", " "))
        axes.plot(t[used[:, k]], final[used[:, k], k], "o", color=colour, markersize=2.5)
    axes.axhline(0.0, color="0.3", linewidth=0.8)
    axes.set_xlabel("time (s)")
    axes.set_ylabel("height above floor (cm)")
    axes.set_xlim(t[0], max(t[-1], t[0] + 1e-3))
    axes.set_title("Foot heights (dots: in contact; faint: kinematic motion before physics)")
    axes.legend(loc="upper right", fontsize=8, ncol=2)
    axes.grid(alpha=0.3)
    _save(figure, out_png)


def write_plots(result: dict[str, np.ndarray], out_dir: str | os.PathLike) -> dict[str, str]:
    """All plots into `out_dir` (PLOT_FILES names); returns {plot: path}."""
    out_dir = Path(out_dir)
    result = finite_result(result, str(out_dir))
    paths = {key: str(out_dir / name) for key, name in PLOT_FILES.items()}
    plot_grf(result, paths["grf"])
    plot_contacts(result, paths["contacts"])
    plot_foot_heights(result, paths["foot_heights"])
    return paths
