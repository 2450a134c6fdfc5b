"""bench.encoders' pure pieces: the compared libx264 settings are the stream's own options with one change each,
and the quality measure."""
from __future__ import annotations

import numpy as np
import pytest

from bench.encoders import STREAM_SETTING, X264_SETTINGS, psnr_db, setting_options
from service.config import StreamConfig
from service.video.rtp_stream import x264_options


def test_the_first_setting_is_exactly_what_the_stream_uses() -> None:
    assert setting_options(X264_SETTINGS[STREAM_SETTING]) == x264_options(StreamConfig(fps=30.0, bitrate_kbps=2000))


def test_overrides_replace_or_drop_options_and_keep_the_rest() -> None:
    default = setting_options({"preset": "medium", "tune": None, "bf": None})
    assert default["preset"] == "medium" and "tune" not in default and "bf" not in default
    assert default["threads"] == "1" and default["maxrate"] == "2000k" and default["g"] == "30"
    assert setting_options({"preset": "veryfast"})["tune"] == "zerolatency"


def test_psnr() -> None:
    a = np.full((4, 4), 100, np.uint8)
    assert psnr_db(a, a) == float("inf")
    b = a.copy()
    b[0, 0] = 104  # mse = 16 / 16 = 1
    assert psnr_db(a, b) == pytest.approx(10 * np.log10(255.0 ** 2))
