"""online_id.util.jit: the package's compiled functions load from numba's cache without numba's compile-time
set-up (issue 26: start-up), run the same code, and still compile where the cache has nothing."""

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
''')

CALL = textwrap.dedent('''
    import sys, numpy as np, mod
    A = np.array([[4.0, 1.0], [2.0, 3.0]])
    print(repr(mod.solve(A, np.array([1.0, 2.0])).tolist()))
    print(int("numba.cpython.setobj" in sys.modules))  # a registry only numba's compile-time set-up imports
    if len(sys.argv) > 1:  # a signature the cache lacks: numba's own path compiles it
        print(repr(mod.solve(np.array([[4.0, 1.0], [2.0, 3.0]], dtype=np.float32), np.ones(2, np.float32)).tolist()))
''')


def _run(tmp_path, *extra):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("NUMBA_DISABLE_JIT", None)
    out = subprocess.run([sys.executable, "-c", CALL, *extra], cwd=tmp_path, env=env, capture_output=True,
                         text=True, check=True).stdout.split("\n")
    return out


def test_a_cached_function_loads_without_numbas_compile_set_up_and_gives_the_same_result(tmp_path):
    (tmp_path / "mod.py").write_text(MODULE)
    compiled = _run(tmp_path)  # compiles, writes the cache (beside mod.py)
    assert compiled[1] == "1"  # compiling needs numba's registries
    assert list((tmp_path / "__pycache__").glob("mod.solve-*.nbi"))
    loaded = _run(tmp_path, "new signature")
    assert loaded[0] == compiled[0]  # the same machine code: the same bits
    assert loaded[1] == "0"  # loaded from the cache without numba's registries
    assert eval(loaded[0]) == [10.2, 11.2]  # solve: (0.1, 0.6); · 2 + sum(A)
    assert np.allclose(eval(loaded[2]), [10.4, 10.4])  # float32: compiled by numba's own path, after the load
