"""How a setting is declared (`setting()`), checked against its declaration and read from a TOML file; the
declarations themselves are in `physmocap.config`."""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import tomllib
import types
import typing
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Self

from .errors import InputError, SettingsError


def setting(default, unit: str = "", limits: tuple[float, float] | None = None, help: str = "",
            choices: tuple[str, ...] | None = None, also=None, check: Callable[[str, Any], None] | None = None):
    """A settings field: `limits` (low, high) bound a number (None passes where the type allows it; `also` is one
    more allowed value outside them), `choices` the allowed words (a tuple value: some of them), `check(key,
    value)` raises SettingsError for any other wrong value."""
    return dataclasses.field(default=default, metadata={"unit": unit, "limits": limits, "help": help,
                                                        "choices": choices, "also": also, "check": check})


class Section:
    """A frozen settings dataclass; check() tests every field against its declaration and each sub-settings."""

    def key(self, name: str) -> str:
        """The field's name as settings files and messages write it: "fit.weight_2d", top level "online"."""
        section = type(self).__name__.removesuffix("Settings").lower()
        return f"{section}.{name}" if section else name

    def check(self):
        owner: type = type(self)  # as `type`: mypy takes a dataclass class object for unhashable
        hints = _hints(owner)
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if isinstance(value, Section):
                value.check()
            elif f.metadata and not (value is None and _allows_none(hints[f.name])):
                _check_value(self.key(f.name), value, f.metadata)
        return self

    def replace(self, section: str | None = None, **values) -> Self:
        """A copy with fields changed; `section` names the sub-settings, None the top level."""
        if section is None:
            return dataclasses.replace(self, **values)  # type: ignore[type-var]
        inner = dataclasses.replace(getattr(self, section), **values)
        return dataclasses.replace(self, **{section: inner})  # type: ignore[type-var]

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)  # type: ignore[call-overload]


def declaration(root: type, key: str) -> dataclasses.Field:
    """The field of the setting `key` ("section.field", or a top-level field's name) in the dataclass `root`."""
    fields = {f.name: f for f in dataclasses.fields(root)}
    section, _, name = key.rpartition(".")
    if section:
        fields = {f.name: f for f in dataclasses.fields(fields[section].default_factory)}  # type: ignore[arg-type]
    return fields[name]


def allowed(metadata) -> str:
    """A declaration's allowed values in words: "1 .. 2.3 m", "auto, always, never", or just its unit."""
    if metadata["choices"]:
        return ", ".join(metadata["choices"])
    if not metadata["limits"]:
        return metadata["unit"]
    low, high = metadata["limits"]
    also = "" if metadata["also"] is None else f", or {metadata['also']}"
    return f"{number(low)} .. {number(high)} {metadata['unit']}".rstrip() + also


def describe(root: type, key: str) -> str:
    """A setting's meaning, allowed values and default in one line, for the command line's help."""
    declared = declaration(root, key)
    values = "" if declared.metadata["choices"] else allowed(declared.metadata)  # argparse lists the choices
    default = declared.default
    unset = default is None or default is False  # the help says what None means
    shown = number(default) if isinstance(default, float) else default
    notes = [note for note in (values, "" if unset else f"default {shown}") if note]
    return declared.metadata["help"] + (f" ({'; '.join(notes)})" if notes else "")


def number(x) -> str:
    """A bound as people write it: 0.1, 1000, 1e6, 1e-10."""
    return f"{x:g}".replace("e+0", "e").replace("e-0", "e-").replace("e+", "e")


@functools.cache
def _hints(owner: type) -> dict:
    """The fields' types, evaluated once per class (typing.get_type_hints takes milliseconds)."""
    return typing.get_type_hints(owner)


def _allows_none(hint) -> bool:
    return isinstance(hint, types.UnionType) and type(None) in typing.get_args(hint)


