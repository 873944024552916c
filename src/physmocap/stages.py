"""The stages of a capture and their cache contract.

A stage is a name, the cache file its output goes to, the code it runs (modules whose source, with everything
they import from physmocap, is its code version), the settings it reads, and the conversion of its output to and
from arrays (the motion containers' `to_arrays` / `from_arrays`). Its cache key digests its inputs' contents,
those settings and that code version, so a changed input, setting or algorithm never reuses a stale output.

A cache entry is `cache/<file>.npz` beside `cache/<file>.key`, a JSON line with the stage's key and the SHA-256
of the .npz file. An entry is used only when both match; a damaged or replaced file (truncated, emptied, another
run's) fails the checksum, is reported in one warning line and recomputed. See docs/architecture.md.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import hashlib
import json
import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar

import numpy as np

from .config import Settings
from .io.atomic import read_npz, save_npz, write_text
from .motion import Observations

if TYPE_CHECKING:
    from .dynamics.stage import PhysicsMotion
    from .kinematics.stage import KinematicMotion
    from .trajopt.stage import TrajoptMotion

log = logging.getLogger("physmocap")

Output = TypeVar("Output")
Progress = Callable[[int, int], None]  # update(done, total)


class ProgressFactory(Protocol):
    """factory(name, total, unit) -> one progress display, updated as update(done, total); `unit` names what is
    counted, in the plural."""

    def __call__(self, name: str, total: int, unit: str = "frames") -> Progress: ...


PACKAGE = "physmocap"


# ---- code version -------------------------------------------------------------------------------------------

PACKAGE_ROOT = Path(__file__).resolve().parent


def module_path(name: str) -> Path | None:
    """The source file of physmocap module `name` (a package's __init__.py), None if there is none. Found on
    disk, without importing anything."""
    if name == PACKAGE:
        return PACKAGE_ROOT / "__init__.py"
    relative = Path(*name.split(".")[1:])
    for candidate in (PACKAGE_ROOT / relative.with_suffix(".py"), PACKAGE_ROOT / relative / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def module_source(name: str) -> bytes:
    """The source of physmocap module `name` (b"" where it has no source file)."""
    path = module_path(name)
    return b"" if path is None else path.read_bytes()


@functools.cache
def _imported_modules(name: str) -> frozenset[str]:
    """The physmocap modules that module `name` imports anywhere in its body (functions included)."""
    source = module_source(name)
    path = module_path(name)
    package = name if path is not None and path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in _import_statements(ast.parse(source).body):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name.split(".")[0] == PACKAGE)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            if base.split(".")[0] != PACKAGE:
                continue
            found.add(base)
            # `from .pkg import module` imports a module, not only a name
            found.update(f"{base}.{alias.name}" for alias in node.names
                         if module_path(f"{base}.{alias.name}") is not None)
    return frozenset(m for m in found if module_path(m) is not None)


def _import_statements(body: list) -> Iterator[ast.Import | ast.ImportFrom]:
    """The import statements among `body` and the statements nested in it (functions, classes, branches)."""
    for node in body:
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        for field in ("body", "orelse", "finalbody", "handlers"):
            yield from _import_statements(getattr(node, field, None) or [])


@functools.cache
def code_closure(*modules: str) -> tuple[str, ...]:
    """`modules` and every physmocap module they import, transitively, sorted. ValueError for a module that does
    not exist (a stage naming a moved module would otherwise lose track of its code)."""
    missing = [name for name in modules if module_path(name) is None]
    if missing:
        raise ValueError(f"no source for the stage module(s) {', '.join(missing)}")
    seen: set[str] = set()
    todo = list(modules)
    while todo:
        name = todo.pop()
        if name not in seen:
            seen.add(name)
            todo.extend(_imported_modules(name) - seen)
    return tuple(sorted(seen))


def code_version(*modules: str) -> str:
    """A digest of the source of `modules` and of everything they import from physmocap: it changes whenever
    any of that code does (no version number to bump by hand)."""
    digest = hashlib.sha256()
    for name in code_closure(*modules):
        digest.update(name.encode() + b"\0" + module_source(name) + b"\0")
    return digest.hexdigest()[:16]


# ---- content digests ----------------------------------------------------------------------------------------

def digest(*parts: Any) -> str:
    """A short digest of JSON-able parts (settings, other digests)."""
    text = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def arrays_digest(arrays: dict[str, Any], skip: tuple[str, ...] = ()) -> str:
    """A digest of named arrays' names, dtypes, shapes and bytes."""
    h = hashlib.sha256()
    for name in sorted(set(arrays) - set(skip)):
        value = np.ascontiguousarray(arrays[name])
        if value.dtype == object:
            value = value.astype(str)
        h.update(f"{name}:{value.dtype.str}:{value.shape}:".encode())
        h.update(value.tobytes())
    return h.hexdigest()[:16]


def file_digest(path: Path) -> str:
    """SHA-256 of a file's bytes, streamed (about 1 GB/s: benchmarks/bench_cache_hash.py)."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def observations_digest(obs: Observations) -> str:
    """A digest of everything in the observations that a later stage reads."""
    return arrays_digest(dict(keypoints_2d=obs.keypoints_2d, landmarks_3d=obs.landmarks_3d, valid=obs.valid,
                              invalid_reason=obs.invalid_reason, fps=np.float64(obs.fps),
                              image_size=np.array(obs.image_size),
                              camera_K=np.zeros(0) if obs.camera_K is None else obs.camera_K))


def motion_digest(motion: Any) -> str:
    """A digest of a stage output with `to_arrays`, without its timing (a re-run takes a different time)."""
    return arrays_digest(motion.to_arrays(), skip=("seconds",))


def as_stored(obs: Observations) -> Observations:
    """The observations at the precision the observations file stores (float32 coordinates): every run starts
    from exactly what a re-run from the cache or from `--observations` reads, so all three give the same result
    (the whole-clip fit is sensitive enough that 1e-5 px of rounding moved joints by 0.27 m)."""
    return dataclasses.replace(obs, keypoints_2d=stored_precision(obs.keypoints_2d),
                               landmarks_3d=stored_precision(obs.landmarks_3d))


def stored_precision(values: np.ndarray) -> np.ndarray:
    """float64 values rounded to float32, as Observations.save stores them."""
    return np.asarray(values, dtype=np.float32).astype(np.float64)


# ---- the cache ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Stage(Generic[Output]):
    """name: as in summary.json (stage_seconds, cached_stages); file: the cache entry's name under cache/;
    code: the modules whose source (with their physmocap imports) is the stage's code version; settings: the
    part of the settings the stage reads; run(settings, progress, *inputs): the computation; write / read: the
    output to and from an .npz file."""

    name: str
    file: str
    code: tuple[str, ...]
    settings: Callable[[Settings], Any]
    run: Callable[..., Output]
    write: Callable[[Path, Output], None]
    read: Callable[[Path], Output]

    def key(self, settings: Settings, *inputs: str) -> str:
        """The cache key: the inputs' digests, the stage's settings and its code version (this module's own
        source included, for the wiring of `run`)."""
        return digest(self.name, inputs, self.settings(settings), code_version(*self.code),
                      hashlib.sha256(module_source(__name__)).hexdigest()[:16])


class CacheFolder:
    """The stage caches of one run folder (`folder/cache/`)."""

    def __init__(self, folder: Path):
        self.folder = folder / "cache"

    def paths(self, stage: Stage) -> tuple[Path, Path]:
        return self.folder / f"{stage.file}.npz", self.folder / f"{stage.file}.key"

    def load(self, stage: Stage[Output], key: str) -> Output | None:
        """The stage's cached output under `key`, or None: absent, written under another key (other inputs,
        settings or code), or damaged (said in one warning line)."""
        data, key_file = self.paths(stage)
        if not data.is_file() or not key_file.is_file():
            return None
        try:
            entry = json.loads(key_file.read_text())
            stored_key, checksum = entry["key"], entry["sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            log.warning("%s is damaged; recomputing the %s stage.", key_file, stage.name)
            return None
        if stored_key != key:
            return None
        if file_digest(data) != checksum:
            log.warning("%s is damaged or was replaced (its checksum does not match); recomputing the %s stage.",
                        data, stage.name)
            return None
        try:
            return stage.read(data)
        except Exception as exc:  # noqa: BLE001 - a checked file that cannot be read is recomputed, whatever broke
            log.warning("%s cannot be read (%s); recomputing the %s stage.", data, exc, stage.name)
            return None

    def store(self, stage: Stage[Output], key: str, output: Output) -> None:
        """Write the output, then its key file: an interrupted write leaves no entry that would be trusted."""
        data, key_file = self.paths(stage)
        key_file.unlink(missing_ok=True)
        stage.write(data, output)
        write_text(key_file, json.dumps({"key": key, "sha256": file_digest(data)}))


class Runner:
    """Runs stages against one run folder's caches and keeps the account that summary.json gives: seconds per
    stage and the stages that came from the cache."""

    def __init__(self, folder: Path, settings: Settings, progress: ProgressFactory | None = None):
        self.cache = CacheFolder(folder)
        self.settings = settings
        self.progress = progress
        self.seconds: dict[str, float] = {}
        self.cached: list[str] = []

    def lookup(self, stage: Stage[Output], inputs: tuple[str, ...]) -> Output | None:
        """The stage's cached output for these input digests, or None."""
        output = self.cache.load(stage, stage.key(self.settings, *inputs))
        if output is not None:
            self.cached.append(stage.name)
        return output

    def run(self, stage: Stage[Output], inputs: tuple[str, ...], *args: Any) -> Output:
        """stage.run(settings, progress, *args), or its cached output for these input digests."""
        output = self.lookup(stage, inputs)
        if output is None:
            output = stage.run(self.settings, self.progress, *args)
            self.store(stage, inputs, output)
        return output

    def store(self, stage: Stage[Output], inputs: tuple[str, ...], output: Output) -> None:
        """Cache an output computed elsewhere (the live-order stream computes detection and fit together)."""
        self.cache.store(stage, stage.key(self.settings, *inputs), output)


