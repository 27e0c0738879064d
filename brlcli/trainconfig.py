"""Training configurations from layers: a named variant, a TOML file, `--set KEY=VALUE` overrides.

A layer is a (flat or nested) table of overrides of `TrainConfig().to_dict()`; `brl sweep` grids, `brl train
--config FILE.toml` and `brl train --set` use the same schema and the same one-line errors. A layer may name a
variant (`variant = "NAME"`): its preset (`VARIANT_PRESETS`) is applied first, then the layers in order.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from brlcli.errors import BrlInputError
from brlcli.train import TASK_PRESETS, VARIANT_PRESETS, TrainConfig

OPEN_TABLES = {"params"}
"""Config tables whose keys are checked by their owner (params.*: BRLParams.from_dict), not against the defaults."""


def merge_layer(base: dict[str, Any], over: dict[str, Any], where: str, defaults: dict[str, Any] | None,
                what: str = "training") -> dict[str, Any]:
    """`over` merged onto `base`: tables merge key by key into tables, anything else replaces; keys not in `defaults`
    are an error naming the `what` config."""
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
            open_table = not (isinstance(default, dict) and default) or name in OPEN_TABLES
            sub_defaults = None if open_table else default  # keys of an open table are checked by its owner
            out[key] = merge_layer(out[key], value, f"{name}.", sub_defaults, what)
        else:
            out[key] = value
    return out


def check_types(d: dict[str, Any], defaults: dict[str, Any], where: str = "", what: str = "training") -> None:
    """Each value has its default's type (int for int, a number for float, a list for a tuple, ...)."""
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
            if ok and default and name not in OPEN_TABLES:
                check_types(value, default, f"{name}.", what)
        else:
            ok = isinstance(value, type(default))
        if not ok:
            kinds = ((bool, "true or false"), (int, "an integer"), (float, "a number"), (str, "a string"),
                     (list | tuple, "a list"), (dict, "a table"))
            kind = next((k for t, k in kinds if isinstance(default, t)), type(default).__name__)
            raise BrlInputError(f"{what} config key '{name}' must be {kind}, not {json.dumps(value, default=str)}")


def variant_of(layers: Sequence[dict[str, Any]], default: str) -> str:
    """The variant the layers name (the last one that sets it), else `default`; unknown names are an error."""
    name = default
    for layer in layers:
        if "variant" in layer:
            name = layer["variant"]
    if not isinstance(name, str) or name not in VARIANT_PRESETS:
        raise BrlInputError(f"unknown variant {json.dumps(name, default=str)}; choose one of "
                            f"{', '.join(VARIANT_PRESETS)}")
    return name


def resolve_config(layers: Sequence[dict[str, Any]], default_variant: str = "paper") -> TrainConfig:
    """The defaults, the named variant's preset, then `layers` in order; validated with one-line errors."""
    defaults = {**TrainConfig().to_dict(), "route_kinds": None}  # None: the task's routes (TASK_ROUTE_KINDS)
    variant = variant_of(layers, default_variant)
    merged = merge_layer(defaults, {**VARIANT_PRESETS[variant], "variant": variant}, "", defaults)
    task = next((layer["task"] for layer in reversed(layers) if "task" in layer), defaults["task"])
    preset = TASK_PRESETS.get(task, {}) if isinstance(task, str) else {}  # an unknown task: TrainConfig says so
    merged = merge_layer(merged, preset, "", defaults)
    for layer in layers:
        merged = merge_layer(merged, layer, "", defaults)
    check_types(merged, defaults)
    try:
        cfg = TrainConfig.from_dict(merged)
        cfg.agent_params()  # validates params.* (BRLParams.from_dict)
    except BrlInputError:
        raise
    except (TypeError, ValueError) as exc:
        raise BrlInputError(" ".join(str(exc).split())) from None
    return cfg


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
    """A TOML (or .json) file of training config overrides, decoded; one-line errors."""
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


def resolve_plain_config(cls: Any, layers: Sequence[str | dict[str, Any] | Sequence[str] | None], what: str) -> Any:
    """A config dataclass (`to_dict` / `from_dict`, no variants) from layers: a --config path, a dict of options
    given on the command line, a list of --set items; each checked against the defaults with one-line errors."""
    defaults = cls().to_dict()
    merged = dict(defaults)
    for layer in layers:
        if layer is None:
            continue
        if isinstance(layer, str):
            layer = read_config_file(layer)
        elif not isinstance(layer, dict):
            layer = parse_sets(layer)
        merged = merge_layer(merged, layer, "", defaults, what)
    check_types(merged, defaults, what=what)
    try:
        return cls.from_dict(merged)
    except BrlInputError:
        raise
    except (TypeError, ValueError) as exc:
        raise BrlInputError(" ".join(str(exc).split())) from None