def _check_value(key: str, value, metadata) -> None:
    """SettingsError naming the key and what it allows, unless `value` is among the declared choices or within the
    declared limits."""
    if metadata["choices"] is not None:
        picked = value if isinstance(value, tuple) else (value,)
        if not all(isinstance(v, str) and v in metadata["choices"] for v in picked):
            raise SettingsError(f"{key} = {value!r} is not allowed: expected "
                                f"{'some' if isinstance(value, tuple) else 'one'} of {allowed(metadata)}.")
    elif metadata["limits"] is not None and not (metadata["also"] is not None and value == metadata["also"]):
        low, high = metadata["limits"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
            raise SettingsError(f"{key} = {value} is out of range: expected {allowed(metadata)}.")
    if metadata["check"] is not None:
        metadata["check"](key, value)


def is_number(value) -> bool:
    """An int or float read from TOML; not a boolean (which Python counts as an int)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def floor_plane(key: str, floor) -> None:
    """Four finite numbers nx,ny,nz,d with a non-zero normal not along the camera's x axis (the world's x axis is
    the camera's projected onto the floor; such a plane is a wall beside the camera)."""
    numbers = isinstance(floor, (tuple, list)) and all(is_number(x) for x in floor)
    if not numbers or len(floor) != 4 or not all(math.isfinite(x) for x in floor):
        raise SettingsError(f"{key} must be four finite numbers nx,ny,nz,d, got {floor}.")
    norm = math.sqrt(sum(x * x for x in floor[:3]))
    if norm < 1e-9:
        raise SettingsError(f"{key} must have a non-zero normal nx,ny,nz, got {floor}.")
    if abs(floor[0]) / norm > math.cos(math.radians(1.0)):
        raise SettingsError(f"{key} {floor} is a vertical plane beside the camera (its normal lies along the "
                            "camera's x axis), not a floor.")


def image_box(key: str, box) -> None:
    """Four numbers x0,y0,x1,y1 with x1 > x0 and y1 > y0."""
    if len(box) != 4 or not (box[2] > box[0] and box[3] > box[1]):
        raise SettingsError(f"{key} must be four numbers x0,y0,x1,y1 with x1 > x0 and y1 > y0, got {box}.")


def _has_type(value, hint) -> bool:
    """Whether a value read from a settings file has the field's type (int where float is asked is fine)."""
    arms = typing.get_args(hint) if isinstance(hint, types.UnionType) else None
    if arms:
        return any(_has_type(value, arm) for arm in arms)
    if hint is float:
        return is_number(value)
    if hint is int or hint is str or hint is bool:
        return isinstance(value, hint) and (hint is bool or not isinstance(value, bool))
    if typing.get_origin(hint) is tuple:
        items = typing.get_args(hint)
        if not isinstance(value, tuple):
            return False
        if len(items) == 2 and items[1] is Ellipsis:
            return all(_has_type(v, items[0]) for v in value)
        return len(value) == len(items) and all(_has_type(v, t) for v, t in zip(value, items, strict=True))
    return hint is type(None) and value is None


def _type_name(hint) -> str:
    arms = [a for a in typing.get_args(hint) if a is not type(None)] if isinstance(hint, types.UnionType) else [hint]
    names = {float: "a number", int: "a whole number", bool: "true or false", str: "text"}
    if typing.get_origin(arms[0]) is tuple:
        items = typing.get_args(arms[0])
        return ("a list of " + names.get(items[0], "values") if items[-1] is Ellipsis
                else f"a list of {len(items)} " + names.get(items[0], "values").replace("a ", "") + "s")
    return names.get(arms[0], str(arms[0]))


def read_toml(path: Path, what: str) -> dict:
    """A user's TOML file (`what`: "settings", "character map") as a dict; InputError naming the file if it is
    missing or not TOML."""
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such {what} file.") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a valid TOML {what} file ({exc}).") from None


def nearest(name: str, known: Iterable[str], prefix: str = "") -> str:
    """" (did you mean PREFIX+X?)" for the known name closest to a misspelt or renamed `name`, else ""."""
    match = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean {prefix}{match[0]}?)" if match else ""


def _as_declared(value, hint):
    """A value of the field's type (_has_type) as the field holds it: a whole number where a number is asked as a
    float (`kp_joint = 3000`), which numpy would otherwise keep as an integer array."""
    arms = typing.get_args(hint) if isinstance(hint, types.UnionType) else (hint,)
    if isinstance(value, tuple) and typing.get_origin(arms[0]) is tuple:
        items = typing.get_args(arms[0])
        items = (items[0],) * len(value) if len(items) == 2 and items[1] is Ellipsis else items
        return tuple(_as_declared(v, t) for v, t in zip(value, items, strict=True))
    if float in arms and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def _typed(source: str, owner: type, values: dict) -> dict:
    """`values` for fields of the dataclass `owner` (lists as tuples); SettingsError naming the source (a file) and
    the first value of the wrong type."""
    hints = _hints(owner)
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
    for name, item in values.items():
        if not _has_type(item, hints[name]):
            raise SettingsError(f"{source}: setting {owner().key(name)} must be {_type_name(hints[name])}, "
                                f"got {item!r}.")
    return values


def _as_declared_section(section):
    """The checked settings with every value as its field declares it (_as_declared), sub-settings too."""
    owner: type = type(section)  # as `type`: mypy takes a dataclass class object for unhashable
    hints = _hints(owner)
    values = {}
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        values[f.name] = (_as_declared_section(value) if isinstance(value, Section)
                          else _as_declared(value, hints[f.name]))
    return dataclasses.replace(section, **values)


def load_toml(root: type, path: Path):
    """root()'s defaults overridden by the TOML file `path` ([section] tables and top-level keys), checked;
    InputError naming the file and the first unknown section or setting, or wrong value."""
    return from_table(root, read_toml(path, "settings"), str(path))


def from_table(root: type, data: dict, source: str):
    """root()'s defaults overridden by `data` as a settings file's TOML reads ([section] tables and top-level keys),
    checked; InputError or SettingsError naming `source` (the file, or whatever gave the values) and the first
    unknown section or setting, or wrong value."""
    settings = root()
    sections = {f.name for f in dataclasses.fields(root) if isinstance(getattr(settings, f.name), Section)}
    top_level = {f.name for f in dataclasses.fields(root)} - sections
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in sections:
                raise InputError(f"{source}: unknown settings section [{key}].")
            names = [f.name for f in dataclasses.fields(getattr(settings, key))]
            unknown = set(value) - set(names)
            if unknown:
                name = sorted(unknown)[0]
                raise InputError(f"{source}: unknown setting {key}.{name}{nearest(name, names, key + '.')}.")
            settings = settings.replace(key, **_typed(source, type(getattr(settings, key)), value))
        elif key not in top_level:
            raise InputError(f"{source}: unknown setting '{key}'{nearest(key, sorted(top_level | sections))}.")
    top_values = {k: v for k, v in data.items() if not isinstance(v, dict)}
    settings = settings.replace(None, **_typed(source, root, top_values))
    try:
        settings.check()  # on the values as written, which its messages quote
    except SettingsError as exc:
        raise SettingsError(f"{source}: {exc}") from None
    return _as_declared_section(settings)
