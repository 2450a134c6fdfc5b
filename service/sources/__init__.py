"""Frame sources (v4l2, file, zenoh) behind one reader protocol; `make_reader` picks one from config."""
from __future__ import annotations

import os

from service.config import ConfigError, SourceConfig
from service.sources.base import CaptureWorker, Frame, FrameReader, LatestSlot, SourceError


def check_source(config: SourceConfig) -> None:
    """Start-up check: a file source's video file or image folder exists; ConfigError naming source.path
    otherwise (a typo would else look like a failing camera, retried for ever). A file that exists but
    cannot be opened, or that goes away later, is a source fault the capture worker retries; so is a v4l2
    device absent at start or unplugged while running (it may be plugged in later)."""
    if config.kind == "file" and not os.path.exists(config.path):
        raise ConfigError(f"source.path: no such file or folder: {config.path!r}")


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


__all__ = ["CaptureWorker", "Frame", "FrameReader", "LatestSlot", "SourceError", "check_source", "make_reader"]
