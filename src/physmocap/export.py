"""`physmocap export RESULT.npz --to bvh|glb|opensim`: the animation and biomechanics files of any earlier run,
written from its result.npz alone (the skeleton is rebuilt from the stored bone lengths and mass).

Files per format (in `out_dir`):
- bvh: motion.bvh (Mixamo names, Y up, T-pose rest); options units "m" | "cm", root_at_origin.
- glb: motion.glb (skinned mannequin, metres, Y up); option root_at_origin.
- opensim: markers.trc (every point of joint_names), grf.mot (one force plate per foot) and external_loads.xml
  (applies grf.mot to calcn_r / calcn_l); option units "m" | "mm" for the markers.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .body.model import CONTACT_POINTS, BodyModel, SkeletonLengths, build_body_model
from .errors import InputError
from .io.bvh_export import UNIT_SCALE as BVH_UNITS, write_bvh
from .io.glb import write_glb
from .io.opensim import TRC_UNITS, write_external_loads, write_grf_mot, write_trc
from .result import load_result

EXPORT_FORMATS: tuple[str, ...] = ("bvh", "glb", "opensim")


def body_from_result(result: dict[str, np.ndarray]) -> BodyModel:
    """The run's body model, rebuilt exactly from result["body_lengths"] (JSON) and result["body_mass"] (kg)."""
    if "body_lengths" not in result:
        raise InputError("the result file lacks body_lengths, which exporting needs: capture it again.")
    lengths = SkeletonLengths(**json.loads(str(result["body_lengths"])))  # checked by load_result
    return build_body_model(lengths, float(result["body_mass"]))


def _export_bvh(result: dict, out_dir: Path, units: str = "m", root_at_origin: bool = False) -> dict[str, str]:
    _choice("units", units, BVH_UNITS)
    path = out_dir / "motion.bvh"
    write_bvh(path, body_from_result(result), result["qpos"], float(result["fps"]), units=units,
              root_at_origin=root_at_origin)
    return {"bvh": str(path)}


def _export_glb(result: dict, out_dir: Path, root_at_origin: bool = False) -> dict[str, str]:
    path = out_dir / "motion.glb"
    write_glb(path, body_from_result(result), result["qpos"], float(result["fps"]), root_at_origin=root_at_origin)
    return {"glb": str(path)}


def _export_opensim(result: dict, out_dir: Path, units: str = "m") -> dict[str, str]:
    _choice("units", units, TRC_UNITS)
    names = [str(n) for n in result["joint_names"]]
    fps = float(result["fps"])
    files = {"trc": out_dir / "markers.trc", "mot": out_dir / "grf.mot",
             "external_loads": out_dir / "external_loads.xml"}
    write_trc(files["trc"], result["joints_world"], names, fps, units=units)
    contact_points = result["joints_world"][:, [names.index(n) for n in CONTACT_POINTS]]
    write_grf_mot(files["mot"], result["grf"], contact_points, fps)
    write_external_loads(files["external_loads"], files["mot"].name)
    return {key: str(path) for key, path in files.items()}


EXPORTERS: dict[str, Callable[..., dict[str, str]]] = {
    "bvh": _export_bvh, "glb": _export_glb, "opensim": _export_opensim,
}
EXPORT_OPTIONS: dict[str, tuple[str, ...]] = {
    "bvh": ("units", "root_at_origin"), "glb": ("root_at_origin",), "opensim": ("units",),
}


def _choice(name: str, value: Any, allowed) -> None:
    if value not in allowed:
        raise InputError(f"{name} must be one of {', '.join(sorted(allowed))} for this format, got '{value}'.")


def export_result(result_path: str | os.PathLike, to: str, out_dir: str | os.PathLike,
                  **options: Any) -> dict[str, str]:
    """Write the `to` format ("bvh", "glb" or "opensim") of the run in `result_path` into `out_dir`.

    options: per format, see the module docstring; an option the format does not take is an InputError, and so
    is a missing or incomplete result file. Returns {kind: path} of the files written.
    """
    if to not in EXPORTERS:
        raise InputError(f"cannot export to '{to}': choose one of {', '.join(EXPORT_FORMATS)}.")
    unknown = sorted(set(options) - set(EXPORT_OPTIONS[to]))
    if unknown:
        raise InputError(f"the {to} export takes no option {', '.join(unknown)} "
                         f"(it takes: {', '.join(EXPORT_OPTIONS[to])}).")
    result = load_result(result_path)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return EXPORTERS[to](result, out_dir, **options)
