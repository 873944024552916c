"""Property-based tests (hypothesis): generated observations files and settings files run through the command line
in-process always end with a documented exit code, no traceback on stderr and nothing half-written in -o.

CI runs the default profile (a few hundred examples, well under two minutes); `pytest tests/test_fuzz.py
--hypothesis-profile=long` runs thousands (see BENCHMARKS.md, "Bad inputs (issue 22)")."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings, strategies as st

from test_bad_inputs import assert_clean, observation_arrays, run_cli

TEMPLATE = observation_arrays(5)

frame_counts = st.integers(0, 5)
frame_rates = st.one_of(st.floats(0.5, 240.0), st.sampled_from([0.0, -30.0, np.nan, np.inf, 1e-9]))
image_sizes = st.one_of(st.sampled_from([(1280, 720), (640, 480), (1, 1), (64, 48), (7680, 4320)]),
                        st.tuples(st.integers(-10, 10000), st.integers(-10, 10000)))
nan_shares = st.sampled_from([0.0, 0.0, 0.1, 0.5, 0.9, 1.0])
coordinate_scales = st.sampled_from([1.0, 1.0, 1e-6, 1e3, 1e9, -1.0])
confidences = st.sampled_from(["template", "uniform", "zero", "above_one", "negative"])
shapes = st.sampled_from(["ok", "ok", "ok", "ok", "landmarks_32", "flat", "3d_mismatch", "missing_fps",
                          "missing_3d", "scalar_size"])
camera_matrices = st.sampled_from([None, None, "good", "zeros", "nan", "negative_focal"])


@st.composite
def observations_files(draw):
    """The arrays of an observations file (see README "The observations file"), good or subtly bad."""
    T = draw(frame_counts)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    k2 = np.resize(TEMPLATE["keypoints_2d"], (T, 33, 3)).copy()
    k3 = np.resize(TEMPLATE["landmarks_3d"], (T, 33, 3)).copy()
    scale = draw(coordinate_scales)
    k2[..., :2] = k2[..., :2] * scale + rng.normal(scale=draw(st.sampled_from([0.0, 2.0, 50.0])), size=(T, 33, 2))
    k3 = k3 * (scale if abs(scale) < 10 else 1.0) + rng.normal(scale=0.02, size=k3.shape)
    conf = draw(confidences)
    if conf != "template":
        k2[..., 2] = {"uniform": rng.random((T, 33)), "zero": np.zeros((T, 33)), "above_one": 1 + rng.random((T, 33)),
                      "negative": -rng.random((T, 33))}[conf]
    hidden = rng.random((T, 33)) < draw(nan_shares)
    k2[hidden] = np.nan
    k3[hidden] = np.nan
    arrays = dict(keypoints_2d=k2, landmarks_3d=k3, fps=np.float64(draw(frame_rates)),
                  image_size=np.array(draw(image_sizes)))
    K = draw(camera_matrices)
    if K is not None:
        w, h = (max(abs(int(x)), 1) for x in arrays["image_size"][:2])
        arrays["camera_K"] = {"good": np.array([[1000.0, 0, w / 2], [0, 1000.0, h / 2], [0, 0, 1]]),
                              "zeros": np.zeros((3, 3)), "nan": np.full((3, 3), np.nan),
                              "negative_focal": np.diag([-500.0, -500.0, 1.0])}[K]
    if draw(st.booleans()):
        arrays["valid"] = rng.random(T) < 0.8
    shape = draw(shapes)
    if shape == "landmarks_32":
        arrays["keypoints_2d"] = k2[:, :32]
    elif shape == "flat":
        arrays["keypoints_2d"] = k2.reshape(T, 99)
    elif shape == "3d_mismatch":
        arrays["landmarks_3d"] = k3[: max(T - 1, 0)]
    elif shape == "missing_fps":
        del arrays["fps"]
    elif shape == "missing_3d":
        del arrays["landmarks_3d"]
    elif shape == "scalar_size":
        arrays["image_size"] = np.int64(640)
    return arrays


@st.composite
def settings_files(draw):
    """A TOML settings file: known and unknown sections and keys, values of every TOML type and range."""
    from physmocap.config import Settings
    import dataclasses

    sections = {f.name: [g.name for g in dataclasses.fields(getattr(Settings(), f.name))]
                for f in dataclasses.fields(Settings) if f.name != "online"}
    values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12), st.booleans(),
                       st.text(max_size=8), st.lists(st.floats(-1e3, 1e3), max_size=5),
                       st.lists(st.text(max_size=4), max_size=3))
    lines = []
    for _ in range(draw(st.integers(1, 4))):
        section = draw(st.one_of(st.sampled_from(sorted(sections)), st.just("nonsense")))
        lines.append(f"[{section}]")
        keys = sections.get(section, ["key"]) + ["unknown_key"]
        for key in draw(st.lists(st.sampled_from(keys), min_size=1, max_size=3, unique=True)):
            lines.append(f"{key} = {_toml_value(draw(values))}")
    if draw(st.booleans()):
        lines.insert(0, f"online = {_toml_value(draw(values))}")
    if draw(st.integers(0, 9)) == 0:
        lines.append("this is [not toml")
    return "\n".join(lines) + "\n"


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
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "obs.npz"
        np.savez(path, **arrays)
        out = Path(tmp) / "out"
        code, _, err = run_cli("capture", "--observations", path, "-o", out, *options)
        event(f"exit {code}")  # --hypothesis-show-statistics: the share of each exit code
        if code == 1:
            event(f"crash at {_crash_site(out)}")
        assert_clean(code, err, out)
        # Exit 1 (a bug, a crash-log sentence) is still documented; the fit's first pose on frames without a
        # torso is one until the NaN-robust calibration lands (BENCHMARKS.md, "Bad inputs (issue 22)").


@pytest.fixture(scope="module")
def good_observations(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz") / "obs.npz"
    np.savez(path, **observation_arrays(3))
    return path


@settings(suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.function_scoped_fixture])
@given(settings_files())
def test_any_settings_file_ends_in_a_documented_exit(good_observations, text):
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "settings.toml"
        config.write_text(text)
        out = Path(tmp) / "out"
        code, _, err = run_cli("capture", "--observations", good_observations, "-o", out, "--config", config, *FAST)
        event(f"exit {code}")
        assert_clean(code, err, out)
        assert code != 1, _crash_log(out)
