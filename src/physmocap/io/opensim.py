"""OpenSim exports: marker trajectories (.trc), ground reaction forces (.mot) and the ExternalLoads file (.xml)
that applies them to a model's feet.

Axes: OpenSim's convention, X forward, Y up, Z to the right, so (X, Y, Z)_opensim = (x, z, -y)_world, a proper
rotation; the floor z = 0 becomes the plane Y = 0. Times are frame / fps in seconds.

Ground reaction forces: the result's four contact forces (left heel, left toe, right heel, right toe) become one
force plate per foot, as OpenSim's examples write them: the net force of the heel and toe (`<side>_ground_force_v*`,
newtons), its point of application on the floor (`<side>_ground_force_p*`, metres, the centre of pressure) and a
torque (`<side>_ground_torque_*`, newton metres) so that force at point plus torque is exactly the wrench of the two
point forces. While the vertical force is at least MIN_COP_FORCE the point is the centre of pressure and the torque
is the free moment about the vertical; below it the centre of pressure is undefined, so the point is the middle of
the foot on the floor and the torque carries the whole remaining moment.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from .atomic import write_text
from .finite import finite_frames

WORLD_TO_OPENSIM = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
TRC_UNITS: dict[str, float] = {"m": 1.0, "mm": 1000.0}
TRC_DECIMALS: dict[str, int] = {"m": 6, "mm": 3}
MIN_COP_FORCE = 5.0  # N of vertical force below which a foot has no centre of pressure
FOOT_SIDES: tuple[tuple[str, int, int], ...] = (("r", 2, 3), ("l", 0, 1))  # prefix, heel index, toe index
DEFAULT_FOOT_BODIES: dict[str, str] = {"r": "calcn_r", "l": "calcn_l"}  # gait2392, Rajagopal 2015 models


def _check_series(array: np.ndarray, shape_tail: tuple[int, ...], name: str) -> np.ndarray:
    """The array as floats, its non-finite frames held at the last finite one (a warning names `name`)."""
    values = np.asarray(array, dtype=float)
    if values.ndim != 1 + len(shape_tail) or values.shape[1:] != shape_tail or len(values) == 0:
        raise ValueError(f"{name} must have shape (T >= 1, {', '.join(map(str, shape_tail))}), got {values.shape}.")
    return finite_frames(values, name)


def _check_fps(fps: float) -> None:
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}.")


def write_trc(path: str | os.PathLike, points_world: np.ndarray, names: Sequence[str], fps: float, *,
              units: str = "m") -> None:
    """Marker trajectories as an OpenSim .trc file (tab separated, Motion Analysis layout).

    points_world: (T, P, 3) metres, world axes (Z up). names: (P,) marker names. units: "m" or "mm" for the file.
    Frames are numbered from 1; written atomically.
    """
    _check_fps(fps)
    if units not in TRC_UNITS:
        raise ValueError(f"units must be one of {sorted(TRC_UNITS)}, got {units!r}.")
    names = [str(n) for n in names]
    points = _check_series(points_world, (len(names), 3), f"{path}: points_world")
    if any(not n or any(c.isspace() for c in n) for n in names) or len(set(names)) != len(names):
        raise ValueError("marker names must be unique and free of whitespace.")
    T, P = points.shape[:2]
    values = points @ WORLD_TO_OPENSIM.T * TRC_UNITS[units]
    decimals = TRC_DECIMALS[units]
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{Path(path).name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{fps:.6g}\t{fps:.6g}\t{T}\t{P}\t{units}\t{fps:.6g}\t1\t{T}",
        "Frame#\tTime\t" + "\t".join(f"{n}\t\t" for n in names).rstrip("\t"),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, P + 1)),
        "",
    ]
    rows = np.round(values.reshape(T, 3 * P), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0
    for frame in range(T):
        numbers = "\t".join(f"{v:.{decimals}f}" for v in rows[frame])
        lines.append(f"{frame + 1}\t{frame / fps:.6f}\t{numbers}")
    write_text(path, "\n".join(lines) + "\n")


def foot_wrenches(grf: np.ndarray, contact_points: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per foot, the force-plate form of the heel and toe forces, in world axes (floor z = 0).

    grf: (T, 4, 3) newtons and contact_points: (T, 4, 3) metres, both in CONTACT_POINTS order.
    Returns {"r": (force, point, torque), "l": ...}, each (T, 3): force N, point on the floor m, torque N m; force
    at point plus torque equals the two point forces (see the module docstring).
    """
    grf = _check_series(grf, (4, 3), "grf")
    contact_points = _check_series(contact_points, (4, 3), "contact_points")
    if len(contact_points) != len(grf):
        raise ValueError(f"grf has {len(grf)} frames but contact_points {len(contact_points)}.")
    wrenches = {}
    for side, heel, toe in FOOT_SIDES:
        force = grf[:, heel] + grf[:, toe]
        moment = np.cross(contact_points[:, heel], grf[:, heel]) + np.cross(contact_points[:, toe], grf[:, toe])
        vertical = force[:, 2]
        pressing = vertical >= MIN_COP_FORCE
        safe = np.where(pressing, vertical, 1.0)
        centre_of_pressure = np.stack([-moment[:, 1] / safe, moment[:, 0] / safe, np.zeros(len(force))], axis=1)
        middle = (contact_points[:, heel] + contact_points[:, toe]) / 2 * np.array([1.0, 1.0, 0.0])
        point = np.where(pressing[:, None], centre_of_pressure, middle)
        wrenches[side] = (force, point, moment - np.cross(point, force))
    return wrenches


