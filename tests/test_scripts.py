"""The README's test command (scripts/test.sh) installs what the tests need and lets pytest's status through;
.ci/run runs exactly it (issue 17). Checked with stub apt-get/dpkg/python3 in PATH, so the check does not
depend on what this machine has installed."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASH = shutil.which("bash") or "/bin/bash"


def _stub(folder: Path, name: str, body: str) -> None:
    p = folder / name
    p.write_text(f"#!{BASH}\n{body}\n")
    p.chmod(0o755)


def _stubs(tmp_path: Path, installed: bool, apt: bool = True) -> tuple[Path, Path]:
    stubs, log = tmp_path / "bin", tmp_path / "calls.log"
    stubs.mkdir()
    if apt:
        _stub(stubs, "apt-get", f'echo "apt-get $*" >> {log}')
        _stub(stubs, "apt-cache", f"exit {0 if installed else 1}")
    _stub(stubs, "dpkg", f"exit {0 if installed else 1}")
    _stub(stubs, "id", "echo 0")
    return stubs, log


def _deps(stubs: Path) -> subprocess.CompletedProcess:
    return subprocess.run([BASH, str(ROOT / "scripts" / "install-test-deps.sh")], capture_output=True, text=True,
                          env={"PATH": str(stubs)}, timeout=60)


def test_a_fresh_debian_machine_gets_the_vm_and_browser_packages(tmp_path):
    stubs, log = _stubs(tmp_path, installed=False)
    res = _deps(stubs)
    assert res.returncode == 0, res.stderr
    calls = log.read_text().splitlines()
    assert calls[0] == "apt-get update -q"
    assert calls[1] == "apt-get install -y -q qemu-system-x86 busybox-static kmod chromium chromium-driver"


def test_nothing_is_installed_when_the_packages_are_there_or_apt_is_not(tmp_path):
    for case, installed, apt, says in (("present", True, True, "present"), ("no-apt", False, False, "no apt-get")):
        (tmp_path / case).mkdir()
        stubs, log = _stubs(tmp_path / case, installed=installed, apt=apt)
        res = _deps(stubs)
        assert res.returncode == 0 and not log.exists() and says in res.stdout, (case, res.stdout, res.stderr)


def test_the_test_command_passes_pytests_status_through_including_no_tests_collected(tmp_path):
    repo = tmp_path / "repo"
    (repo / "scripts").mkdir(parents=True)
    shutil.copy(ROOT / "scripts" / "test.sh", repo / "scripts" / "test.sh")
    _stub(repo / "scripts", "install-test-deps.sh", "echo deps")
    stubs = tmp_path / "bin"
    stubs.mkdir()
    # python3 -m venv .venv makes a venv whose pip works and whose pytest collects nothing (exit 5)
    _stub(stubs, "python3", f'mkdir -p .venv/bin && printf "#!{BASH}\\nexit 0\\n" > .venv/bin/pip'
                            f' && printf "#!{BASH}\\nexit 5\\n" > .venv/bin/python && chmod +x .venv/bin/*')
    res = subprocess.run([BASH, str(repo / "scripts" / "test.sh")], capture_output=True, text=True,
                         env={"PATH": f"{stubs}:/usr/bin:/bin"}, timeout=60)
    assert res.returncode == 5, (res.stdout, res.stderr)


def test_the_readme_and_ci_run_the_same_test_command():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, re.S)
    assert blocks[1].strip() == "scripts/test.sh"  # the second of the first two commands: the tests
    ci = (ROOT / ".ci" / "run").read_text()
    assert re.search(r"^exec scripts/test\.sh$", ci, re.M)
