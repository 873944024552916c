"""Property-based tests (hypothesis): generated observations files, settings files and edited result files run
through the command line in-process always end with a documented exit code, no traceback on stderr and nothing
half-written in -o.

CI runs the default profile (100 examples per test, well under a minute); `pytest tests/test_fuzz.py
--hypothesis-profile=long` runs thousands (see BENCHMARKS.md, "Bad inputs (issue 22)")."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings, strategies as st

from physmocap.body.model import build_body_model, template_lengths
from physmocap.io.glb import write_glb
from test_bad_inputs import assert_clean, observation_arrays, run_cli
from test_glb import glb_json, glb_with_json

pytestmark = pytest.mark.slow  # hundreds of generated inputs through the command line

TEMPLATE = observation_arrays(5)

frame_counts = st.integers(0, 5)
frame_rates = st.floats(0.5, 240.0)
image_sizes = st.sampled_from([(1280, 720), (640, 480), (1, 1), (64, 48), (7680, 4320), (720, 1280)])
nan_shares = st.sampled_from([0.0, 0.0, 0.1, 0.5, 0.9, 1.0])
coordinate_scales = st.sampled_from([1.0, 1.0, 1.0, 0.5, 3.0, 1e-3, 20.0])  # of the template's pixels
confidences = st.sampled_from(["template", "uniform", "uniform", "zero", "low"])
# At most one way in which the file is broken (None: a well-formed file, perhaps with odd values)
breakages = st.sampled_from([None] * 8 + [
    "landmarks_32", "flat", "3d_mismatch", "missing_fps", "missing_3d", "scalar_size", "zero_fps", "nan_fps",
    "inf_fps", "negative_size", "camera_K_zeros", "camera_K_nan", "camera_K_negative", "coordinates_1e9",
    "coordinates_negative", "confidence_above_one", "confidence_negative", "valid_wrong_length", "text_fps",
    "empty_fps", "text_keypoints", "nan_size", "text_seconds_per_frame"])


@st.composite
def observations_files(draw):
    """The arrays of an observations file (see README "The observations file"): the walker of test_bad_inputs
    with random frame counts, rates, image sizes, confidences, NaN patterns and scales, and at most one breakage."""
    T = draw(frame_counts)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    k2 = np.resize(TEMPLATE["keypoints_2d"], (T, 33, 3)).copy()
    k3 = np.resize(TEMPLATE["landmarks_3d"], (T, 33, 3)).copy()
    k2[..., :2] = k2[..., :2] * draw(coordinate_scales) + rng.normal(
        scale=draw(st.sampled_from([0.0, 2.0, 50.0])), size=(T, 33, 2))
    k3 = k3 + rng.normal(scale=draw(st.sampled_from([0.0, 0.02, 0.3])), size=k3.shape)
    k2[..., 2] = {"template": k2[..., 2], "uniform": rng.random((T, 33)), "zero": np.zeros((T, 33)),
                  "low": 0.05 * rng.random((T, 33))}[draw(confidences)]
    hidden = rng.random((T, 33)) < draw(nan_shares)
    k2[hidden] = np.nan
    k3[hidden] = np.nan
    size = np.array(draw(image_sizes))
    arrays = dict(keypoints_2d=k2, landmarks_3d=k3, fps=np.float64(draw(frame_rates)), image_size=size)
    if draw(st.booleans()):
        arrays["camera_K"] = np.array([[draw(st.floats(10, 1e5)), 0, size[0] / 2], [0, 0, size[1] / 2], [0, 0, 1]])
        arrays["camera_K"][1, 1] = arrays["camera_K"][0, 0]
    if draw(st.booleans()):
        arrays["valid"] = rng.random(T) < 0.8
    broken = draw(breakages)
    changes = {
        "landmarks_32": lambda: {"keypoints_2d": k2[:, :32]}, "flat": lambda: {"keypoints_2d": k2.reshape(T, 99)},
        "3d_mismatch": lambda: {"landmarks_3d": k3[: max(T - 1, 0)]}, "scalar_size": lambda: {"image_size": 640},
        "zero_fps": lambda: {"fps": 0.0}, "nan_fps": lambda: {"fps": np.nan}, "inf_fps": lambda: {"fps": np.inf},
        "negative_size": lambda: {"image_size": -size}, "camera_K_zeros": lambda: {"camera_K": np.zeros((3, 3))},
        "camera_K_nan": lambda: {"camera_K": np.full((3, 3), np.nan)},
        "camera_K_negative": lambda: {"camera_K": np.diag([-500.0, -500.0, 1.0])},
        "coordinates_1e9": lambda: {"keypoints_2d": np.concatenate([k2[..., :2] * 1e9, k2[..., 2:]], axis=-1)},
        "coordinates_negative": lambda: {"keypoints_2d": np.concatenate([-k2[..., :2], k2[..., 2:]], axis=-1)},
        "confidence_above_one": lambda: {"keypoints_2d": np.concatenate([k2[..., :2], 1 + k2[..., 2:]], axis=-1)},
        "confidence_negative": lambda: {"keypoints_2d": np.concatenate([k2[..., :2], -k2[..., 2:]], axis=-1)},
        "valid_wrong_length": lambda: {"valid": np.ones(T + 1, bool)},
        # written by other code: text where numbers belong
        "text_fps": lambda: {"fps": "abc"}, "empty_fps": lambda: {"fps": np.zeros(0)},
        "text_keypoints": lambda: {"keypoints_2d": k2.astype(str)}, "nan_size": lambda: {"image_size": [np.nan, 480]},
        "text_seconds_per_frame": lambda: {"seconds_per_frame": "fast"},
    }
    if broken in ("missing_fps", "missing_3d"):
        del arrays["fps" if broken == "missing_fps" else "landmarks_3d"]
    elif broken is not None:
        arrays.update(changes[broken]())
    return arrays


JUNK = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12), st.booleans(),
                 st.text(max_size=8), st.lists(st.floats(-1e3, 1e3), max_size=5),
                 st.lists(st.text(max_size=4), max_size=3))  # a TOML value of any type and range


@st.composite
def settings_files(draw):
    """A TOML settings file: known and unknown sections and keys, each value either near the setting's default
    (scaled, toggled, a subset) or of any TOML type and range; now and then broken TOML."""
    import dataclasses

    from physmocap.config import Settings

    defaults = {f.name: {g.name: getattr(getattr(Settings(), f.name), g.name)
                         for g in dataclasses.fields(getattr(Settings(), f.name))}
                for f in dataclasses.fields(Settings) if dataclasses.is_dataclass(getattr(Settings(), f.name))}
    junk = JUNK
    lines = []
    for _ in range(draw(st.integers(1, 3))):
        section = draw(st.sampled_from(sorted(defaults) + ["nonsense"]))
        lines.append(f"[{section}]")
        known = defaults.get(section, {})
        keys = draw(st.lists(st.sampled_from(sorted(known) + ["unknown_key"]), min_size=1, max_size=3, unique=True))
        for key in keys:
            near = key in known and draw(st.integers(0, 9)) < 7
            value = _near(draw, known[key]) if near else draw(junk)
            if value is not None:
                lines.append(f"{key} = {_toml_value(value)}")
    if draw(st.integers(0, 9)) == 0:
        lines.insert(0, f"online = {_toml_value(draw(st.one_of(st.booleans(), junk)))}")
    if draw(st.integers(0, 19)) == 0:
        lines.append("this is [not toml")
    return "\n".join(lines) + "\n"


def _near(draw, default):
    """A value like `default`: a float or int scaled by 0.25-4, a bool either way, a tuple's subset or itself."""
    if isinstance(default, bool):
        return draw(st.booleans())
    if isinstance(default, (int, float)):
        value = default * draw(st.sampled_from([0.25, 0.5, 1.0, 2.0, 4.0])) if default else draw(st.floats(0, 1))
        return int(value) if isinstance(default, int) else float(value)
    if isinstance(default, tuple):
        return list(draw(st.lists(st.sampled_from(default), unique=True))) if default else []
    return default if isinstance(default, str) else None


