"""bench.encoders' pure pieces: the compared libx264 settings are the stream's own options with one change each,
and the quality measure."""
from __future__ import annotations

import numpy as np
import pytest

from bench.encoders import OTHER_WORK, STREAM_SETTING, X264_SETTINGS, psnr_db, report, setting_options
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


def test_the_report_gives_this_hosts_instruction_rate_only_for_counts_made_here() -> None:
    """An arm64 count (under qemu) against this host's CPU time is no rate: the column stays empty."""
    kinds = (*OTHER_WORK, *X264_SETTINGS)
    ms = {kind: 2.0 for kind in kinds}
    counts = {kind: 10e6 for kind in kinds}
    here = report(ms, {}, counts).splitlines()[2]
    arm64 = report(ms, {}, counts, native_counts=False).splitlines()[2]
    assert "| 10.0 | 5.0 |" in here  # 10 M instructions in 2 ms: 5 G/s
    assert "| 10.0 | - |" in arm64
