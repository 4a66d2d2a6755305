"""The VM harness reports which step failed, and never hangs (a fake qemu stands in for the real one)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent / "vm"))
import harness  # noqa: E402


@pytest.fixture
def fake_qemu(tmp_path, monkeypatch):
    """Install a ``qemu-system-x86_64`` that runs the given shell body instead of booting a guest."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    monkeypatch.setenv("PATH", f"{bindir}:/usr/bin:/bin")
    monkeypatch.setattr(harness, "CACHE", tmp_path / "cache")
    (tmp_path / "cache").mkdir()
    monkeypatch.setattr(harness, "prepare", lambda: (tmp_path / "vmlinuz", _empty_initrd(tmp_path), "6.1.0-test"))

    def install(body: str) -> None:
        exe = bindir / "qemu-system-x86_64"
        exe.write_text("#!/bin/sh\n" + body + "\n")
        exe.chmod(0o755)

    return install


def _empty_initrd(tmp_path: Path) -> Path:
    p = tmp_path / "base.cpio.gz"
    p.write_bytes(b"")
    return p


def test_missing_qemu_names_the_tools_step(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))  # nothing on PATH
    with pytest.raises(harness.VMError, match=r"(?s)step 'tools'.*qemu-system-x86_64 not found.*qemu-system-x86"):
        harness.check_tools()


def test_a_guest_that_never_boots_fails_at_the_boot_step_without_hanging(fake_qemu, monkeypatch):
    monkeypatch.setattr(harness, "BOOT_TIMEOUT_S", 1)
    fake_qemu('echo "SeaBIOS"; echo "Booting from ROM..."; sleep 60')
    with pytest.raises(harness.VMError, match=r"(?s)step 'boot'.*within 1 s.*Booting from ROM") as err:
        harness.run("true", timeout_s=30)
    assert err.value.step == "boot"


def test_a_command_that_never_ends_fails_at_the_command_step(fake_qemu):
    fake_qemu('echo OID_BOOTED_AT=3.5; echo OID_BEGIN; echo "still running"; sleep 60')
    with pytest.raises(harness.VMError, match=r"(?s)step 'command'.*no end within 2 s.*still running"):
        harness.run("true", timeout_s=2)


def test_guest_setup_failures_are_reported(fake_qemu):
    fake_qemu('echo "OID_FAIL ip link add vcan0 failed"; echo OID_BEGIN; echo OID_RC=0')
    with pytest.raises(harness.VMError, match=r"(?s)step 'guest setup'.*ip link add vcan0 failed"):
        harness.run("true", timeout_s=30)


def test_the_commands_output_exit_status_and_boot_time_come_back(fake_qemu):
    fake_qemu(r'printf "kernel noise\r\nOID_BOOTED_AT=4.25\r\nOID_BEGIN\r\n3 passed\r\nOID_RC=3\r\n"')
    result = harness.run("true", timeout_s=30)
    assert result.returncode == 3
    assert result.output.strip() == "3 passed"
    assert result.boot_s == pytest.approx(4.25)
    assert "kernel noise" in result.console and "kernel noise" not in result.output
