"""One configuration pipeline for every command that trains: layers of overrides resolved into a frozen config.

A command's configuration is its config class's defaults, then (for `brl train`) the named method and task presets,
then the layers in order: `--config FILE.toml`, the options given on the command line, `--set KEY=VALUE`. Each
layer is a (flat or nested) table of overrides of `cls().to_dict()`; it is merged, type-checked against the
defaults and validated once by the class (`from_dict`, whose `__post_init__` checks every value), with one-line
errors that name the layer. The result is the frozen dataclass the library works with; the command records it once
(`config.json`, `run.json`, ...). `brl sweep` grids use the same schema for their `[base]` and `[variants.NAME]`.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from brlcli.errors import BrlInputError

C = TypeVar("C")


@dataclass(frozen=True)
class Layer:
    """One table of overrides and where it came from (named in errors)."""

    source: str
    values: dict[str, Any] = field(default_factory=dict)


def merge_layer(base: dict[str, Any], over: dict[str, Any], where: str, defaults: dict[str, Any] | None,
                what: str = "training", open_tables: Iterable[str] = ()) -> dict[str, Any]:
    """`over` merged onto `base`: tables merge key by key into tables, anything else replaces; keys not in `defaults`
    are an error naming the `what` config. The keys of an `open_tables` table are checked by its owner."""
    open_tables = tuple(open_tables)
    out = dict(base)
    for key, value in over.items():
        name = f"{where}{key}"
        if defaults is not None and key not in defaults:
            hint = (" (a dot in a TOML table name nests tables: quote the variant name, [variants.\"a.b\"])"
                    if where == "" and isinstance(value, dict) else "")
            raise BrlInputError(f"unknown {what} config key '{name}'{hint}; known keys: "
                                f"{', '.join(sorted(defaults))}")
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            default = defaults.get(key) if defaults is not None else None
            open_table = not (isinstance(default, dict) and default) or name in open_tables
            sub_defaults = None if open_table else default
            out[key] = merge_layer(out[key], value, f"{name}.", sub_defaults, what, open_tables)
        else:
            out[key] = value
    return out


def check_types(d: dict[str, Any], defaults: dict[str, Any], where: str = "", what: str = "training",
                open_tables: Iterable[str] = ()) -> None:
    """Each value has its default's type (int for int, a number for float, a list for a tuple, ...)."""
    open_tables = tuple(open_tables)
    for key, value in d.items():
        default, name = defaults.get(key), f"{where}{key}"
        if default is None:
            continue
        if isinstance(default, bool):
            ok = isinstance(value, bool)
        elif isinstance(default, int):
            ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(default, float):
            ok = isinstance(value, int | float) and not isinstance(value, bool)
        elif isinstance(default, list | tuple):
            ok = isinstance(value, list | tuple)
        elif isinstance(default, dict):
            ok = isinstance(value, dict)
            if ok and default and name not in open_tables:
                check_types(value, default, f"{name}.", what, open_tables)
        else:
            ok = isinstance(value, type(default))
        if not ok:
            kinds = ((bool, "true or false"), (int, "an integer"), (float, "a number"), (str, "a string"),
                     (list | tuple, "a list"), (dict, "a table"))
            kind = next((k for t, k in kinds if isinstance(default, t)), type(default).__name__)
            raise BrlInputError(f"{what} config key '{name}' must be {kind}, not {json.dumps(value, default=str)}")


def parse_value(text: str) -> Any:
    """A `--set` value: a TOML value (0.5, 12, true, "a", [1, 2], {a = 1}), else the text itself as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def parse_sets(items: Sequence[str]) -> dict[str, Any]:
    """`KEY=VALUE` items (dotted keys nest: params.gamma=0.8) as one override layer."""
    layer: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        parts = key.split(".")
        if not sep or not key or any(not p for p in parts):
            raise BrlInputError(f"--set '{item}' must be KEY=VALUE (dotted keys nest: --set params.gamma=0.8)")
        table = layer
        for i, part in enumerate(parts[:-1]):
            sub = table.setdefault(part, {})
            if not isinstance(sub, dict):
                raise BrlInputError(f"--set '{item}': '{'.'.join(parts[:i + 1])}' was set to a value above")
            table = sub
        if isinstance(table.get(parts[-1]), dict):
            raise BrlInputError(f"--set '{item}': '{key}' is a table; set its keys ({key}.NAME=VALUE)")
        table[parts[-1]] = parse_value(text.strip())
    return layer


def read_config_file(path: str | Path, what: str = "--config") -> dict[str, Any]:
    """A TOML (or .json) file of config overrides, decoded; one-line errors."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BrlInputError(f"{what} {path}: cannot read it ({exc.strerror or exc})") from None
    try:
        if path.suffix.lower() == ".json":
            doc = json.loads(data.decode("utf-8"))
        else:
            doc = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        kind = "JSON" if path.suffix.lower() == ".json" else "TOML"
        raise BrlInputError(f"{what} {path}: not valid {kind} ({' '.join(str(exc).split())})") from None
    if not isinstance(doc, dict):
        raise BrlInputError(f"{what} {path}: the document must be a table")
    return doc


def command_layers(config: str | Path | None, options: dict[str, Any], sets: Sequence[str] | None) -> list[Layer]:
    """The layers of a command line: `--config FILE`, the options given on it, `--set KEY=VALUE` items."""
    return [Layer("--config", read_config_file(config) if config is not None else {}),
            Layer("options", dict(options)), Layer("--set", parse_sets(sets or []))]


def resolve(cls: type[C], layers: Sequence[Layer], what: str, base: dict[str, Any] | None = None,
            defaults: dict[str, Any] | None = None, open_tables: Iterable[str] = ()) -> C:
    """`cls`'s defaults (or `base`, a preset already merged onto them), then `layers` in order, type-checked against
    `defaults` (default: `cls().to_dict()`) and validated by `cls.from_dict`, with one-line errors."""
    defaults = cls().to_dict() if defaults is None else defaults  # type: ignore[attr-defined]
    merged = dict(base if base is not None else defaults)
    for layer in layers:
        merged = merge_layer(merged, layer.values, "", defaults, what, open_tables)
    check_types(merged, defaults, what=what, open_tables=open_tables)
    try:
        return cls.from_dict(merged)  # type: ignore[attr-defined]
    except BrlInputError:
        raise
    except (TypeError, ValueError) as exc:
        raise BrlInputError(" ".join(str(exc).split())) from None


def check_known_keys(cls: type, d: dict[str, Any], what: str) -> None:
    """A one-line error for keys of `d` that are no field of the config dataclass `cls` (its `from_dict`)."""
    from dataclasses import fields

    extra = set(d) - {f.name for f in fields(cls)}
    if extra:
        raise BrlInputError(f"unknown {what} config keys: {', '.join(sorted(extra))}")
