#!/usr/bin/env bash
# Install the Debian packages the test suite needs, where apt is available and they are missing:
# tests/test_vcan_vm.py boots Debian's kernel under qemu for a real SocketCAN vcan0 (this kind of
# machine's kernel has no CAN): qemu-system-x86, busybox-static, kmod, and the package lists
# (the harness downloads the kernel package with apt-get download); tests/test_browser.py opens the
# report, the live page and the fleet page in a real browser: chromium, driven by chromium-driver.
# Without apt (not Debian) nothing is done; a failed install is a warning: the VM test then fails
# and names the missing tool. Called by scripts/test.sh (the README's test command).
set -euo pipefail
PACKAGES="qemu-system-x86 busybox-static kmod chromium chromium-driver"

if ! command -v apt-get >/dev/null 2>&1; then
    echo "== no apt-get: not installing $PACKAGES (tests/test_vcan_vm.py and tests/test_browser.py need them)"
    exit 0
fi
sudo=""
if [ "$(id -u)" != 0 ]; then
    if command -v sudo >/dev/null 2>&1; then sudo="sudo -n"; else
        echo "== warning: not root and no sudo: cannot install missing packages"; fi
fi
missing=""
for pkg in $PACKAGES; do
    dpkg -s "$pkg" >/dev/null 2>&1 || missing="$missing $pkg"
done
if [ -n "$missing" ] || ! apt-cache show linux-image-amd64 >/dev/null 2>&1; then
    echo "== apt-get update (for:${missing:- the kernel package list})"
    $sudo apt-get update -q >/dev/null || echo "== warning: apt-get update failed"
fi
if [ -n "$missing" ]; then
    echo "== apt-get install$missing"
    # shellcheck disable=SC2086  # $missing is a list of package names
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q $missing </dev/null >/dev/null \
        || echo "== warning: apt-get install$missing failed; tests/test_vcan_vm.py and tests/test_browser.py will say what is missing"
else
    echo "== test packages present: $PACKAGES"
fi
