"""Settings declared once (config.py): check(), the command line's help and docs/settings.md all follow the
declarations."""

from __future__ import annotations

import dataclasses
import importlib.util
import typing
from pathlib import Path

import pytest

from physmocap.cli import build_parser
from physmocap.config import Settings, load_settings
from physmocap.errors import InputError, SettingsError
from physmocap.settings_fields import Section, describe, from_table

ROOT = Path(__file__).resolve().parents[1]


def _declarations():
    """(owner class, field, key) of every declared setting, top level included."""
    for f in dataclasses.fields(Settings):
        if isinstance(getattr(Settings(), f.name), Section):
            for g in dataclasses.fields(f.default_factory):  # type: ignore[arg-type]
                yield f.default_factory, g, f"{f.name}.{g.name}"
        else:
            yield Settings, f, f.name


DECLARATIONS = list(_declarations())
RANGED = [(owner, f, key) for owner, f, key in DECLARATIONS if f.metadata["limits"]]


def _with(key: str, value) -> Settings:
    section, _, name = key.rpartition(".")
    return Settings().replace(section or None, **{name: value})


def test_every_setting_is_declared_with_a_meaning_and_its_numbers_with_a_range():
    for owner, f, key in DECLARATIONS:
        assert f.metadata and f.metadata["help"], f"{key} is not declared with setting()"
        hint = typing.get_type_hints(owner)[f.name]
        numeric = hint in (int, float) or set(typing.get_args(hint)) in ({int, type(None)}, {float, type(None)})
        assert not numeric or f.metadata["limits"], f"{key} is a number without a range"
    Settings().check()  # every default lies within its own range


@pytest.mark.parametrize("owner, f, key", RANGED, ids=[key for _, _, key in RANGED])
def test_check_names_the_key_and_range_just_outside_it(owner, f, key):
    low, high = f.metadata["limits"]
    below = low - (1 if isinstance(low, int) else max(abs(low), 1e-3) * 0.5)
    above = high + (1 if isinstance(high, int) else abs(high) * 0.5 + 1e-3)
    for value in (below, above):
        with pytest.raises(SettingsError, match=rf"^{key} = .* is out of range: expected .*\."):
            _with(key, value).check()
    if key not in ("trajopt.window_seconds", "trajopt.window_overlap"):  # bound together: overlap <= seconds / 2
        _with(key, low).check()
        _with(key, high).check()


def test_none_only_where_the_type_allows_it():
    with pytest.raises(SettingsError, match="body.height"):
        _with("body.height", None).check()
    _with("physics.target_lift_time", None).check()
    _with("physics.release_distance", None).check()


def test_one_value_outside_a_range_and_choices():
    _with("overlay_width", 0).check()  # 0: the video's own width
    with pytest.raises(SettingsError, match="overlay_width = 100 is out of range: expected 160 .. 7680 px, or 0"):
        _with("overlay_width", 100).check()
    with pytest.raises(SettingsError, match="physics.foot_lock = 'sometimes' is not allowed: expected one of auto"):
        _with("physics.foot_lock", "sometimes").check()
    with pytest.raises(SettingsError, match="trajopt.costs .* expected some of data"):
        _with("trajopt.costs", ("data", "beauty")).check()
    with pytest.raises(SettingsError, match="window_overlap"):
        Settings().replace("trajopt", window_seconds=1.0, window_overlap=0.6).check()


def test_a_settings_file_out_of_range_is_named_with_the_key(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text("[physics]\nkp_joint = 20000\n")
    with pytest.raises(SettingsError, match=rf"^{path}: physics.kp_joint = 20000 is out of range: expected 0 .. "
                                            r"10000 1/s\^2\.$"):
        load_settings(path)
    path.write_text("online = true\noverlay_width = 640\n[fit]\nweight_depth = 0.5\n")
    settings = load_settings(path)
    assert (settings.online, settings.overlay_width, settings.fit.weight_depth) == (True, 640, 0.5)


def test_whole_numbers_in_a_settings_file_are_read_as_the_floats_declared(tmp_path):
    from physmocap.body.model import build_body_model, template_lengths
    from physmocap.dynamics.physcap import PhysCapTracker

    path = tmp_path / "settings.toml"
    path.write_text("[physics]\nkp_joint = 3000\nkd_joint = 110\niterations = 4\n[camera]\nfloor = [0, -1, 0, 2]\n")
    settings = load_settings(path)
    assert type(settings.physics.kp_joint) is float and type(settings.physics.iterations) is int
    assert all(type(x) is float for x in settings.camera.floor)
    PhysCapTracker(build_body_model(template_lengths()), settings.physics, 30.0)  # integer gains had raised


def test_an_unknown_setting_names_the_nearest_known_one(tmp_path):
    path = tmp_path / "settings.toml"
    path.write_text("[physics]\ncorrection_rate = 0.1\n")  # renamed to correction_time (seconds)
    with pytest.raises(InputError, match=r"unknown setting physics.correction_rate \(did you mean "
                                         r"physics.correction_time\?\)\.$"):
        load_settings(path)
    path.write_text("overlay_widht = 640\n")
    with pytest.raises(InputError, match=r"unknown setting 'overlay_widht' \(did you mean overlay_width\?\)"):
        load_settings(path)
    path.write_text("[physics]\nzzz = 1\n")
    with pytest.raises(InputError, match=r"unknown setting physics.zzz\.$"):
        load_settings(path)


def test_a_table_is_read_and_checked_as_a_settings_file_naming_its_source():
    settings = from_table(Settings, {"physics": {"kp_joint": 3000, "balance_correction": False}}, "--physics")
    assert type(settings.physics.kp_joint) is float and settings.physics.balance_correction is False
    with pytest.raises(SettingsError, match=r"^--physics: setting physics.balance_correction must be true or false, "
                                            r"got 'false'\.$"):
        from_table(Settings, {"physics": {"balance_correction": "false"}}, "--physics")
    with pytest.raises(SettingsError, match=r"^--physics: physics.slide_speed = 5 is out of range"):
        from_table(Settings, {"physics": {"slide_speed": 5}}, "--physics")
    with pytest.raises(InputError, match=r"^--physics: unknown setting physics.balance_corection \(did you mean "):
        from_table(Settings, {"physics": {"balance_corection": True}}, "--physics")


def test_help_of_capture_options_comes_from_the_declarations():
    capture = next(a for a in build_parser()._subparsers._group_actions[0].choices.values()  # type: ignore[union-attr]
                   if a.prog.endswith("capture"))
    options = {option: action for action in capture._actions for option in action.option_strings}
    assert options["--height"].help == describe(Settings, "body.height")
    assert "1 .. 2.3 m" in options["--height"].help and "default 1.7" in options["--height"].help
    assert tuple(options["--foot-lock"].choices) == ("auto", "always", "never")
    assert "160 .. 7680 px, or 0" in options["--overlay-size"].help


def test_docs_settings_md_is_generated_from_the_declarations():
    spec = importlib.util.spec_from_file_location("settings_reference", ROOT / "scripts" / "settings_reference.py")
    script = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(script)  # type: ignore[union-attr]
    committed = (ROOT / "docs" / "settings.md").read_text()
    assert committed == script.reference(), ("docs/settings.md is out of date: run PYTHONPATH=src python "
                                             "scripts/settings_reference.py > docs/settings.md")
    for _, f, _ in DECLARATIONS:
        assert f"| `{f.name}` |" in committed