def _toml_value(value) -> str:
    import math

    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"').encode("unicode_escape").decode("ascii") + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return str(value)


FAST = ["--physics", "none", "--no-overlay"]


def _ends_in_a_documented_exit(name: str, write, argv, context: tuple = ()) -> None:
    """Write a generated file `name` into a fresh folder (`write(path)`), run the command line `argv(path, out)`
    in-process and check its end: a documented exit code, no traceback, nothing half-written in `out`, and not 1
    (a bug: its crash log and `context` go into the failure message)."""
    with tempfile.TemporaryDirectory() as tmp:
        path, out = Path(tmp) / name, Path(tmp) / "out"
        write(path)
        code, _, err = run_cli(*argv(path, out))
        event(f"exit {code}")  # --hypothesis-show-statistics: the share of each exit code
        if code == 1:
            event(f"crash at {_crash_site(out) or _crash_site(Path(tmp))}")
        assert_clean(code, err, out)
        assert code != 1, (*context, err, _crash_log(out), _crash_log(Path(tmp)))


def _crash_log(out: Path) -> str:
    """The traceback of the crash log a bug left in `out`, for the failure message."""
    return "\n".join(log.read_text()[-3000:] for log in out.glob("physmocap-crash-*.log"))


def _crash_site(out: Path) -> str:
    """The innermost physmocap frame of a crash log in `out` (for the statistics), or ''."""
    sites = [line.strip() for line in _crash_log(out).splitlines() if "physmocap/" in line and "File" in line]
    return sites[-1].split("physmocap/")[-1] if sites else ""


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(observations_files(), st.sampled_from([FAST, FAST, FAST + ["--online"], ["--physics", "physcap",
                                                                                 "--no-overlay", "--online"]]))
