"""docs/settings.md, the reference of every setting, from its declaration in src/physmocap/config.py:

    PYTHONPATH=src .venv/bin/python scripts/settings_reference.py > docs/settings.md

tests/test_config.py fails while the committed page differs from what this prints.
"""

from __future__ import annotations

import dataclasses
import inspect

from physmocap.config import Settings
from physmocap.settings_fields import allowed, number

INTRO = """\
# Settings

Every setting of a capture, generated from its declaration in `src/physmocap/config.py` by
`scripts/settings_reference.py` (do not edit by hand). A TOML file given with `--config` overrides any of them,
section by section, with the names below:

```toml
online = true

[fit]
weight_depth = 0.5
```

A value outside its range, of the wrong type, or an unknown name stops the run with one sentence naming the file
and the setting. A default of `none` cannot be written in TOML: leave the key out to keep it. Ranges include both
ends; weights without a unit are relative to each other. Why a value is what it is: the pages in
`docs/decisions/`.
"""


def toml_value(value) -> str:
    """A default as it would be written in the TOML file."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return number(value) if isinstance(value, float) else str(value)


def table(owner) -> list[str]:
    rows = ["| setting | default | allowed | meaning |", "|---|---|---|---|"]
    for f in dataclasses.fields(owner):
        if not f.metadata:
            continue
        words = allowed(f.metadata)
        if f.metadata["choices"]:
            words = ("some of " if isinstance(f.default, tuple) else "one of ") + words
        cells = [f"`{f.name}`", f"`{toml_value(f.default)}`", words, f.metadata["help"]]
        rows.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return rows


def reference() -> str:
    lines = [INTRO, "## Top level", "", *table(Settings), ""]
    for f in dataclasses.fields(Settings):
        section = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if section is None:
            continue
        lines += [f"## [{f.name}]", ""]
        doc = inspect.getdoc(section) or ""
        if not doc.startswith(section.__name__ + "("):  # dataclass's own docstring: the signature
            lines += [" ".join(doc.split()), ""]
        lines += [*table(section), ""]
    return "\n".join(lines)


if __name__ == "__main__":
    print(reference(), end="")
