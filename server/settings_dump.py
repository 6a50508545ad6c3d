"""The effective settings as commented TOML (`fpv-station config --dump`), as kvmd's
`--dump-config` prints its own: every key with its description above it, and its default
when the value differs. The output loads back as a config file into the same settings,
except for secrets, which are never printed (a dump is made to be shown to others)."""

from __future__ import annotations

import json
import re
import textwrap
from typing import Any

from pydantic import BaseModel

from fpv_station.server.settings import Settings

SECRET_KEYS = frozenset({"server.token"})
"""Dotted keys whose value is never printed: only whether it is set."""

HEADER = """\
# fpv-station settings, as `fpv-station serve` would load them: defaults, then
# --config FILE.toml, then FPV_<SECTION>__<KEY> environment variables, then flags.
# Save it as a config file, edit it, and pass it with --config; a key left out keeps
# its default. A key shown commented out is unset.
"""

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")
_WIDTH = 88


def dump_settings(settings: Settings) -> str:
    """`settings` as commented TOML, section by section in declaration order."""
    lines = [HEADER]
    _section(settings, Settings(), [], lines)
    return "\n".join(lines).rstrip() + "\n"


def _section(model: BaseModel, default: BaseModel, path: list[str], lines: list[str]) -> None:
    fields = type(model).model_fields
    tables = [n for n in fields if isinstance(getattr(model, n), BaseModel)]
    values, defaults = model.model_dump(mode="json"), default.model_dump(mode="json")
    for name, info in fields.items():
        if name in tables:
            continue
        dotted = ".".join([*path, name])
        value, was = values[name], defaults[name]
        lines.extend(_comment(info.description or ""))
        if value != was and dotted not in SECRET_KEYS:
            lines.append(f"# default: {_literal(was) if was is not None else 'unset'}")
        if dotted in SECRET_KEYS and value is not None:
            lines.append(f"# {_key(name)} = (set; not shown)")
        elif value is None:
            lines.append(f"# {_key(name)} = (unset)")
        else:
            lines.append(f"{_key(name)} = {_literal(value)}")
        lines.append("")
    for name in tables:
        sub_path = [*path, name]
        lines.append(f"[{'.'.join(_key(p) for p in sub_path)}]")
        about = type(getattr(model, name)).__doc__ or fields[name].description or ""
        lines.extend(_comment(about))
        lines.append("")
        _section(getattr(model, name), getattr(default, name), sub_path, lines)


def _comment(text: str) -> list[str]:
    text = " ".join(text.split())
    return ["# " + line for line in textwrap.wrap(text, _WIDTH - 2)] if text else []


def _key(name: str) -> str:
    return name if _BARE_KEY.match(name) else _string(name)


def _string(text: str) -> str:
    # A JSON string is a TOML basic string once every non-ASCII character stays literal
    # (TOML refuses JSON's surrogate-pair escapes) and DEL is escaped (JSON leaves it).
    return json.dumps(text, ensure_ascii=False).replace("\x7f", "\\u007f")


def _literal(value: Any) -> str:
    """One JSON-mode value (what `model_dump(mode="json")` gives) as a TOML literal."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)  # inf, -inf and nan are TOML too; repr round-trips exactly
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_literal(v) for v in value) + "]"
    if isinstance(value, dict):
        if not value:
            return "{}"
        return "{ " + ", ".join(f"{_key(k)} = {_literal(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"A setting of type {type(value).__name__} has no TOML form.")