def test_any_observations_file_ends_in_a_documented_exit(arrays, options):
    _ends_in_a_documented_exit("obs.npz", lambda path: np.savez(path, **arrays),
                               lambda path, out: ["capture", "--observations", path, "-o", out, *options])


@pytest.fixture(scope="module")
def good_observations(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz") / "obs.npz"
    np.savez(path, **observation_arrays(3))
    return path


@settings(suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(settings_files())
def test_any_settings_file_ends_in_a_documented_exit(good_observations, text):
    _ends_in_a_documented_exit("settings.toml", lambda path: path.write_text(text), lambda path, out: [
        "capture", "--observations", good_observations, "-o", out, "--config", path, *FAST])


@pytest.fixture(scope="module")
def good_result(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz_result")
    np.savez(folder / "obs.npz", **observation_arrays(6))
    code, _, err = run_cli("capture", "--observations", folder / "obs.npz", "-o", folder / "run", *FAST)
    assert code == 0, err
    return folder / "run" / "result.npz"


RIG = Path(__file__).parent / "data" / "rig_cc3_iclone.bvh"
MUTATIONS = {  # how another program might have changed one array of a result file
    "text": lambda a: a.astype(str), "nan": lambda a: np.full(a.shape, np.nan),
    "inf": lambda a: np.full(a.shape, np.inf),
    "one_frame_less": lambda a: a[:-1], "scalar": lambda a: np.array(1.0), "empty": lambda a: np.zeros(0),
    "negative": lambda a: -np.abs(a.astype(float)) - 1, "flattened": lambda a: a.reshape(-1),
    "extra_axis": lambda a: a[..., None], "zeros": lambda a: np.zeros(a.shape), "huge": lambda a: a * 1e12 + 1e12,
}


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.data())
def test_any_edited_result_file_ends_in_a_documented_exit(good_result, data):
    arrays = dict(np.load(good_result, allow_pickle=False))
    key = data.draw(st.sampled_from(sorted(arrays)))
    mutation = data.draw(st.sampled_from(sorted(MUTATIONS) + ["deleted"]))
    command = data.draw(st.sampled_from([["export", "--to", "bvh"], ["export", "--to", "glb"],
                                         ["export", "--to", "opensim"], ["evaluate"],
                                         ["retarget", "--character", RIG]]))
    if mutation == "deleted":
        del arrays[key]
    else:
        try:
            arrays[key] = MUTATIONS[mutation](arrays[key])
        except (TypeError, ValueError, IndexError):  # e.g. a text array made negative: nothing to try
            return
    _ends_in_a_documented_exit(
        "result.npz", lambda path: np.savez(path, **arrays),
        lambda path, out: [command[0], path, *command[1:], *(["-o", out] if command[0] != "evaluate" else [])],
        (key, mutation))


NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e-?\d+)?")
ODD_NUMBERS = ["nan", "inf", "-inf", "1e308", "-1e308", "0", "1e-300", "1e30", "x", ""]


def _leaves(value, path=()):
    """(path, value) of every number in a JSON document."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _leaves(item, path + (key,))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            yield from _leaves(item, path + (i,))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, value


@pytest.fixture(scope="module")
def good_glb(tmp_path_factory):
    body = build_body_model(template_lengths(1.7), 70.0)
    path = tmp_path_factory.mktemp("fuzz_glb") / "character.glb"
    write_glb(path, body, body.rest_qpos[None], 30.0)
    return path


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.data())
def test_any_edited_character_ends_in_a_documented_exit(good_result, good_glb, data):
    """A BVH rig with one number changed (NaN, infinity, an overflowing or absurd value, text), a channel count
    changed, a joint renamed to another's name or the file cut short; or a GLB whose JSON has one number changed,
    one key deleted or a node made its own ancestor: `retarget` runs or refuses in one sentence."""
    if data.draw(st.booleans()):
        name, text = "character.bvh", RIG.read_text()
        kind = data.draw(st.sampled_from(["number", "number", "channels", "same_name", "cut"]))
        if kind == "number":
            match = data.draw(st.sampled_from(list(NUMBER.finditer(text[:text.index("MOTION") + 400]))))
            text = text[:match.start()] + data.draw(st.sampled_from(ODD_NUMBERS)) + text[match.end():]
        elif kind == "channels":
            counts = list(re.finditer(r"CHANNELS (\d+)", text))
            match = data.draw(st.sampled_from(counts))
            text = text[:match.start(1)] + data.draw(st.sampled_from(["0", "1", "7", "-3"])) + text[match.end(1):]
        elif kind == "same_name":
            names = re.findall(r"JOINT (\S+)\n", text)
            a, b = data.draw(st.permutations(names))[:2]
            text = text.replace(f"JOINT {a}\n", f"JOINT {b}\n", 1)
        else:
            text = text[:data.draw(st.integers(0, len(text) - 1))]
        content = text.encode()
    else:
        name = "character.glb"
        document, rest = glb_json(good_glb.read_bytes())
        kind = data.draw(st.sampled_from(["number", "number", "number", "delete", "cycle"]))
        if kind == "number":
            path, _ = data.draw(st.sampled_from(list(_leaves(document))))
        elif kind == "delete":
            path = data.draw(st.sampled_from([p[:cut] for p, _ in _leaves(document) for cut in (1, 2, 3)
                                              if len(p) >= cut]))
        *parents, last = path if kind != "cycle" else (None,)
        if kind != "cycle":
            holder = document
            for key in parents:
                holder = holder[key]
        if kind == "number":
            holder[last] = data.draw(st.sampled_from([float("nan"), float("inf"), -1, 0, 1e308, 10**9, 2.5]))
        elif kind == "delete":
            del holder[last]
        else:
            child = data.draw(st.sampled_from([n for node in document["nodes"] for n in node.get("children", [])]))
            document["nodes"][child].setdefault("children", []).append(
                next(i for i, node in enumerate(document["nodes"]) if child in node.get("children", [])))
        content = glb_with_json(document, rest)
    event(f"{name} {kind}")
    _ends_in_a_documented_exit(name, lambda path: path.write_bytes(content), lambda path, out: [
        "retarget", good_result, "--character", path, "-o", out, "--physics", "none"], (kind,))


@st.composite
def character_maps(draw):
    """A TOML character map (README "Your own character"): units, bones, total mass and mass fractions, each key
    known or not, each value plausible (a bone of the rig, a share, a mass) or of any TOML type and range; now and
    then a plain value where a table belongs."""
    from physmocap.retarget.mapping import MAPPABLE, MASS_GROUPS

    bone_names = re.findall(r"JOINT (\S+)\n", RIG.read_text())
    lines = []
    if draw(st.booleans()):
        units = draw(st.one_of(st.sampled_from([0.01, 0.01, 0.001, 1.0, 1e-300, 1e300]), JUNK))
        lines.append(f"units_to_metres = {_toml_value(units)}")
    if draw(st.integers(0, 9)) == 0:
        lines.append(f"{draw(st.sampled_from(['bones', 'mass']))} = {_toml_value(draw(JUNK))}")
    for section, keys, plausible in (
            ("bones", MAPPABLE, st.sampled_from(bone_names)),
            ("mass", ("total",), st.floats(0.5, 3000.0)),
            ("mass.fractions", MASS_GROUPS, st.floats(0.0, 1.0))):
        if draw(st.booleans()):
            lines.append(f"[{section}]")
            for key in draw(st.lists(st.sampled_from(keys + ("unknown_key",)), min_size=1, max_size=4, unique=True)):
                value = draw(plausible) if draw(st.integers(0, 9)) < 7 else draw(JUNK)
                lines.append(f"{key} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(character_maps())
def test_any_character_map_ends_in_a_documented_exit(good_result, text):
    _ends_in_a_documented_exit("map.toml", lambda path: path.write_text(text), lambda path, out: [
        "retarget", good_result, "--character", RIG, "--character-map", path, "-o", out, "--physics", "none"], (text,))
