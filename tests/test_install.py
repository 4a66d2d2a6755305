"""Installing, running, uninstalling and installing editable in one environment, as a user does (issue 40).

numba's cache used to land beside the installed source (``site-packages/online_id/**/__pycache__/*.nbi``):
``pip uninstall`` left those files in an ``online_id/`` folder without ``__init__.py``, and a later ``pip
install -e .`` into the same environment imported that folder instead of the checkout (``ImportError:
cannot import name '__version__' from 'online_id' (unknown location)``). Now the cache is in the user's
cache directory (online_id/util/jit.py).

The environment is a fresh venv made here. It sees the suite's own packages (numpy, numba, pip,
setuptools, ...) but not online-id's, and builds with ``--no-build-isolation --no-index --no-deps``: no
network. Its cache directory is this test's (``XDG_CACHE_HOME``), so the run compiles as a first run does.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
#: What the wheel is built from (pyproject.toml's packages and readme).
SOURCES = ("pyproject.toml", "README.md", "online_id", "drivers", "replay", "deprecated")
#: The suite environment's entries that are online-id itself: the fresh venv must not see them.
OWN = ("online_id", "drivers", "replay")
#: The old top-level names (issue 37): installed as one-file shims for one release, the code in online_id.
SHIMS = ("drivers", "replay")


def _suite_packages(into: Path) -> Path:
    """A folder of links to the suite environment's installed packages, online-id's own left out."""
    into.mkdir()
    for site in {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}:
        for entry in Path(site).iterdir():
            name = entry.name.lower()
            if (entry.name in OWN or name.startswith(("online_id-", "online_id.", "__editable__"))
                    or "online_id" in name or (into / entry.name).exists()):
                continue
            (into / entry.name).symlink_to(entry)
    return into


def _run(args, env, **kw):
    done = subprocess.run(args, env=env, capture_output=True, text=True, timeout=900, **kw)
    assert done.returncode == 0, f"{args}: {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done


def _numba_cache_files(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.suffix in (".nbi", ".nbc")] if folder.exists() else []


def test_install_run_uninstall_then_install_editable_in_the_same_venv(tmp_path):
    import setuptools

    if tuple(int(x) for x in setuptools.__version__.split(".")[:2]) < (70, 1):
        pytest.fail(f"setuptools {setuptools.__version__}: the test extra asks for >= 70.1 (its own bdist_wheel,"
                    " to build without network): pip install -e '.[test]'")
    src = tmp_path / "src"  # a copy: building writes build/ and *.egg-info into the source folder
    src.mkdir()
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nb[ic]"))
        else:
            shutil.copy2(path, src / name)
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    bin_dir = venv / ("Scripts" if os.name == "nt" else "bin")
    python = bin_dir / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     dict(os.environ)).stdout.strip())
    packages = _suite_packages(tmp_path / "suite-packages")
    (site / "suite-packages.pth").write_text(f"import site; site.addsitedir({str(packages)!r})\n")

    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "PYTHON", "VIRTUAL_ENV"))}
    env.update(XDG_CACHE_HOME=str(tmp_path / "cache"), PIP_NO_INPUT="1", OMP_NUM_THREADS="1")
    pip = [str(python), "-m", "pip", "--disable-pip-version-check", "-q"]
    install = [*pip, "install", "--no-deps", "--no-build-isolation", "--no-index"]
    imports = [str(python), "-c", "import online_id; print(online_id.__version__); print(online_id.__file__)"]

    _run([*install, str(src)], env, cwd=tmp_path)  # 1. installed as a user installs it (a wheel, copied in)
    package = site / "online_id"
    assert (package / "__init__.py").exists()
    for shim in SHIMS:  # drivers/ and replay/ install inside online_id; their old names are one file each
        assert sorted(p.name for p in (site / shim).iterdir() if p.name != "__pycache__") == ["__init__.py"], shim
        assert (package / shim / "__init__.py").exists(), shim
    moved = ("import warnings, online_id.drivers.sources as s, online_id.replay.player as p\n"
             "assert (s.__name__, p.__name__) == ('online_id.drivers.sources', 'online_id.replay.player')\n"
             "with warnings.catch_warnings(record=True) as seen:\n"
             "    warnings.simplefilter('always')\n"
             "    import drivers.sources, replay.player\n"
             "assert drivers.sources is s and replay.player is p\n"
             "assert [w.category for w in seen] == [DeprecationWarning] * 2, seen\n")
    _run([str(python), "-c", moved], env, cwd=tmp_path)
    run = [str(bin_dir / "online-id"), "simulate", "--duration", "0.2", "--out", str(tmp_path / "run.csv")]
    first = _run(run, env, cwd=tmp_path)  # 2. run: its first compile
    notes = [line for line in first.stderr.splitlines() if "compiling" in line]
    assert len(notes) == 1 and notes[0].startswith("online-id: note: compiling numerical code"), first.stderr
    assert "compiling" not in first.stdout
    again = _run(run, env, cwd=tmp_path)
    assert "compiling" not in again.stderr, again.stderr  # loaded from the cache: nothing to say
    assert _numba_cache_files(tmp_path / "cache" / "online-id" / "numba")
    assert not _numba_cache_files(package), _numba_cache_files(package)  # nothing inside the installed package

    _run([*pip, "uninstall", "-y", "online-id"], env, cwd=tmp_path)  # 3. uninstalled: nothing left behind
    assert not package.exists(), sorted(str(p) for p in package.rglob("*"))
    gone = subprocess.run(imports, env=env, capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert gone.returncode != 0 and "No module named 'online_id'" in gone.stderr, gone.stdout + gone.stderr

    _run([*install, "-e", str(src)], env, cwd=tmp_path)  # 4. editable, in the same venv
    version, where = _run(imports, env, cwd=tmp_path).stdout.split()  # 5. imports the checkout
    assert version and Path(where) == src / "online_id" / "__init__.py", where
    assert _run([str(bin_dir / "online-id"), "--version"], env, cwd=tmp_path).stdout.startswith("online-id ")


def test_every_package_folder_is_listed_in_pyproject():
    """pyproject.toml lists its packages (the drivers/ and replay/ folders install as online_id.drivers and
    online_id.replay through package-dir): a new folder with an __init__.py must be listed, or the wheel leaves
    it out."""
    import tomllib

    setup = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    where = {name: REPO / setup.get("package-dir", {}).get(name, name.replace(".", "/")) for name in setup["packages"]}
    assert all((folder / "__init__.py").exists() for folder in where.values()), where
    listed = {folder.resolve() for folder in where.values()}
    for top in ("online_id", "drivers", "replay", "deprecated"):
        for init in (REPO / top).rglob("__init__.py"):
            assert init.parent.resolve() in listed, f"{init.parent.relative_to(REPO)} is not in pyproject's packages"
