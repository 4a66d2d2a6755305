"""The README's main command (``online-id estimate``) the first time after installing, against a warm run
(issue 40: the first run within 2x the warm one).

Run: python benchmarks/bench_first_run.py [--repeat 3] [--source CHECKOUT]

The checkout (this one, or ``--source``, e.g. an older one for a before-and-after) is installed as a user
installs it, ``pip install .`` (a wheel, non-editable, pip compiling the bytecode), into a fresh venv that
sees this environment's packages (numpy, numba, ...) but not online-id's: no network. Then, ``--repeat``
times, a first run with nothing compiled (an empty user cache directory, ``XDG_CACHE_HOME``, and no numba
cache files left inside the installed package, where the code before issue 40 wrote them) followed by a
warm run (the cache the first run wrote). Printed: each run's wall and CPU time (user + system, which a busy
machine disturbs less), the medians and their ratio, and which compiled functions the first run wrote to
the cache (what the command compiled).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

import _checkout
from _timing import timed

ROOT = Path(_checkout.ROOT)
TARGET_RATIO = 2.0  # issue 40: the first run within 2x the warm run
SOURCES = ("pyproject.toml", "README.md", "online_id", "drivers", "replay", "deprecated")
OWN = ("online_id", "drivers", "replay")


def install(source: Path, tmp: Path) -> tuple[Path, Path]:
    """``source`` installed (non-editable) into a fresh venv in ``tmp``: (its bin folder, the package)."""
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        path = source / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nb[ic]"))
        else:
            shutil.copy2(path, src / name)
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    links = tmp / "suite-packages"
    links.mkdir()
    for where in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        for entry in Path(where).iterdir():
            if entry.name in OWN or "online_id" in entry.name.lower() or (links / entry.name).exists():
                continue
            (links / entry.name).symlink_to(entry)
    (site / "suite-packages.pth").write_text(f"import site; site.addsitedir({str(links)!r})\n")
    subprocess.run([str(python), "-m", "pip", "-q", "install", "--no-deps", "--no-build-isolation", "--no-index",
                    str(src)], check=True, cwd=tmp)
    return venv / "bin", site / "online_id"


def forget_compiled(package: Path) -> None:
    """Remove numba cache files from inside the installed package (where the code before issue 40 wrote)."""
    for path in package.rglob("*"):
        if path.suffix in (".nbi", ".nbc"):
            path.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--source", type=Path, default=ROOT, help="the checkout to install (default: this one)")
    args = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "PYTHON", "VIRTUAL_ENV"))}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        bin_dir, package = install(args.source.resolve(), tmp)
        cmd = [str(bin_dir / "online-id"), "estimate"]
        first, warm, compiled = [], [], []
        for k in range(args.repeat):
            cache = tmp / f"cache-{k}"
            run_env = dict(env, XDG_CACHE_HOME=str(cache))
            forget_compiled(package)
            first.append(timed(cmd, run_env, tmp))
            warm.append(timed(cmd, run_env, tmp))
            print(f"run {k + 1}: first {first[-1][0]:6.2f} s (CPU {first[-1][1]:6.2f} s), warm {warm[-1][0]:6.2f} s"
                  f" (CPU {warm[-1][1]:6.2f} s)", flush=True)
            compiled = sorted({p.name.split("-")[0] for p in [*cache.rglob("*.nbi"), *package.rglob("*.nbi")]})
    f_wall, f_cpu = statistics.median(w for w, _ in first), statistics.median(c for _, c in first)
    w_wall, w_cpu = statistics.median(w for w, _ in warm), statistics.median(c for _, c in warm)
    print(f"source: {args.source}")
    print(f"compiled by the first run ({len(compiled)}): {', '.join(compiled)}")
    print(f"{'online-id estimate':<22} {'wall':>8} {'CPU':>8}")
    print(f"{'first after install':<22} {f_wall:>7.2f}s {f_cpu:>7.2f}s")
    print(f"{'warm':<22} {w_wall:>7.2f}s {w_cpu:>7.2f}s")
    print(f"{'first ÷ warm':<22} {f_wall / w_wall:>8.2f} {f_cpu / w_cpu:>8.2f}   (medians of {args.repeat}; target"
          f" {TARGET_RATIO:g}x: {'met' if f_wall / w_wall <= TARGET_RATIO else 'not met'})")


if __name__ == "__main__":
    main()
