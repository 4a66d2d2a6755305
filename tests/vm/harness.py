"""A Debian kernel under qemu that runs a command on a real SocketCAN ``vcan0``.

This host's kernel has no CAN. The harness boots Debian's kernel (which has ``vcan`` as a module)
with a small busybox initramfs, shares the host's root read-only over virtio-9p, chroots into it
and creates ``vcan0``: the guest then runs the host's own Python, virtual environment and checkout
(see ``shared/VCAN.md`` for what was shown to work). Output comes back over the serial console.

Everything slow is prepared once and cached (``ONLINE_ID_VM_CACHE``, default
``~/.cache/online-id-vm``): the kernel package (``apt-get download``), ``depmod``, and the base
initramfs. Each run appends a tiny second archive holding the command (Linux accepts concatenated
initramfs archives). Every step that can fail raises :class:`VMError` naming the step.

Needs, from Debian: qemu-system-x86, busybox-static, kmod (``.ci/run`` installs them).
"""

from __future__ import annotations

import gzip
import hashlib
import io
import os
import re
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

CACHE = Path(os.environ.get("ONLINE_ID_VM_CACHE", Path.home() / ".cache" / "online-id-vm"))
MODULES = ("vcan", "can-raw", "9p", "9pnet_virtio", "virtio_pci")
BOOT_TIMEOUT_S = 60
BEGIN, RC = "OID_BEGIN", "OID_RC="

INIT = r"""#!/bin/busybox sh
/bin/busybox --install -s /bin
mkdir -p /proc /sys /dev /host
mount -t proc proc /proc || echo "OID_FAIL mount /proc"
mount -t sysfs sys /sys || echo "OID_FAIL mount /sys"
mount -t devtmpfs dev /dev || echo "OID_FAIL mount /dev"
for m in $(cat /modules.list); do insmod /modules/$m || echo "OID_STEP insmod $m failed"; done
mkdir -p /host
if ! mount -t 9p -o trans=virtio,version=9p2000.L,msize=512000 host /host; then
    echo "OID_FAIL mount of the host's root over 9p failed"; poweroff -f
fi
mount --bind /proc /host/proc || echo "OID_FAIL bind /proc into the host root"
mount --bind /sys /host/sys || echo "OID_FAIL bind /sys into the host root"
mount --bind /dev /host/dev || echo "OID_FAIL bind /dev into the host root"
# scratch space: a tmpfs at /run (not /tmp, which may hold the very checkout or venv under test)
mount -t tmpfs -o size=1g tmpfs /host/run || echo "OID_FAIL no writable scratch space at /run"
mkdir -p /host/run/tmp /host/run/home
mkdir -p /host/dev/shm && mount -t tmpfs tmpfs /host/dev/shm
chroot /host /usr/sbin/ip link add dev vcan0 type vcan || echo "OID_FAIL ip link add vcan0 failed"
chroot /host /usr/sbin/ip link set up vcan0
chroot /host /usr/sbin/ip -details link show vcan0
cp /cmd.sh /host/run/oid-cmd.sh
read up rest < /proc/uptime
echo "OID_BOOTED_AT=$up"
echo OID_BEGIN
chroot /host /usr/bin/env TMPDIR=/run/tmp HOME=/run/home /bin/sh /run/oid-cmd.sh
echo "OID_RC=$?"
poweroff -f
"""


class VMError(RuntimeError):
    """A step of preparing or running the VM failed; the message names the step."""

    def __init__(self, step: str, detail: str):
        super().__init__(f"VM step '{step}' failed: {detail}")
        self.step = step


@dataclass
class VMResult:
    returncode: int
    output: str  # the command's output (serial console after OID_BEGIN)
    console: str  # everything the guest printed
    boot_s: float  # qemu start to the command starting
    total_s: float


def host_has_vcan0() -> bool:
    """True when a CAN_RAW socket can bind to vcan0 here (then the live tests run without a VM)."""
    import socket

    if not hasattr(socket, "AF_CAN"):
        return False
    try:
        with socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as s:
            s.bind(("vcan0",))
        return True
    except OSError:
        return False


def _run(step: str, cmd: list[str], **kw) -> subprocess.CompletedProcess:
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, **kw)
    except FileNotFoundError:
        raise VMError(step, f"{cmd[0]} is not installed (apt-get install qemu-system-x86 busybox-static kmod)") \
            from None
    except subprocess.TimeoutExpired:
        raise VMError(step, f"{' '.join(cmd[:3])} timed out") from None
    if res.returncode != 0:
        raise VMError(step, f"{' '.join(cmd[:4])} exited {res.returncode}: {(res.stderr or res.stdout)[-500:]}")
    return res


