"""Only finite numbers reach a file: every writer passes its per-frame arrays through `finite_frames`, which
holds a frame with any non-finite value at the last finite frame (the first finite one before it) and says, as
a logging warning naming the file, which frames it blanked; every JSON file is written by `json_text`, where a
measure that is not defined (NaN) reads null."""

from __future__ import annotations

import json
import logging
import math

import numpy as np

from ..motion import frame_ranges

log = logging.getLogger("physmocap")

# Per-frame float arrays of result.npz (first axis: frames); the rest are flags, text or per-run constants.
RESULT_FRAME_ARRAYS = ("joints_world", "joints_world_kinematic", "qpos", "qpos_kinematic", "grf",
                       "residual_root_force", "physics_deviation", "person_height_px")


def finite_frames(values, what: str, fallback=None) -> np.ndarray:
    """values (T, ...) as floats with every frame that holds a NaN or infinity replaced by the last finite frame
    before it (before the first finite frame: that one). A clip without a finite frame takes `fallback` (one
    frame's values, e.g. the rest pose; default zeros). `what` names the array and file in the warning."""
    values = np.array(values, dtype=float)
    if values.ndim == 0 or len(values) == 0:
        return values
    bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    if not bad.any():
        return values
    good = np.flatnonzero(~bad)
    if len(good) == 0:
        values[:] = 0.0 if fallback is None else np.asarray(fallback, dtype=float)
        log.warning(f"{what}: no frame is finite; all {len(values)} frames written as "
                    f"{'zeros' if fallback is None else 'the rest pose'}.")
        return values
    source = np.maximum.accumulate(np.where(bad, -1, np.arange(len(values))))
    source[source < 0] = good[0]
    log.warning(f"{what}: frames {', '.join(frame_ranges(np.flatnonzero(bad)))} hold non-finite values; written as the "
                "nearest earlier finite frame.")
    return values[source]


def finite_value(value: float, what: str, fallback: float) -> float:
    """A per-run number (e.g. a mass), `fallback` with a warning when it is not finite."""
    value = float(value)
    if np.isfinite(value):
        return value
    log.warning(f"{what} is {value}; written as {fallback:g}.")
    return fallback


def finite_result(result: dict[str, np.ndarray], where: str) -> dict[str, np.ndarray]:
    """A copy of result.npz's arrays whose per-frame float arrays (RESULT_FRAME_ARRAYS) are finite, blanked as
    `finite_frames` does; per-frame errors (reprojection) may stay NaN where not measured."""
    out = dict(result)
    for key in RESULT_FRAME_ARRAYS:
        if key in out:
            out[key] = finite_frames(out[key], f"{where}: {key}", _rest_pose(out) if key.startswith("qpos") else None)
    return out


def _rest_pose(result: dict[str, np.ndarray]) -> np.ndarray | None:
    """The rest pose of the result's body, the stand-in for a motion without a single finite frame."""
    if np.isfinite(np.asarray(result["qpos"], dtype=float)).all(axis=-1).any():
        return None  # some frame is finite: the fallback is not needed
    from ..export import body_from_result

    return body_from_result(result).rest_qpos


def _json_finite(value):
    """`value` with every float that is not finite (numpy scalars and arrays included) as None."""
    if isinstance(value, dict):
        return {k: _json_finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_text(value, indent: int | None = None, sort_keys: bool = False) -> str:
    """Strict JSON of `value` (what every JSON file of a run holds): NaN and infinities as null, never as the
    NaN / Infinity tokens that browsers' and jq's parsers reject; other objects by str()."""
    return json.dumps(_json_finite(value), indent=indent, sort_keys=sort_keys, allow_nan=False, default=str)
