"""Shared test plumbing: which CAN bus each live test used is printed in the summary."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

#: (test id, bus description) for every live-bus test that ran
BUSES_USED: list[tuple[str, str]] = []

def _shared() -> Path:
    """The project's shared folder: $ONLINE_ID_SHARED, else ``shared/`` beside the checkout, else /work/shared."""
    candidates = [Path(os.environ["ONLINE_ID_SHARED"])] if os.environ.get("ONLINE_ID_SHARED") else []
    candidates += [Path(__file__).resolve().parents[1].parent / "shared", Path("/work/shared")]
    return next((p for p in candidates if (p / "realdata").is_dir()), candidates[0])


SHARED = _shared()
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
        pytest.fail(f"the real-data log is missing: {RAV4_LOG} (shared/ must sit beside the checkout,"
                    " or set ONLINE_ID_SHARED)")
    return RAV4_LOG, RAV4_DBC


def pytest_terminal_summary(terminalreporter):
    if BUSES_USED:
        terminalreporter.section("CAN buses used by live tests")
        for nodeid, bus in BUSES_USED:
            terminalreporter.write_line(f"{bus}  <- {nodeid}")