def _bar(progress: ProgressFactory | None, name: str, total: int) -> Progress | None:
    return progress(name, total) if progress else None


# ---- the stages ---------------------------------------------------------------------------------------------

def detect(settings: Settings, progress: ProgressFactory | None, video: Path) -> Observations:
    """MediaPipe's observations of the video, at the precision they are stored (`as_stored`)."""
    from .detect.mediapipe_pose import detect_video

    return as_stored(detect_video(video, person_box=settings.detect.person_box,
                                  max_width=settings.detect.max_width, progress=_bar(progress, "detect", 0),
                                  graphs=settings.detect.graphs))


def fit(settings: Settings, progress: ProgressFactory | None, obs: Observations) -> KinematicMotion:
    """The calibrated skeleton, camera, floor and fitted motion (kinematics.stage.fit_motion)."""
    from .kinematics.stage import fit_motion

    return fit_motion(obs, settings, progress)


@dataclass
class RefinedMotion:
    """The B.4 refinement's output: motion (world frame on the refitted floor), contacts (T, 4) bool after
    relabelling, report (seconds, contacts removed and added, floor plane in the camera frame)."""

    motion: KinematicMotion
    contacts: np.ndarray
    report: dict

    def to_arrays(self) -> dict[str, np.ndarray]:
        return dict(self.motion.to_arrays(), refined_contacts=np.asarray(self.contacts, bool),
                    refinement=np.array(json.dumps(self.report)))

    @classmethod
    def from_arrays(cls, arrays: Any) -> RefinedMotion:
        from .kinematics.stage import KinematicMotion

        return cls(KinematicMotion.from_arrays(arrays), arrays["refined_contacts"],
                   json.loads(str(arrays["refinement"])))


