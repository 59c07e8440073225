"""What every schema shares: the named option (`Choice`), the seed's range, the type check of a
config's values (`check_types`) and the small checks each schema's `check` calls, each raising
ValueError that names the full key, the bad value and what is allowed."""

from __future__ import annotations

import json
import math
import os
import typing
from dataclasses import asdict, fields, is_dataclass
from enum import Enum
from typing import Any


class Choice(str, Enum):
    """A named option: compares, hashes, prints and serialises as its plain string."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


class Dtype(Choice):
    float64 = "float64"
    float32 = "float32"


# Seeds feed scikit-learn's random_state (< 2**32) and derive data streams seed * 1000 + k.
MAX_SEED = 2**32 - 1


def type_mismatch(annotation: Any, value: Any) -> str | None:
    """What is allowed where `value` is not of the field type `annotation` (None where it is): a
    bool field takes only true or false (not 1, 2 or "yes", which OmegaConf would take for true),
    an int field only integers (not 1.5, not true), a float field only numbers (not true), a str
    field no bool (true would become "True"), a choice one of its names; lists and dicts element by
    element. Nested config schemas are checked field by field by `check_types`."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Union:  # Optional[X]
        inner = [a for a in args if a is not type(None)]
        return None if value is None else type_mismatch(inner[0], value)
    if annotation is bool:
        return None if isinstance(value, bool) else "must be true or false"
    if annotation is int:
        return None if isinstance(value, int) and not isinstance(value, bool) else "must be an integer"
    if annotation is float:
        return None if isinstance(value, (int, float)) and not isinstance(value, bool) else "must be a number"
    if annotation is str:
        return "must be a string (on the command line, quote it: 'true')" if isinstance(value, bool) else None
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        names = [m.value for m in annotation]
        return None if value in names else f"expected one of {names}"
    if origin is list and isinstance(value, (list, tuple)):
        errors = (type_mismatch(args[0], v) for v in value)
        return next((f"each entry {e}" for e in errors if e), None)
    if origin is dict and isinstance(value, dict):
        errors = (type_mismatch(args[1], v) for v in value.values())
        return next((f"each value {e}" for e in errors if e), None)
    if origin in (list, dict):
        return f"must be a {origin.__name__}"
    return None


def check_types(cfg: Any, key: str = "") -> None:
    """ValueError naming the full key and value of the first field of the config dataclass `cfg`
    (nested ones included) whose value is not of its declared type (`type_mismatch`): the Python API's
    counterpart of what Hydra's composition and `check_overrides` refuse on the command line."""
    hints = typing.get_type_hints(type(cfg))
    for f in fields(cfg):
        value, name = getattr(cfg, f.name), f"{key}{f.name}"
        if is_dataclass(value):
            check_types(value, f"{name}.")
            continue
        error = type_mismatch(hints[f.name], value)
        if error:
            raise ValueError(f"{name}={value!r} is not allowed: {error}")


def from_mapping(schema: type, data: Any, key: str = "") -> Any:
    """The config dataclass `schema` built from plain data (a YAML file's mapping) as Hydra's
    composition builds it, without Hydra: choices from their names, nested schemas from nested
    mappings, integers where a float is declared as floats, the fields not given at their
    defaults. ValueError naming the full key of a key the schema lacks or of a value of another
    type (`type_mismatch`)."""
    if not isinstance(data, dict):
        raise ValueError(f"{key.rstrip('.') or schema.__name__}={data!r} is not allowed: must be a mapping of keys")
    hints, names = typing.get_type_hints(schema), [f.name for f in fields(schema)]
    unknown = [k for k in data if k not in names]
    if unknown:
        raise ValueError(f"{key}{unknown[0]} is not a key of {schema.__name__}; its keys: {sorted(names)}")
    values = {name: _typed(hints[name], value, f"{key}{name}") for name, value in data.items()}
    return schema(**values)


def _typed(annotation: Any, value: Any, key: str) -> Any:
    """`value` as a field of type `annotation` holds it (`from_mapping`), or ValueError."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Union:  # Optional[X]
        return None if value is None else _typed(next(a for a in args if a is not type(None)), value, key)
    if is_dataclass(annotation) and isinstance(annotation, type):
        return from_mapping(annotation, value, f"{key}.")
    error = type_mismatch(annotation, value)
    if error:
        raise ValueError(f"{key}={value!r} is not allowed: {error}")
    if annotation is float:
        return float(value)
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        return annotation(value)
    if origin is list:
        return [_typed(args[0], v, key) for v in value]
    if origin is dict:
        return {k: _typed(args[1], v, key) for k, v in value.items()}
    return value


def _check_sensing(rate: float | None, counts: list[float], key: str) -> None:
    """`key`.control_rate (Hz or null) and `key`.encoder_counts, the robot's facts and the loop's."""
    _need(rate is None or (finite(rate) and rate > 0), f"{key}.control_rate", rate, "must be > 0 Hz or null")
    _need(
        all(finite(c) and c >= 1 for c in counts),
        f"{key}.encoder_counts",
        list(counts),
        "counts per revolution (per metre for a prismatic joint) >= 1, one per chain joint, or empty (exact)",
    )


AOT_CHOICES = ("auto", "true", "false")  # control.aot, online.aot (a bool from the command line reads as one)


def _check_aot(value: Any, key: str) -> None:
    _need(str(value).lower() in AOT_CHOICES, key, value, f"choose from {list(AOT_CHOICES)}")


def _need(ok: bool, key: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ValueError(f"{key}={value!r} is not allowed: {allowed}")


def finite(x: Any) -> bool:
    """Whether `x` is a finite int or float (not a bool): the check every numeric setting passes."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def validate_device(device: str, num_threads: int, prefix: str = "") -> None:
    """`device` is cpu or an available cuda[:N]; `num_threads` in [0, MAX_THREADS_PER_CPU x the
    machine's CPUs] (torch's thread pool crashes the process far above that: 100 000 segfaults)."""
    most = MAX_THREADS_PER_CPU * (os.cpu_count() or 1)
    _need(
        isinstance(num_threads, int) and 0 <= num_threads <= most,
        f"{prefix}num_threads",
        num_threads,
        f"use 0 (torch's default) or a number of threads up to {most} ({MAX_THREADS_PER_CPU} x this machine's "
        f"{os.cpu_count() or 1} CPUs)",
    )
    d = str(device)
    ok = d == "cpu" or d == "cuda" or (d.startswith("cuda:") and d[5:].isdigit())
    _need(ok, f"{prefix}device", device, "use 'cpu', 'cuda' or 'cuda:N'")
    if d != "cpu":
        import torch  # a runtime fact, not a schema one

        if not torch.cuda.is_available():
            raise ValueError(
                f"{prefix}device={device!r}: no CUDA device is available to this torch "
                f"(torch {torch.__version__}, built for CUDA {torch.version.cuda}); use device=cpu"
            )
        n = torch.cuda.device_count()
        if d.startswith("cuda:") and int(d[5:]) >= n:
            raise ValueError(f"{prefix}device={device!r}: only {n} CUDA device(s) (cuda:0..cuda:{n - 1})")


MAX_THREADS_PER_CPU = 4  # num_threads' ceiling: more threads than that only contend for the CPUs


def _seed(key: str, seed: Any) -> None:
    _need(isinstance(seed, int) and 0 <= seed <= MAX_SEED, key, seed, f"use an integer in [0, {MAX_SEED}]")


def plain(cfg: Any) -> dict:
    """A config dataclass as plain JSON data (choices as strings), for checkpoints and logs."""
    return json.loads(json.dumps(asdict(cfg)))
