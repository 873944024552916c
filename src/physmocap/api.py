"""The Python API: what `physmocap capture` and `physmocap export` do, for a notebook or a script.

    import physmocap
    result = physmocap.capture("video.mp4", physics="trajopt", height=1.72)
    result.joint("left_ankle")      # (T, 3) metres, world frame (Z up, floor z = 0)
    physmocap.export(result, to="glb")

Units are SI throughout (metres, seconds, kilograms, newtons). Errors a user can fix raise
physmocap.errors.InputError (or one of its kinds) with a one-sentence message.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .settings_fields import nearest

PathLike = str | os.PathLike


@dataclass(frozen=True)
class Result:
    """A run's result.npz (the contract in docs/architecture.md), with its summary.json when it lies beside it.

    path: the result.npz file; arrays: every array in it by name (`result["grf"]` works too); summary: the
    run's summary.json as a dict (frames, timings, cached stages, warnings' frame ranges), or {}.
    """

    path: Path
    arrays: Mapping[str, np.ndarray]
    summary: Mapping[str, Any]

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def __contains__(self, key: object) -> bool:
        return key in self.arrays

    @property
    def folder(self) -> Path:
        """The run folder."""
        return self.path.parent

    @property
    def fps(self) -> float:
        """Frames per second."""
        return float(self.arrays["fps"])

    @property
    def num_frames(self) -> int:
        """T, the number of frames."""
        return len(self.arrays["qpos"])

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The names of the points in `joints_world` (DESIGN.md's 20 joints first, then landmark points)."""
        return tuple(str(n) for n in self.arrays["joint_names"])

    @property
    def joints_world(self) -> np.ndarray:
        """(T, J, 3) metres: the final motion's points in the world frame (Z up, floor z = 0)."""
        return self.arrays["joints_world"]

    @property
    def qpos(self) -> np.ndarray:
        """(T, nq) the final motion's generalised coordinates (MuJoCo order: root position m, root quaternion
        w x y z, then joint angles rad)."""
        return self.arrays["qpos"]

    @property
    def contacts(self) -> np.ndarray:
        """(T, 4) bool: left heel, left toe, right heel, right toe in contact."""
        return self.arrays["contacts"]

    @property
    def grf(self) -> np.ndarray:
        """(T, 4, 3) newtons: the ground reaction force at each contact point, world frame (zeros without
        physics)."""
        return self.arrays["grf"]

    @property
    def valid(self) -> np.ndarray:
        """(T,) bool: frames that could be reconstructed."""
        return self.arrays["valid"]

    @property
    def physics(self) -> str:
        """"none", "physcap" or "trajopt"."""
        return str(self.arrays.get("physics", "none"))

    def joint(self, name: str) -> np.ndarray:
        """(T, 3) metres: one point of `joint_names` over time, world frame."""
        if name not in self.joint_names:
            raise InputError(f"{self.path}: no joint named '{name}' (it has {', '.join(self.joint_names[:20])}, "
                             "...).")
        return self.joints_world[:, self.joint_names.index(name)]


def capture(source: PathLike, out_dir: PathLike | None = None, *, physics: str | None = None,
            online: bool = False, height: float | None = None, mass: float | None = None,
            config: PathLike | None = None, overlay: bool = True, **overrides: Any) -> Result:
    """Capture the motion of the one person in a video (or an observations .npz file) into a run folder.

    source: a video file, or an observations file (.npz, see the README) to skip detection.
    out_dir: the run folder; default runs/<source's name>. Stages whose inputs, settings and code are unchanged
        come from its cache, so a second call with a new physics setting does not detect again.
    physics: "physcap" (per frame; the default, as on the command line), "trajopt" (Rempe et al., whole clip,
        offline only) or "none" (kinematics only).
    online: fit causally frame by frame (as live capture does) instead of the whole clip at once.
    height: the person's standing height, metres; mass: their mass, kilograms (defaults: the settings').
    config: a TOML settings file, applied first.
    overlay: draw the fit on the video as overlay.mp4 (videos only).
    overrides: any other setting as <section>_<field>=value, e.g. fit_weight_smooth=0.2,
        physics_contact_height=0.05 (config.py lists them with their units and ranges).
    """
    from .config import load_settings
    from .pipeline import run_capture

    source = Path(source)
    settings = load_settings(None if config is None else Path(config))
    settings = settings.replace(None, online=online) if online else settings
    settings = settings.replace("physics", method=physics) if physics else settings
    body = {k: v for k, v in (("height", height), ("mass", mass)) if v is not None}
    settings = settings.replace("body", **body) if body else settings
    settings = _with_overrides(settings, overrides).check()
    is_observations = source.suffix.lower() == ".npz"
    if not is_observations:
        from .io.video import probe_video

        probe_video(source)  # fail before any folder is made
    out = Path(out_dir) if out_dir is not None else Path("runs") / source.stem
    run_capture(out, settings, video=None if is_observations else source,
                observations=source if is_observations else None, overlay=overlay and not is_observations)
    return load_result(out)


def _with_overrides(settings: Any, overrides: Mapping[str, Any]) -> Any:
    """settings with <section>_<field>=value overrides applied; InputError names an unknown one."""
    sections = [f.name for f in dataclasses.fields(settings) if dataclasses.is_dataclass(getattr(settings, f.name))]
    for name, value in overrides.items():
        section = next((s for s in sections if name.startswith(s + "_")), None)
        field = name[len(section) + 1:] if section else ""
        if section is None or field not in {f.name for f in dataclasses.fields(getattr(settings, section))}:
            known = [f"{s}_{f.name}" for s in sections for f in dataclasses.fields(getattr(settings, s))]
            raise InputError(f"capture() got an unknown setting '{name}'{nearest(name, known)}: write "
                             f"<section>_<field>, with section one of {', '.join(sections)} (e.g. fit_weight_smooth).")
        settings = settings.replace(section, **{field: tuple(value) if isinstance(value, list) else value})
    return settings


def load_result(path: PathLike | Result) -> Result:
    """The Result of a run folder or of its result.npz; InputError naming the file when it is missing, unreadable
    or incomplete."""
    import json

    from .result import load_result as read_result

    if isinstance(path, Result):
        return path
    path = Path(path)
    file = path / "result.npz" if path.is_dir() else path
    arrays = read_result(file)
    summary: dict[str, Any] = {}
    try:
        summary = json.loads((file.parent / "summary.json").read_text())
    except (OSError, ValueError):
        pass  # a result file on its own
    return Result(file, arrays, summary)


def export(result: PathLike | Result, to: str = "bvh", out: PathLike | None = None, **options: Any) -> dict[str, Path]:
    """Write a run's motion in another format; returns {kind: path} of the files written.

    result: a Result, a run folder or a result.npz.
    to: "bvh" (motion.bvh: Mixamo names, Y up; options units="m" | "cm", root_at_origin=bool), "glb" (motion.glb:
        skinned mannequin, metres, Y up; option root_at_origin) or "opensim" (markers.trc, grf.mot,
        external_loads.xml; option units="m" | "mm" for the markers).
    out: the folder to write into; default the run folder.
    """
    from .export import export_result

    loaded = load_result(result)
    written = export_result(loaded.path, to, loaded.folder if out is None else Path(out), **options)
    return {kind: Path(p) for kind, p in written.items()}
