"""Shared test fixtures: the real-data root and its sequences, loopback port allocation, and the
`firmware` marker (tests against the real autopilot firmware: skipped with the reason where it is
missing, failed in CI; one xdist worker runs them all, one after the other, so no two firmware
processes compete for the CPU)."""
from __future__ import annotations

import os
import socket
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")  # before any pymavlink import

import pytest


def require(missing: str | None) -> None:
    """Skip with the reason `missing` (a peer the test needs is absent) outside CI; fail in CI (env CI set)."""
    if missing is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI needs it: {missing}")
    pytest.skip(missing)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "firmware(*kinds): runs real autopilot firmware ('arducopter', 'px4')")


@pytest.hookimpl(tryfirst=True)  # before xdist reads the group marks
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("firmware"):
            item.add_marker(pytest.mark.slow)
            item.add_marker(pytest.mark.xdist_group("firmware"))


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures start anything
def pytest_runtest_setup(item: pytest.Item) -> None:
    from sim.firmware import firmware_missing

    marker = item.get_closest_marker("firmware")
    for kind in marker.args if marker else ():
        require(firmware_missing(kind))


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The shared UAV sequences (OTB layout) from JSAR_DATA_ROOT; skip with a message when absent."""
    root = os.environ.get("JSAR_DATA_ROOT")
    if not root:
        pytest.skip("JSAR_DATA_ROOT is not set: real-sequence tests need the shared UAV data (set it to a folder "
                    "of OTB-layout sequences: <name>/img/*.jpg + <name>/groundtruth_rect.txt)")
    path = Path(root)
    if not path.is_dir():
        pytest.skip(f"JSAR_DATA_ROOT={root} is not a directory")
    return path


def real_sequence(data_root: Path, name: str):
    """Sequence `name` under the data root, read by jsar.eval.dataset.load_sequence (frame paths; ground truth
    (N, 4) 0-based x, y, w, h pixels, NaN rows = target not visible); skip when it is not there."""
    from jsar.eval.dataset import load_sequence

    folder = data_root / name
    if not folder.is_dir():
        pytest.skip(f"sequence {name} is not under JSAR_DATA_ROOT")
    return load_sequence(folder)


def free_tcp_port() -> int:
    """A loopback TCP port that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def free_udp_port() -> int:
    """A loopback UDP port that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def tcp_port() -> int:
    return free_tcp_port()


@pytest.fixture
def udp_port() -> int:
    return free_udp_port()
