"""Name -> tracker factory. `create(name, **overrides)` builds a tracker with config overrides."""
from __future__ import annotations

from typing import Any, Callable

from jsar.api import Tracker


def _factories() -> dict[str, Callable[..., Tracker]]:
    # Imported lazily so `import jsar` stays cheap and a missing optional piece names itself.
    from jsar.opencv_trackers import make_csrt, make_kcf

    # OpenCV's trackers: the evaluation's baselines, and usable before the JSAR tracker exists.
    factories: dict[str, Callable[..., Tracker]] = {"csrt": make_csrt, "kcf": make_kcf}
    try:
        from jsar.tracking.jsar_tracker import make_jsar, make_strcf
    except ModuleNotFoundError as exc:
        if exc.name != "jsar.tracking.jsar_tracker":
            raise
    else:
        factories.update({"jsar": make_jsar, "strcf": make_strcf})
    try:
        from jsar.redetect.jsar_re import make_jsar_re
    except ModuleNotFoundError as exc:
        if exc.name != "jsar.redetect.jsar_re":
            raise
    else:
        factories["jsar-re"] = make_jsar_re
    return factories


def available() -> list[str]:
    """Names accepted by `create`."""
    return sorted(_factories())


def create(name: str, **overrides: Any) -> Tracker:
    """Build tracker `name` ("jsar", "strcf", "jsar-re", "csrt", "kcf") with parameter overrides (ValueError if unknown)."""
    factories = _factories()
    if name not in factories:
        raise ValueError(f"unknown tracker {name!r}; available: {', '.join(sorted(factories))}")
    return factories[name](**overrides)
