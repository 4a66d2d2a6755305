"""Shared test plumbing: which CAN bus each live test used is printed in the summary."""

from __future__ import annotations

from pathlib import Path

import pytest

#: (test id, bus description) for every live-bus test that ran
BUSES_USED: list[tuple[str, str]] = []

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
RAV4_LOG = SHARED / "realdata" / "comma2k19_rav4" / "rav4_highway_60s.log"
RAV4_DBC = SHARED / "realdata" / "comma2k19_rav4" / "toyota_rav4_2017_chassis.dbc"


@pytest.fixture
def record_bus(request):
    def record(description: str) -> None:
        BUSES_USED.append((request.node.nodeid, description))
        print(f"bus used: {description}")

    return record


@pytest.fixture(scope="session")
def rav4_paths():
    if not RAV4_LOG.exists():
        pytest.fail(f"the real-data log is missing: {RAV4_LOG} (shared/ must sit beside the checkout)")
    return RAV4_LOG, RAV4_DBC


def pytest_terminal_summary(terminalreporter):
    if BUSES_USED:
        terminalreporter.section("CAN buses used by live tests")
        for nodeid, bus in BUSES_USED:
            terminalreporter.write_line(f"{bus}  <- {nodeid}")