def check_tools() -> None:
    for tool, pkg in (("qemu-system-x86_64", "qemu-system-x86"), ("busybox", "busybox-static"),
                      ("depmod", "kmod"), ("apt-get", "apt"), ("dpkg-deb", "dpkg")):
        if shutil.which(tool) is None:
            raise VMError("tools", f"{tool} not found: install Debian's {pkg} (scripts/test.sh does)")
    bb = _run("tools", ["file", "-L", shutil.which("busybox")]) if shutil.which("file") else None
    if bb is not None and "statically linked" not in bb.stdout:
        raise VMError("tools", "busybox is not statically linked: install busybox-static")


def kernel_package() -> str:
    res = _run("kernel lookup", ["apt-cache", "depends", "linux-image-amd64"], timeout=60)
    m = re.search(r"Depends: (linux-image-[0-9][^\s]*-amd64)", res.stdout)
    if not m:
        raise VMError("kernel lookup", "apt-cache names no linux-image for linux-image-amd64 (run apt-get update)")
    return m.group(1)


def prepare() -> tuple[Path, Path, str]:
    """Kernel image, base initramfs and kernel version. The kernel and its modules are downloaded
    once; the base initramfs is rebuilt whenever the init script or the module list changes."""
    check_tools()
    kernel = CACHE / "kernel"
    if not (kernel / "version").exists():
        _fetch_kernel(kernel)
    version = (kernel / "version").read_text().strip()
    digest = hashlib.sha256((INIT + " ".join(MODULES)).encode()).hexdigest()[:12]
    base = CACHE / f"base-{digest}.cpio.gz"
    if not base.exists():
        order = (kernel / "modules.list").read_text().split()
        files = {"init": (INIT.encode(), 0o100755),
                 "bin/busybox": (Path(shutil.which("busybox")).read_bytes(), 0o100755),
                 "modules.list": ("\n".join(order).encode() + b"\n", 0o100644)}
        for name in order:
            files[f"modules/{name}"] = ((kernel / "modules" / name).read_bytes(), 0o100644)
        tmp = base.with_suffix(".part")
        tmp.write_bytes(gzip.compress(_cpio(files), compresslevel=1))
        tmp.rename(base)
    return kernel / "vmlinuz", base, version


def _fetch_kernel(kernel: Path) -> None:
    """Download Debian's kernel package, keep vmlinuz and the modules the guest needs."""
    pkg = kernel_package()
    CACHE.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=CACHE) as tmp:
        _run("kernel download", ["apt-get", "download", "-q", pkg], cwd=tmp, timeout=600)
        debs = list(Path(tmp).glob("linux-image-*.deb"))
        if not debs:
            raise VMError("kernel download", f"apt-get download {pkg} produced no .deb")
        root = Path(tmp) / "root"
        _run("kernel extract", ["dpkg-deb", "-x", str(debs[0]), str(root)], timeout=300)
        version = next((root / "lib" / "modules").iterdir()).name
        _run("depmod", ["depmod", "-b", str(root), version], timeout=300)
        moddir = root / "lib" / "modules" / version
        order = _module_closure(moddir, MODULES)
        staging = Path(tmp) / "kernel"
        (staging / "modules").mkdir(parents=True)
        for p in order:
            shutil.copy(moddir / p, staging / "modules" / Path(p).name)
        (staging / "modules.list").write_text("\n".join(Path(p).name for p in order) + "\n")
        shutil.copy(root / "boot" / f"vmlinuz-{version}", staging / "vmlinuz")
        (staging / "version").write_text(version)
        if kernel.exists():
            shutil.rmtree(kernel)
        shutil.move(str(staging), kernel)


def _module_closure(moddir: Path, wanted) -> list[str]:
    """Module paths (relative to moddir) in load order: dependencies first."""
    deps = {}
    for line in (moddir / "modules.dep").read_text().splitlines():
        mod, _, rest = line.partition(":")
        deps[mod] = rest.split()
    by_name = {Path(m).name.removesuffix(".ko").replace("_", "-"): m for m in deps}
    order: list[str] = []

    def visit(m):
        if m in order:
            return
        for d in deps.get(m, []):
            visit(d)
        order.append(m)

    for name in wanted:
        key = name.replace("_", "-")
        if key not in by_name:
            raise VMError("modules", f"kernel module {name} not found in {moddir}")
        visit(by_name[key])
    return order


