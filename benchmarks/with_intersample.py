"""Run a benchmark with ``FilterConfig.intersample``'s default set to another intersample model (issue 36).

Run: python benchmarks/with_intersample.py KIND BENCHMARK.py [ARGS ...]

Until the default moves from "hold", the benchmarks build their estimators with it; this runs one of them with
KIND ("hold", "linear" or "cubic") instead, in this process: whatever it times in-process (the filter alone in
bench_fast.py, every figure of bench_tyres.py) then runs with KIND. A command it runs in a subprocess
(bench_fast.py's whole ``online-id estimate``) keeps the default.
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import _checkout  # noqa: F401 -- this checkout's online_id, not an installed copy

from online_id.filters.config import FilterConfig
from online_id.model.intersample import check_kind


def main() -> None:
    if len(sys.argv) < 3:
        sys.exit(__doc__.split("\n\n")[1])
    kind, script = check_kind(sys.argv[1]), Path(sys.argv[2])
    names = FilterConfig.__init__.__code__.co_varnames[1:FilterConfig.__init__.__code__.co_argcount]
    defaults = list(FilterConfig.__init__.__defaults__)
    defaults[names.index("intersample") - (len(names) - len(defaults))] = kind
    FilterConfig.__init__.__defaults__ = tuple(defaults)
    assert FilterConfig().intersample == kind
    print(f"(FilterConfig.intersample defaults to {kind!r} in this process)", flush=True)
    sys.argv = [str(script), *sys.argv[3:]]
    sys.path.insert(0, str(script.resolve().parent))
    runpy.run_path(str(script), run_name="__main__")


if __name__ == "__main__":
    main()
