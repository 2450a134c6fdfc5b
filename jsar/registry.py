"""Name -> tracker factory. `create(name, **overrides)` builds a tracker with config overrides."""
from __future__ import annotations

from typing import Any, Callable

from jsar.api import Tracker


def _factories() -> dict[str, Callable[..., Tracker]]:
    # Imported lazily so `import jsar` stays cheap.
    from jsar.opencv_trackers import make_csrt, make_kcf
    from jsar.redetect.jsar_re import make_jsar_re
    from jsar.tracking.jsar_tracker import make_jsar, make_strcf

    # csrt and kcf are OpenCV's trackers: the evaluation's baselines.
    return {"jsar": make_jsar, "strcf": make_strcf, "jsar-re": make_jsar_re, "csrt": make_csrt, "kcf": make_kcf}


def available() -> list[str]:
    """Names accepted by `create`."""
    return sorted(_factories())


def create(name: str, **overrides: Any) -> Tracker:
    """Build tracker `name` ("jsar", "strcf", "jsar-re", "csrt", "kcf") with parameter overrides (ValueError if unknown)."""
    factories = _factories()
    if name not in factories:
        raise ValueError(f"unknown tracker {name!r}; available: {', '.join(sorted(factories))}")
    return factories[name](**overrides)