def refine(settings: Settings, progress: ProgressFactory | None, obs: Observations, motion: KinematicMotion,
           contacts: np.ndarray) -> RefinedMotion:
    """Rempe et al.'s three-stage kinematic refinement (B.4) of the offline fit, which trajopt and offline
    PhysCap start from; a given floor (settings.camera.floor) is kept."""
    from .kinematics.refine import refine_kinematics

    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings.trajopt,
                                keep_floor=settings.camera.floor is not None, progress=progress)
    report = dict(seconds=refined.seconds, contacts_removed=int(refined.relabelled.sum()),
                  contacts_added=int(refined.added.sum()), floor=refined.motion.floor.plane.tolist())
    return RefinedMotion(refined.motion, refined.contacts, report)


def physcap(settings: Settings, progress: ProgressFactory | None, obs: Observations, motion: KinematicMotion,
            contacts: np.ndarray, stationary: np.ndarray) -> PhysicsMotion:
    """The PhysCap tracker over the kinematic motion, in the kinematic world (see dynamics.stage.run_physcap);
    online with an estimated floor, the floor is refined as frames arrive (offline it already came from every
    frame)."""
    from .dynamics.stage import run_physcap

    refine_floor = settings.online and settings.camera.floor is None
    refined_input = settings.refines_before_physics  # the pipeline then tracks REFINE's motion
    return run_physcap(motion.body, motion.qpos, obs.fps, contacts, stationary, settings.physics,
                       _bar(progress, "physics", obs.num_frames), refine_floor, motion.valid, refined_input,
                       floor_trusted=motion.floor.trusted)


