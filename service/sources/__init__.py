"""Frame sources (v4l2, file, zenoh) behind one reader protocol; `make_reader` picks one from config."""
from __future__ import annotations

from service.config import SourceConfig
from service.sources.base import CaptureWorker, Frame, FrameReader, LatestSlot, SourceError


def make_reader(config: SourceConfig, zenoh_session: object | None = None, zenoh_prefix: str = "jsar") -> FrameReader:
    """The reader for `config.kind`; zenoh needs an open session."""
    if config.kind == "v4l2":
        from service.sources.v4l2 import V4L2Reader
        return V4L2Reader(config.device, config.width, config.height, config.fps, config.fourcc)
    if config.kind == "file":
        from service.sources.file import FileReader
        return FileReader(config.path, realtime=config.realtime, loop=config.loop, folder_fps=config.fps)
    if config.kind == "zenoh":
        if zenoh_session is None:
            raise ValueError("source.kind zenoh needs a Zenoh session (zenoh.enabled: true)")
        from service.sources.zenoh import ZenohReader
        return ZenohReader(zenoh_session, zenoh_prefix)
    raise ValueError(f"source.kind: unknown kind {config.kind!r}")


__all__ = ["CaptureWorker", "Frame", "FrameReader", "LatestSlot", "SourceError", "make_reader"]
