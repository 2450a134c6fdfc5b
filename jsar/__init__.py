"""JSAR / JSAR-Re correlation-filter trackers.

    import jsar
    tracker = jsar.create("jsar")          # or "strcf", "jsar-re"
    tracker.init(frame, (x, y, w, h))      # HxWx3 uint8 BGR, box in pixels, top-left origin
    result = tracker.update(frame)         # result.box, result.score, result.state
"""
from jsar.api import Box, Tracker, TrackResult, TrackState
from jsar.registry import available, create

__all__ = ["Box", "Tracker", "TrackResult", "TrackState", "available", "create"]
