"""Shared test fixtures and hooks: the real-data root (every test that asks for it is marked `data`), and the
`firmware` marker (tests against the real autopilot firmware: skipped with the reason where it is missing,
failed in CI; one xdist worker runs them all, one after the other, so no two firmware processes compete for
the CPU). Helpers that are not fixtures live in tests/helpers.py."""
from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")  # before any pymavlink import

import pytest  # noqa: E402

from tests.helpers import require  # noqa: E402


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "firmware(*kinds): runs real autopilot firmware ('arducopter', 'px4')")


@pytest.hookimpl(tryfirst=True)  # before xdist reads the group marks
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        # every test that reaches the shared data (asks for data_root, itself or through its fixtures) is `data`
        if "data_root" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.data)
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
