"""Start-up (issue 26): what a command imports before its first sample. Timings are the benchmark's
(benchmarks/bench_startup.py); these tests state what must not be imported, which no machine changes."""

from __future__ import annotations

import subprocess
import sys


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "; import sys; print('\\n'.join(sys.modules))"],
                         capture_output=True, text=True, check=True).stdout
    return set(out.split())


def test_the_filters_import_no_scipy_stats_and_no_other_part_of_filterpy():
    loaded = _modules_after("import online_id.filters.ekf, online_id.filters.ukf, online_id.filters.tyre_filters")
    assert "filterpy.kalman" in loaded
    unwanted = {"scipy.stats", "scipy.ndimage", "filterpy.monte_carlo", "filterpy.discrete_bayes",
                "filterpy.stats.stats", "matplotlib", "pandas", "dask", "asammdf"}
    assert not unwanted & loaded, unwanted & loaded


def test_filterpy_stays_whole_for_code_that_uses_it():
    """The stand-ins (online_id/filters/_filterpy.py) hand on filterpy's own objects when they are used."""
    code = ("import online_id.filters.ekf, numpy as np, filterpy, filterpy.stats as s, filterpy.stats.stats as real;"
            "from filterpy.stats import multivariate_gaussian; from filterpy.monte_carlo import systematic_resample;"
            "assert s.logpdf(1.0, 0.0, 1.0) == real.logpdf(1.0, 0.0, 1.0);"
            "assert multivariate_gaussian is real.multivariate_gaussian;"
            "assert filterpy.gh.GHFilter.__module__ == 'filterpy.gh.gh_filter';"
            "assert filterpy.__version__.count('.') >= 1;"
            "from filterpy.kalman import ExtendedKalmanFilter as E; k = E(2, 1); k.x = np.zeros((2, 1));"
            "k.update(np.array([[1.0]]), lambda x: np.array([[1.0, 0.0]]), lambda x: x[:1]);"
            "assert np.isfinite(k.log_likelihood)")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_filterpy_imported_first_is_left_as_it_is():
    code = ("import filterpy, filterpy.stats, online_id.filters.ekf, sys; import filterpy.stats.stats as real;"
            "assert type(sys.modules['filterpy']).__name__ == 'module';"
            "assert filterpy.stats.logpdf is real.logpdf")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_the_filter_registry_imports_no_filter():
    """``online_id.filters`` names its filters (FILTERS, for the CLI's --filter choices) and imports each on use."""
    loaded = _modules_after("import online_id.filters; online_id.filters.FILTERS['ekf']")
    assert not {"filterpy", "numpy", "online_id.filters.ekf", "online_id.filters.base"} & loaded, loaded
    loaded = _modules_after("from online_id.filters import EKFEstimator")
    assert "online_id.filters.ekf" in loaded and "online_id.filters.ukf" not in loaded


def test_the_cli_imports_no_filter_library_before_a_command_runs():
    loaded = _modules_after("import online_id.cli.main")
    assert not {"filterpy", "scipy", "numba", "matplotlib", "pandas", "dask"} & loaded, \
        {"filterpy", "scipy", "numba", "matplotlib", "pandas", "dask"} & loaded


def test_a_command_imports_its_own_module_only_and_the_version_no_numpy():
    """The parser names every command (``--help`` lists them) and imports a command's module when it is chosen."""
    loaded = _modules_after("from online_id.cli.main import build_parser; build_parser().parse_args(['simulate', "
                            "'--out', 'x.csv'])")
    commands = {m for m in loaded if m.startswith("online_id.cli.") and m.endswith("_cmd")}
    assert commands == {"online_id.cli.simulate_cmd"}, commands
    loaded = _modules_after("from online_id.cli.main import build_parser; build_parser()")
    assert not {m for m in loaded if m.endswith("_cmd")} and "numpy" not in loaded


def test_the_help_lists_every_command_with_the_line_of_commands():
    from online_id.cli.main import COMMANDS

    out = subprocess.run([sys.executable, "-m", "online_id.cli.main", "--help"], capture_output=True, text=True,
                         check=True, env={"COLUMNS": "400", "PATH": ""}).stdout
    for name, _, line in COMMANDS:
        assert f"    {name}" in out and line in out, name


def test_a_command_imported_late_writes_to_the_stdout_of_its_run(monkeypatch):
    """A command's module is imported when the command first runs (above), maybe while another stream is
    sys.stdout (a test's capture, a caller's redirect) that is closed by the next run: listen's live table
    bound that stream at import, and the next listen ended on "I/O operation on closed file" (exit 70)."""
    import importlib
    import io

    from online_id.cli import listen_cmd

    then = io.StringIO()
    monkeypatch.setattr(sys, "stdout", then)
    importlib.reload(listen_cmd)  # imported while `then` is stdout
    then.close()
    now = io.StringIO()
    monkeypatch.setattr(sys, "stdout", now)
    table = listen_cmd._LiveTable(1.0)
    assert table.stream is now and table.tty is False
