"""The ``online-id`` command: simulate, and errors as one line with a non-zero exit."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from online_id.cli.main import main
from online_id.io.tracklog import read_track_run


def test_simulate_writes_a_readable_run(tmp_path, capsys):
    out = tmp_path / "run.csv"
    rc = main(["simulate", "--out", str(out), "--duration", "3", "--rate", "200", "--speed-kmh", "60",
               "--maneuver", "step", "--truth", "constructor", "--seed", "4"])
    assert rc == 0
    run = read_track_run(out)
    assert len(run) == 600 and np.allclose(run.speed, 60 / 3.6)
    assert run.meta["truth_name"] == "constructor" and run.meta["seed"] == 4
    assert "wrote" in capsys.readouterr().out


def test_same_seed_same_run_other_seed_other_noise(tmp_path):
    paths = []
    for i, seed in enumerate((1, 1, 2)):
        paths.append(tmp_path / f"r{i}.csv")
        assert main(["simulate", "--out", str(paths[-1]), "--duration", "1", "--seed", str(seed)]) == 0
    a, b, c = (read_track_run(p).yaw_rate for p in paths)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "online_id.cli.main", *args], capture_output=True, text=True,
                          cwd=cwd, stdin=subprocess.DEVNULL, timeout=120)


def test_user_errors_are_one_line_without_traceback(tmp_path):
    bad = tmp_path / "car.toml"
    bad.write_text('name = "x"\n[known]\nM = -3\n')
    for args, needle in [
        (["simulate", "--out", "r.csv", "--vehicle", str(bad)], "missing key known.ms"),
        (["simulate", "--out", "r.csv", "--truth", "nope"], "no parameter set named 'nope'"),
        (["simulate", "--out", "nofolder/r.csv"], "does not exist"),
        (["simulate", "--out", "r.csv", "--speed-kmh", "0"], "--speed-kmh must be positive"),
    ]:
        res = _cli(*args, cwd=tmp_path)
        assert res.returncode == 2, res
        assert "Traceback" not in res.stderr
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("online-id: error:") and needle in lines[0], res.stderr