def trajopt(settings: Settings, progress: ProgressFactory | None, obs: Observations, motion: KinematicMotion,
            contacts: np.ndarray) -> TrajoptMotion:
    """Rempe et al.'s trajectory optimisation over the whole clip (trajopt.stage.run_trajopt)."""
    from .trajopt.stage import run_trajopt

    return run_trajopt(motion.body, motion.qpos, obs.fps, contacts, settings.trajopt,
                       _bar(progress, "trajopt", obs.num_frames), obs.valid)


def _detect_settings(settings: Settings) -> dict:
    values = dataclasses.asdict(settings.detect)
    values.pop("accept_truncated")  # only decides whether a short read is an error, after detection
    from .detect.two_graphs import graphs_to_run

    values["graphs"] = graphs_to_run(settings.detect.graphs)  # two graphs splice different numbers than one
    return values


def _write_arrays(path: Path, output: Any) -> None:
    save_npz(path, **output.to_arrays())


def _reader(container: Callable[[], Any]) -> Callable[[Path], Any]:
    """A cache reader for the container class that `container()` imports (stage modules load lazily)."""
    return lambda path: container().from_arrays(read_npz(path, "cache"))


def _kinematic_motion() -> type:
    from .kinematics.stage import KinematicMotion
    return KinematicMotion


def _physics_motion() -> type:
    from .dynamics.stage import PhysicsMotion
    return PhysicsMotion


def _trajopt_motion() -> type:
    from .trajopt.stage import TrajoptMotion
    return TrajoptMotion


DETECT: Stage[Observations] = Stage(
    "detect", "observations", ("physmocap.detect.mediapipe_pose",), _detect_settings, detect,
    lambda path, obs: obs.save(path), Observations.load)
KINEMATICS: Stage[KinematicMotion] = Stage(
    "kinematics", "kinematics", ("physmocap.kinematics.stage",), lambda s: (s.body, s.camera, s.fit, s.online),
    fit, _write_arrays, _reader(_kinematic_motion))
REFINE: Stage[RefinedMotion] = Stage(
    "refine", "refined", ("physmocap.kinematics.refine",), lambda s: (s.fit, s.trajopt, s.camera.floor), refine,
    _write_arrays, _reader(lambda: RefinedMotion))
PHYSCAP: Stage[PhysicsMotion] = Stage(
    "physics", "physics", ("physmocap.dynamics.stage",), lambda s: (s.physics, s.online, s.camera.floor), physcap,
    _write_arrays, _reader(_physics_motion))
TRAJOPT: Stage[TrajoptMotion] = Stage(
    "physics", "trajopt", ("physmocap.trajopt.stage",), lambda s: s.trajopt, trajopt, _write_arrays,
    _reader(_trajopt_motion))

STAGES: tuple[Stage, ...] = (DETECT, KINEMATICS, REFINE, PHYSCAP, TRAJOPT)
