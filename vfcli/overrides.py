"""``--set section.field=value`` items: reading them into a config dict, writing a value back as one, and
the settings two configs differ in (what `vfcli info` prints to resume a stopped fit)."""
from __future__ import annotations

import json
import tomllib
from typing import Any

from vfcli.errors import ConfigError


def parse_value(text: str) -> Any:
    """A ``--set`` value: TOML/JSON literal when it parses as one, ``null`` for none (a field that may be
    unset, e.g. ``optimize.n_frames=null``: one glottal cycle; TOML has no null), else the plain string
    (``'"null"'`` for the string)."""
    if text == "null":
        return None
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except (RecursionError, ValueError, MemoryError) as exc:  # nested too deep, a 5000-digit integer
        raise ConfigError(f"--set value {text[:40]!r}...: {toml_limit(exc)}") from None


def override_item(key: str, value: Any) -> str:
    """The ``--set`` item ``key=value`` that :func:`apply_overrides` reads back as ``value`` (a JSON value:
    None as ``null``, a string bare unless it would read as another value, then quoted)."""
    if value is None:
        return f"{key}=null"
    if isinstance(value, str):
        plain = value == value.strip() and value != "null" and parse_value(value) == value
        text = value if plain else json.dumps(value)
        return f"{key}={text}"
    return f"{key}={json.dumps(value)}"


def settings_changes(saved: dict[str, Any], current: dict[str, Any], prefix: str = "") -> list[tuple[str, Any, Any]]:
    """``(section.field, saved value, current value)`` for every field of the nested settings ``saved`` whose value
    differs from ``current``'s (a field ``current`` lacks counts as None), in the order of ``saved``."""
    out: list[tuple[str, Any, Any]] = []
    for key, value in saved.items():
        now = current.get(key) if isinstance(current, dict) else None
        if isinstance(value, dict):
            out += settings_changes(value, now if isinstance(now, dict) else {}, f"{prefix}{key}.")
        elif value != now:
            out.append((f"{prefix}{key}", value, now))
    return out


def toml_limit(exc: BaseException) -> str:
    """Why a TOML text or a --set value is refused when parsing it hit a limit (nesting, a huge integer)."""
    if isinstance(exc, RecursionError):
        return "nested too deep to be a config"
    return f"not a config value ({str(exc)[:120]})"


def apply_overrides(base: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """Apply ``section.field=value`` overrides to a config dict (returns a new dict)."""
    out = json.loads(json.dumps(base))
    for item in overrides:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item!r}: expected section.field=value")
        node = out
        *parents, leaf = key.strip().split(".")
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {item!r}: {p} is not a section")
        node[leaf] = parse_value(value.strip())
    return out
