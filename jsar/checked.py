"""Checked parameters: a dataclass field's default with the checks its values must pass, and the one loader.

`checked(default, *checks)` declares a field; `check_fields(params, prefix)` runs the checks of every field
(nested parameter sets too) and raises ValueError naming the key, e.g. `redetect.search.windows_per_frame must
be >= 0, got -1`. A check returns None or why the value fails; a `Relation` also sees the whole set (a bound
given by another key). `with_overrides` applies {key: value} overrides, types coerced to the defaults'.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping

Check = Callable[[Any], "str | None"]


@dataclass(frozen=True)
class Relation:
    """A check against other keys of the same parameter set: rule(value, params) -> None or why it fails."""

    rule: Callable[[Any, Any], "str | None"]


def checked(default: Any, *checks: Check | Relation) -> Any:
    """A dataclass field with a default and value checks run by the loader."""
    if isinstance(default, (list, dict)):
        raise TypeError("mutable defaults are not allowed; use tuples")
    return dataclasses.field(default=default, metadata={"checks": checks})


def positive(value: float) -> str | None:
    return None if value > 0 else f"must be > 0, got {value}"


def non_negative(value: float) -> str | None:
    return None if value >= 0 else f"must be >= 0, got {value}"


def in_range(low: float, high: float) -> Check:
    """low <= value <= high."""
    def check(value: float) -> str | None:
        return None if low <= value <= high else f"must be in [{low}, {high}], got {value}"
    return check


def at_least(low: float) -> Check:
    """value >= low."""
    return lambda value: None if value >= low else f"must be >= {low}, got {value}"


def interval(low: float, high: float, *, low_open: bool = False, high_open: bool = False) -> Check:
    """value in the interval from low to high, each end open or closed as told."""
    def check(value: float) -> str | None:
        inside = (low < value if low_open else low <= value) and (value < high if high_open else value <= high)
        return None if inside else f"must be in {'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}, got {value}"
    return check


def one_of(*choices: str) -> Check:
    """value is one of `choices`."""
    return lambda value: None if value in choices else f"must be one of {', '.join(map(repr, choices))}, got {value!r}"


def odd(value: int) -> str | None:
    return None if value % 2 else f"must be odd (a centre sample), got {value}"


def at_most_key(key: str) -> Relation:
    """value <= the value of `key`."""
    return Relation(lambda value, params: None if value <= getattr(params, key)
                    else f"must be <= {key} ({getattr(params, key)}), got {value}")


def at_least_key(key: str) -> Relation:
    """value >= the value of `key`."""
    return Relation(lambda value, params: None if value >= getattr(params, key)
                    else f"must be >= {key} ({getattr(params, key)}), got {value}")


def below_key(key: str) -> Relation:
    """value < the value of `key`."""
    return Relation(lambda value, params: None if value < getattr(params, key)
                    else f"must be < {key} ({getattr(params, key)}), got {value}")


def check_fields(params: Any, prefix: str = "") -> None:
    """Run every field's checks (nested parameter sets' too); ValueError naming `prefix.key` of the first failure."""
    for f in dataclasses.fields(params):
        value, name = getattr(params, f.name), f"{prefix}.{f.name}" if prefix else f.name
        if dataclasses.is_dataclass(value):
            check_fields(value, name)
        for check in f.metadata.get("checks", ()):
            problem = check.rule(value, params) if isinstance(check, Relation) else check(value)
            if problem:
                raise ValueError(f"{name} {problem}")


def with_overrides(params: Any, values: Any, prefix: str, unknown: Callable[[str], str] | None = None) -> Any:
    """`params` (a frozen dataclass) with `values` {key: value} applied, types coerced to the defaults'
    (unchecked); ValueError naming `prefix.key` on an unknown key (`unknown(key)`: the message) or a bad type."""
    if not isinstance(values, Mapping):
        raise ValueError(f"{prefix} must be a mapping of keys, got {values!r}")
    known = {f.name for f in dataclasses.fields(params)}
    coerced = {}
    for key, value in values.items():
        if key not in known:
            raise ValueError(unknown(key) if unknown is not None else
                             f"unknown key {prefix}.{key}; expected one of {', '.join(sorted(known))}")
        coerced[key] = coerce(f"{prefix}.{key}" if prefix else key, value, getattr(params, key))
    return dataclasses.replace(params, **coerced)


def coerce(name: str, value: Any, default: Any) -> Any:
    """`value` as the type of `default` (ints accepted for floats), or ValueError naming `name`."""
    if default is None:
        if value is None or isinstance(value, str):
            return value
        raise ValueError(f"{name} must be a path string or None, got {value!r}")
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{name} must be a list of numbers, got {value!r}")
        return tuple(coerce(name, v, 0.0) for v in value)
    if isinstance(default, str):
        if value is None or isinstance(value, str):
            return value
        raise ValueError(f"{name} must be a string, got {value!r}")
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be a bool, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return int(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)