def _cpio(files: dict[str, tuple[bytes, int]]) -> bytes:
    """A newc cpio archive of ``{path: (data, mode)}`` with the directories it needs."""
    out = io.BytesIO()
    ino = 1
    dirs = sorted({str(Path(p).parents[i]) for p in files for i in range(len(Path(p).parents) - 1)})
    entries = [(d, b"", 0o040755) for d in dirs] + [(p, d, m) for p, (d, m) in files.items()]
    entries.append(("TRAILER!!!", b"", 0))
    for name, data, mode in entries:
        nb = name.encode() + b"\0"
        hdr = "070701" + "".join(f"{v:08X}" for v in (ino, mode, 0, 0, 1, 0, len(data), 0, 0, 0, 0, len(nb), 0))
        out.write(hdr.encode() + nb)
        out.write(b"\0" * (-(110 + len(nb)) % 4))
        out.write(data)
        out.write(b"\0" * (-len(data) % 4))
        ino += 1
    return out.getvalue()


def run(script: str, timeout_s: float = 600, memory_mb: int = 3072, cpus: int = 2) -> VMResult:
    """Boot the VM, run ``script`` (sh) in the host's root with vcan0 up, and return its output.

    The host's files are read-only in the guest; TMPDIR and HOME point into a tmpfs under /run.
    """
    vmlinuz, base, _ = prepare()
    with tempfile.TemporaryDirectory(dir=CACHE) as tmp:
        # the script travels in the initramfs; /init copies it to the guest's scratch tmpfs
        extra = _cpio({"cmd.sh": (script.encode(), 0o100755)})
        initrd = Path(tmp) / "initrd.gz"
        initrd.write_bytes(base.read_bytes() + gzip.compress(extra, compresslevel=1))
        cmd = ["qemu-system-x86_64", "-accel", "tcg", "-cpu", "max", "-m", str(memory_mb), "-smp", str(cpus),
               "-nographic", "-no-reboot", "-kernel", str(vmlinuz), "-initrd", str(initrd),
               "-append", "console=ttyS0 quiet panic=-1 rdinit=/init",
               "-virtfs", "local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap"]
        t0 = time.monotonic()
        console, returncode = _watch(cmd, timeout_s)
        total = time.monotonic() - t0
    fails = re.findall(r"OID_FAIL ([^\n]*)", console)
    if fails:
        raise VMError("guest setup", "; ".join(fails) + f"\nconsole tail:\n{console[-1500:]}")
    if BEGIN not in console:
        raise VMError("boot", f"the guest never reached the command (qemu rc {returncode});"
                              f" console tail:\n{console[-1500:]}")
    after = console.split(BEGIN, 1)[1]
    m = re.search(r"OID_RC=(\d+)", after)
    if not m:
        raise VMError("command", f"no exit status from the guest; console tail:\n{console[-1500:]}")
    output = after[: m.start()]
    boot_s = _boot_seconds(console, total)
    return VMResult(returncode=int(m.group(1)), output=output, console=console, boot_s=boot_s, total_s=total)


def _watch(cmd: list[str], timeout_s: float) -> tuple[str, int]:
    """Run qemu, collecting the serial console; a guest that does not reach the command within
    BOOT_TIMEOUT_S, or does not finish within ``timeout_s``, is killed and reported by step."""
    try:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                start_new_session=True)
    except FileNotFoundError:
        raise VMError("boot", "qemu-system-x86_64 not found (apt-get install qemu-system-x86)") from None
    chunks: list[bytes] = []

    def read():
        while data := proc.stdout.read1(65536):
            chunks.append(data)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    started = time.monotonic()
    try:
        while proc.poll() is None:
            time.sleep(0.2)
            elapsed = time.monotonic() - started
            if elapsed > BOOT_TIMEOUT_S and BEGIN.encode() not in b"".join(chunks):
                raise VMError("boot", f"the guest did not reach the command within {BOOT_TIMEOUT_S} s;"
                                      f" console tail:\n{_text(chunks)[-1500:]}")
            if elapsed > timeout_s:
                raise VMError("command", f"no end within {timeout_s:g} s; console tail:\n{_text(chunks)[-1500:]}")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        reader.join(timeout=5)
    return _text(chunks), proc.returncode


def _text(chunks: list[bytes]) -> str:
    return b"".join(chunks).decode(errors="replace").replace("\r", "")


def _boot_seconds(console: str, total: float) -> float:
    m = re.search(r"OID_BOOTED_AT=([0-9.]+)", console)
    return float(m.group(1)) if m else float("nan")