def grf_columns(grf: np.ndarray, contact_points: np.ndarray) -> tuple[list[str], np.ndarray]:
    """Column labels (without time) and values (T, 18) of the GRF .mot file, OpenSim axes."""
    wrenches = foot_wrenches(grf, contact_points)
    labels, columns = [], []
    for side, _, _ in FOOT_SIDES:
        force, point, _ = wrenches[side]
        labels += [f"{side}_ground_force_v{a}" for a in "xyz"] + [f"{side}_ground_force_p{a}" for a in "xyz"]
        columns += [force @ WORLD_TO_OPENSIM.T, point @ WORLD_TO_OPENSIM.T]
    for side, _, _ in FOOT_SIDES:
        labels += [f"{side}_ground_torque_{a}" for a in "xyz"]
        columns.append(wrenches[side][2] @ WORLD_TO_OPENSIM.T)
    return labels, np.concatenate(columns, axis=1)


def write_grf_mot(path: str | os.PathLike, grf: np.ndarray, contact_points: np.ndarray, fps: float) -> None:
    """Ground reaction forces as an OpenSim .mot file (Storage version 1 header), one force plate per foot.

    grf: (T, 4, 3) N, contact_points: (T, 4, 3) m, world axes, CONTACT_POINTS order. Written atomically.
    """
    _check_fps(fps)
    grf = _check_series(grf, (4, 3), f"{path}: grf")
    contact_points = _check_series(contact_points, (4, 3), f"{path}: contact_points")
    labels, values = grf_columns(grf, contact_points)
    values = finite_frames(values, f"{path}: ground reaction force columns")  # huge inputs may overflow
    T = len(values)
    lines = [Path(path).name, "version=1", f"nRows={T}", f"nColumns={len(labels) + 1}", "inDegrees=no",
             "endheader", "time\t" + "\t".join(labels)]
    values = np.round(values, 6) + 0.0
    for frame in range(T):
        lines.append(f"{frame / fps:.6f}\t" + "\t".join(f"{v:.6f}" for v in values[frame]))
    write_text(path, "\n".join(lines) + "\n")


def write_external_loads(path: str | os.PathLike, grf_file: str,
                         foot_bodies: dict[str, str] = DEFAULT_FOOT_BODIES) -> None:
    """An OpenSim ExternalLoads .xml applying the .mot file `grf_file` (a path relative to this file, as OpenSim
    resolves it) to the model bodies `foot_bodies` {"r": ..., "l": ...}; forces and points in ground."""
    forces = []
    for side, _, _ in FOOT_SIDES:
        forces.append(f"""      <ExternalForce name="{side}_foot_grf">
        <applied_to_body>{escape(foot_bodies[side])}</applied_to_body>
        <force_expressed_in_body>ground</force_expressed_in_body>
        <point_expressed_in_body>ground</point_expressed_in_body>
        <force_identifier>{side}_ground_force_v</force_identifier>
        <point_identifier>{side}_ground_force_p</point_identifier>
        <torque_identifier>{side}_ground_torque_</torque_identifier>
      </ExternalForce>""")
    text = f"""<?xml version="1.0" encoding="UTF-8" ?>
<OpenSimDocument Version="40000">
  <ExternalLoads name="physmocap_grf">
    <objects>
{chr(10).join(forces)}
    </objects>
    <groups />
    <datafile>{escape(grf_file)}</datafile>
  </ExternalLoads>
</OpenSimDocument>
"""
    write_text(path, text)
