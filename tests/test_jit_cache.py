"""online_id.util.jit: the package's compiled functions are cached in the user's cache directory (never beside
the source: issue 40), load from it without numba's compile-time set-up (issue 26: start-up), run the same
code, still compile where the cache has nothing or no cache can be written, and say once that they compile."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np

MODULE = textwrap.dedent('''
    import numpy as np
    from online_id.util.jit import cached_njit

    @cached_njit()
    def solve(A, b):
        return np.linalg.solve(A, b) * 2.0 + np.sum(A)

    @cached_njit()
    def put_row(a, b):
        a[0, :] = b
        return a
''')

CALL = textwrap.dedent('''
    import sys, numpy as np
    from online_id.util import first_compile
    first_compile.listen(lambda line: print("NOTICE " + line, file=sys.stderr))
    import mod
    A = np.array([[4.0, 1.0], [2.0, 3.0]])
    print(repr(mod.solve(A, np.array([1.0, 2.0])).tolist()))
    print(int("numba.cpython.setobj" in sys.modules))  # a registry only numba's compile-time set-up imports
    if len(sys.argv) > 1:  # a signature the cache lacks: numba's own path compiles it
        print(repr(mod.solve(np.array([[4.0, 1.0], [2.0, 3.0]], dtype=np.float32), np.ones(2, np.float32)).tolist()))
''')


def _run(tmp_path, *extra, code=CALL, **env_extra):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    env.update({"XDG_CACHE_HOME": str(tmp_path / "cache"), **env_extra})
    for name in ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT"):
        if name not in env_extra:
            env.pop(name, None)
    done = subprocess.run([sys.executable, "-c", code, *extra], cwd=tmp_path, env=env, capture_output=True,
                          text=True, check=True)
    return done.stdout.split("\n"), [line for line in done.stderr.splitlines() if line.startswith("NOTICE")]


def _cache_files(folder):
    return sorted(p.name for p in folder.rglob("*") if p.suffix in (".nbi", ".nbc"))


def test_a_cached_function_loads_without_numbas_compile_set_up_and_gives_the_same_result(tmp_path):
    (tmp_path / "mod.py").write_text(MODULE)
    compiled, notices = _run(tmp_path)  # compiles, writes the cache (in the user cache directory)
    assert compiled[1] == "1"  # compiling needs numba's registries
    assert len(notices) == 1 and "once" in notices[0], notices  # said once, however many functions compile
    assert any(name.startswith("mod.solve-") for name in _cache_files(tmp_path / "cache" / "online-id" / "numba"))
    assert not (tmp_path / "__pycache__").exists() or not _cache_files(tmp_path / "__pycache__")  # not beside it
    loaded, notices = _run(tmp_path, "new signature")
    assert loaded[0] == compiled[0]  # the same machine code: the same bits
    assert loaded[1] == "0"  # loaded from the cache without numba's registries
    assert eval(loaded[0]) == [10.2, 11.2]  # solve: (0.1, 0.6); · 2 + sum(A)
    assert np.allclose(eval(loaded[2]), [10.4, 10.4])  # float32: compiled by numba's own path, after the load
    assert len(notices) == 1  # the new signature compiled: said once; a run that only loads says nothing
    assert _run(tmp_path)[1] == []


def test_numbas_cache_dir_is_honoured(tmp_path):
    (tmp_path / "mod.py").write_text(MODULE)
    _run(tmp_path, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    assert any(name.startswith("mod.solve-") for name in _cache_files(tmp_path / "numba-cache"))
    assert not (tmp_path / "cache").exists() or not _cache_files(tmp_path / "cache")


def test_without_a_writable_cache_directory_the_functions_compile_in_each_run_and_say_so(tmp_path):
    (tmp_path / "mod.py").write_text(MODULE)
    (tmp_path / "a-file").write_text("")
    for _ in range(2):
        out, notices = _run(tmp_path, XDG_CACHE_HOME=str(tmp_path / "a-file" / "cache"))  # cannot be made
        assert eval(out[0]) == [10.2, 11.2] and out[1] == "1"  # compiled, both times
        assert len(notices) == 1 and "every run compiles again" in notices[0], notices
    assert not _cache_files(tmp_path)


def test_a_slice_of_another_shape_still_raises_valueerror_after_the_first_compile(tmp_path):
    """The package's first compile gives numba's plain message for a slice assigned from an array of another
    shape (its shaped message's string code was a third of the first run's compile); the error is the same."""
    (tmp_path / "mod.py").write_text(MODULE)
    code = textwrap.dedent('''
        import numpy as np, mod
        print(mod.put_row(np.zeros((2, 3)), np.ones(3)).tolist())
        try:
            mod.put_row(np.zeros((2, 3)), np.ones(4))
        except ValueError as exc:
            print("ValueError", exc)
    ''')
    out, _ = _run(tmp_path, code=code)
    assert out[0] == "[[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]]"
    assert out[1] == "ValueError cannot assign slice from input of different size"


def test_the_cli_says_a_compile_is_starting_except_under_quiet(tmp_path, capsys):
    from online_id.cli import main as cli
    from online_id.util import first_compile

    missing = str(tmp_path / "missing.csv")
    try:
        assert cli.main(["estimate", missing, "--quiet"]) == 2  # (no such log: ends before anything runs)
        assert first_compile._listener is None
        assert cli.main(["estimate", missing]) == 2
        assert first_compile._listener is cli._note_compiling
        capsys.readouterr()
        cli._note_compiling("compiling numerical code for this machine, once")
        out, err = capsys.readouterr()
        assert out == "" and err == "online-id: note: compiling numerical code for this machine, once\n"
    finally:
        first_compile.listen(None)


def test_every_module_with_compiled_code_is_covered_by_the_cache_stamp():
    """A cached function carries the code of the compiled functions it calls in other modules, and numba stamps its
    entry by its own file alone: each entry's stamp also holds a digest of every module with compiled code
    (online_id/util/jit.py ``COMPILED_MODULES``). A module with a compiled function left off the list would let an
    edit to it run stale code in its callers."""
    from pathlib import Path

    import online_id
    from online_id.util.jit import COMPILED_MODULES

    root = Path(online_id.__file__).parent
    with_code = {p.relative_to(root).as_posix() for p in root.rglob("*.py") if "@cached_njit" in p.read_text()}
    assert with_code == set(COMPILED_MODULES)


def test_the_stamp_changes_with_a_compiled_module_and_with_nothing_else(tmp_path):
    from online_id.util.jit import COMPILED_MODULES, sources_digest

    for name in COMPILED_MODULES:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(f"# {name}\n")
    (tmp_path / "cli.py").write_text("# no compiled code\n")
    before = sources_digest(str(tmp_path))
    sources_digest.cache_clear()
    (tmp_path / "cli.py").write_text("# an edit elsewhere\n")
    assert sources_digest(str(tmp_path)) == before
    sources_digest.cache_clear()
    (tmp_path / COMPILED_MODULES[-1]).write_text("# a callee edited\n")
    assert sources_digest(str(tmp_path)) != before
    sources_digest.cache_clear()


def test_a_cached_functions_stamp_holds_the_compiled_sources_digest():
    from online_id.filters import block_close
    from online_id.util import jit

    assert jit._FUNCTION_CACHE is not None  # (the numba the project installs has the parts)
    func = block_close.listen.py_func
    locator = jit._FUNCTION_CACHE._impl_class._locator_classes[0](func, func.__code__.co_filename)
    stamp = locator.get_source_stamp()
    assert stamp[1] == jit.sources_digest() and len(stamp[1]) == 64


ONE_TYPE = textwrap.dedent('''
    import sys, warnings
    from dataclasses import replace
    from online_id.effects import parse_effect_to_estimate
    from online_id.estimation import make_estimator, run_estimator
    from online_id.filters import block_close, kinematics
    from online_id.stream.samples import SampleArrays, samples_from_run
    sys.path.insert(0, sys.argv[1])
    from test_array_path import CAR, _damaged_run
    damaged = _damaged_run()  # NaNs (a sample's own mask), a spike, gaps, a stop
    no_roll = replace(damaged, roll_angle=None, roll_rate=None)  # channels absent (a pattern's shared mask)
    warnings.simplefilter("ignore")
    tyres = dict(effects=[parse_effect_to_estimate("tire_saturation")])
    for run in (damaged, no_roll):
        for options in ({}, tyres):  # the linear EKF and the tyre EKF, in one process
            run_estimator(make_estimator(CAR, "ekf", **options), list(samples_from_run(run)))  # sample by sample
            run_estimator(make_estimator(CAR, "ekf", **options), SampleArrays.from_run(run))  # the array path
    for module in (block_close, kinematics):
        for name, fn in vars(module).items():
            if hasattr(fn, "signatures") and fn.signatures:
                print(module.__name__.rsplit(".", 1)[1], name, len(fn.signatures))
''')


def test_a_filters_compiled_calls_take_one_type_of_array_each_so_a_first_run_compiles_each_once(tmp_path):
    """Issue 40, the first run: numba compiles a function once for each type of array it is given, writable and
    read-only, contiguous and strided apart (a compile of close_block is 3 s). The EKF warms its block close for
    the masks it passes (block_close.compile_now, compile_close): every mask it passes is read-only, every
    variance vector a contiguous copy, the kinematic sums' columns contiguous, whether the samples are complete,
    a sample has a missing value or a channel is absent, sample by sample or on the array path (the damaged run
    of tests/test_array_path.py, with and without its roll channels; the linear and the tyre EKF in one
    process). A second type of either would show as a second signature."""
    out = subprocess.run([sys.executable, "-c", ONE_TYPE, os.path.dirname(__file__)], capture_output=True, text=True,
                         timeout=600, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    counts = {" ".join(line.split()[:2]): int(line.split()[2]) for line in out.stdout.splitlines()
              if line.startswith(("block_close ", "kinematics "))}
    for name in ("close_block", "accept_group", "book_block", "book_adapt_listen", "_running_sums"):
        assert any(k.endswith(" " + name) for k in counts), (name, counts)
    assert all(n == 1 for n in counts.values()), counts
