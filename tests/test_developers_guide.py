"""docs/developers.md followed as a newcomer would (issue 37 item 5): each "Where new things go" recipe done here
and seen to reach the commands it promises, without touching the CLI.

- a new **model form** from another package: a toy effect (a yaw-rate gyro's scale-factor error, a term on an output
  channel, as an installed plug-in would ship it: an entry point of ``online_id.effects``) reaches ``simulate``,
  ``estimate``, ``listen`` (over udp_multicast, fed by ``replay``) and ``report`` (its diagnosis), each run as a
  user runs it, in its own process;
- a new **filter**: one ``FilterEntry`` in ``FILTERS`` and ``estimate --filter NAME`` takes it;
- a new **kind of source**: a ``SampleSource`` subclass with one hook and one ``OPENERS`` entry;
- a new **command**: one line in ``COMMANDS`` and a module with ``add_parser`` and ``run``;
- a new **vehicle**: a TOML file;
- and every registry the guide names by module exists there.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import random
import re
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import pytest

from online_id.cli.main import main

REPO = Path(__file__).resolve().parents[1]
GUIDE = REPO / "docs" / "developers.md"
#: The toy plug-in's simulated gyro scale error and how close the filters and the diagnosis must get to it (each
#: measured: estimate 0.0408 ± 0.0007, the diagnosis's fit 0.0411, listen as estimate's, on the 30 s run at 100 Hz).
SCALE, SCALE_TOLERANCE = 0.04, 0.004

TOY_EFFECT = '''
"""A yaw-rate gyro's scale-factor error, r_logged = (1 + k)·r: an effect shipped by another package."""
import numpy as np

from online_id.effects.base import Effect, ExtraState, FitParameter, parse_number
from online_id.model.lateral import N_STATES, OUTPUT_NAMES, R

_YAW = OUTPUT_NAMES.index("yaw_rate")


class YawRateScale(Effect):
    name = "yaw_rate_scale"
    stage = "sensor"
    syntax = "K: the gyro's scale-factor error, e.g. 0.04 (reads 4 % high)"
    example = "0.04"
    summary = "the yaw-rate gyro reads (1 + k) times the yaw rate"

    @classmethod
    def fit_parameters(cls):
        return [FitParameter("k", "-", initial=0.0, lower=-0.5, upper=0.5, scale=0.05)]

    @classmethod
    def parse(cls, text):
        return cls(k=parse_number(cls.name, text or "0", "K"))

    def measure(self, outputs, dt):
        out = outputs.copy()
        out[:, _YAW] *= 1.0 + self.values["k"]
        return out

    def block_means(self, outputs, context):
        return self.measure(outputs, context.block_dt)  # linear: a block mean scales as its samples

    def filter_states(self, known):
        coupling = np.zeros((len(OUTPUT_NAMES), N_STATES))
        coupling[_YAW, R] = 1.0  # r_logged = r + k·r
        return [ExtraState(group="effects", key=self.label, parameter="k", unit="-", prior_std=0.1,
                           random_walk=1e-5, initial=self.values["k"], output_state=tuple(map(tuple, coupling)))]
'''


def _plugin(root: Path, entry: str = "yaw_rate_scale = toy_gyro:YawRateScale") -> Path:
    """An installed package as importlib.metadata finds it: the module and its dist-info with the entry point."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "toy_gyro.py").write_text(textwrap.dedent(TOY_EFFECT))
    info = root / "toy_gyro-0.1.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-gyro\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[online_id.effects]\n{entry}\n")
    return root


def _cli(*args: str, plugin: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(plugin), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "online_id.cli.main", *args], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, env=env, timeout=timeout)


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    """The plug-in and a 30 s, 100 Hz chirp simulated with a gyro reading 4 % high (simulate takes the plug-in)."""
    root = tmp_path_factory.mktemp("toy")
    plugin = _plugin(root / "site")
    log = root / "run.csv"
    done = _cli("simulate", "--out", str(log), "--duration", "30", "--rate", "100", "--seed", "3",
                "--effect", f"yaw_rate_scale={SCALE}", plugin=plugin)
    assert done.returncode == 0, done.stderr
    assert "with effect yaw_rate_scale=0.04" in done.stdout, done.stdout
    return plugin, log


def _scale(result: dict) -> tuple[float, float]:
    k = result["effects"]["yaw_rate_scale"]["k"]
    return k["value"], k["std"]


def test_a_plugin_effect_reaches_estimate_and_the_report(toy_run, tmp_path):
    plugin, log = toy_run
    out = tmp_path / "est.json"
    done = _cli("estimate", str(log), "--effect", "yaw_rate_scale", "--json", str(out), plugin=plugin)
    assert done.returncode == 0, done.stderr
    k, std = _scale(json.loads(out.read_text()))
    assert abs(k - SCALE) < max(3 * std, SCALE_TOLERANCE), (k, std)
    assert "effect yaw_rate_scale k:" in done.stdout
    # the help lists it beside the built-in effects, from the registry
    listed = " ".join(_cli("estimate", "--help", plugin=plugin).stdout.split())
    assert "yaw_rate_scale (the yaw-rate gyro reads" in listed

    page, rep = tmp_path / "run.html", tmp_path / "rep.json"
    done = _cli("report", str(log), "--effects", "yaw_rate_scale", "--out", str(page), "--json", str(rep),
                plugin=plugin)
    assert done.returncode == 0, done.stderr
    diagnosis = json.loads(rep.read_text())["diagnose"]
    assert diagnosis["verdict"] == "yaw_rate_scale", diagnosis["verdict"]
    (found,) = diagnosis["effects"]
    assert found["significant"] and abs(found["parameters"]["k"] - SCALE) < SCALE_TOLERANCE, found
    assert diagnosis["carry"]["online"] == [f"yaw_rate_scale:{found['parameters']['k']:g}"]
    assert "yaw_rate_scale" in page.read_text(encoding="utf-8")


def test_a_plugin_effect_reaches_listen_over_a_bus(toy_run, tmp_path, monkeypatch, record_bus):
    from test_live import replay_and_listen

    plugin, log = toy_run
    monkeypatch.setenv("PYTHONPATH", str(plugin))  # the listener's and the player's processes
    port, group = random.randint(40000, 49000), f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    record_bus(f"udp_multicast:{group} port={port} (a plug-in effect estimated live, 30 s at 100 Hz, ×3)")
    live, _, _, listen_out = replay_and_listen(tmp_path, "udp_multicast", group, [f"port={port}"], log, speed=3.0,
                                               listen_args=("--effect", "yaw_rate_scale"))
    k, std = _scale(live)
    lost = live.get("lost_samples", 0)
    assert live["samples"] + lost >= 2900, live["samples"]
    assert abs(k - SCALE) < max(3 * std, SCALE_TOLERANCE), (k, std, listen_out[-2000:])


def test_a_broken_plugin_is_left_out_with_its_reason(tmp_path):
    plugin = _plugin(tmp_path / "site", entry="yaw_rate_scale = toy_gyro_missing:YawRateScale")
    done = _cli("estimate", "--help", plugin=plugin)
    assert done.returncode == 0, done.stderr
    assert "effect plug-in 'yaw_rate_scale' (toy_gyro_missing:YawRateScale): not loaded: ModuleNotFoundError" \
        in done.stderr, done.stderr
    assert "yaw_rate_scale" not in done.stdout
    clash = _plugin(tmp_path / "clash", entry="sensor_bias = toy_gyro:YawRateScale")
    done = _cli("simulate", "--help", plugin=clash)
    assert done.returncode == 0 and "'sensor_bias' (toy_gyro:YawRateScale, from toy-gyro): not loaded, the name is" \
        " taken" in done.stderr, done.stderr


def test_a_plugin_imported_before_online_id_still_joins(tmp_path, monkeypatch):
    """The plug-in's module imports online_id.effects itself: the search waits for the registry's first look."""
    plugin = _plugin(tmp_path / "site")
    code = ("import toy_gyro\nfrom online_id.effects import EFFECTS, DIAGNOSIS_CANDIDATES, parse_effect\n"
            "assert EFFECTS['yaw_rate_scale'] is toy_gyro.YawRateScale\n"
            "assert 'yaw_rate_scale' in DIAGNOSIS_CANDIDATES\nprint(parse_effect('yaw_rate_scale=0.1').values)")
    env = dict(os.environ, PYTHONPATH=str(plugin))
    done = subprocess.run([sys.executable, "-W", "error::UserWarning", "-c", code], capture_output=True, text=True,
                          env=env)
    assert done.returncode == 0 and "{'k': 0.1}" in done.stdout, done.stderr


# -- the registries in the process: a filter, a kind of source, a command, a vehicle ---------------------------------

@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    log = tmp_path_factory.mktemp("short") / "run.csv"
    assert main(["simulate", "--out", str(log), "--duration", "10", "--rate", "100", "--seed", "1"]) == 0
    return log


def _parameters(path: Path) -> dict:
    return {p: v["value"] for p, v in json.loads(path.read_text())["parameters"].items()}


def test_a_new_filter_is_one_registry_entry(short_run, tmp_path, monkeypatch):
    from online_id.filters import FILTERS, FilterEntry

    monkeypatch.setitem(FILTERS, "ekf_again", FilterEntry("online_id.filters.ekf:EKFEstimator"))
    ours, ref = tmp_path / "ours.json", tmp_path / "ref.json"
    assert main(["estimate", str(short_run), "--filter", "ekf_again", "--no-polish", "--quiet", "--json",
                 str(ours)]) == 0
    assert main(["estimate", str(short_run), "--no-polish", "--quiet", "--json", str(ref)]) == 0
    assert _parameters(ours) == _parameters(ref)
    # without a saturating-tyre form a tyre effect is a one-line error naming the filters that have one
    assert main(["estimate", str(short_run), "--filter", "ekf_again", "--effect", "tire_saturation"]) == 2


def test_a_new_kind_of_source_is_one_class_and_one_opener(short_run, tmp_path, monkeypatch, capsys):
    from online_id.drivers import sources
    from online_id.drivers.base import SampleSource

    from online_id.io.tracklog import read_track_run
    from online_id.stream.samples import samples_from_run

    class JsonLines(SampleSource):
        """One JSON object a line: the canonical names of a Sample."""

        def __init__(self, path):
            super().__init__()
            self.name, self._path = path.name, path

        def _samples(self):
            from online_id.stream.samples import Sample

            with self._path.open() as fh:
                for line in fh:
                    yield Sample(**json.loads(line))

        @property
        def channels(self):
            return ["yaw_rate", "roll_angle", "roll_rate", "lateral_acceleration"]

    lines = tmp_path / "run.jsonl"
    with lines.open("w") as fh:
        for s in samples_from_run(read_track_run(short_run)):
            fh.write(json.dumps({k: v for k, v in dataclasses.asdict(s).items() if v is not None}) + "\n")
    monkeypatch.setitem(sources.OPENERS, ".jsonl", lambda path, options: JsonLines(path))
    ours, ref = tmp_path / "ours.json", tmp_path / "ref.json"
    assert main(["estimate", str(lines), "--no-polish", "--quiet", "--json", str(ours)]) == 0
    assert main(["estimate", str(short_run), "--no-polish", "--quiet", "--json", str(ref)]) == 0
    got, want = _parameters(ours), _parameters(ref)
    assert all(np.isclose(got[p], want[p], rtol=1e-9) for p in want), (got, want)


def test_a_new_command_is_one_line_and_one_module(monkeypatch, capsys):
    from online_id.cli import main as cli_main

    module = types.ModuleType("online_id.cli.hello_cmd")

    def add_parser(sub):
        p = sub.add_parser("hello", description="say hello")
        p.add_argument("--name", default="world")
        p.set_defaults(run=run)

    def run(args) -> int:
        print(f"hello, {args.name}")
        return 0

    module.add_parser, module.run = add_parser, run
    monkeypatch.setitem(sys.modules, "online_id.cli.hello_cmd", module)
    monkeypatch.setattr(cli_main, "COMMANDS", (*cli_main.COMMANDS, ("hello", "hello_cmd", "say hello")))
    assert main(["hello", "--name", "track"]) == 0
    assert "hello, track" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "say hello" in capsys.readouterr().out


def test_a_new_vehicle_is_a_toml_file(short_run, tmp_path):
    from importlib import resources

    from online_id.vehicle.loader import builtin_vehicle_names

    text = (resources.files("online_id.vehicle") / "data" / "haro2008.toml").read_text(encoding="utf-8")
    assert "haro2008" in builtin_vehicle_names()
    car = tmp_path / "my_car.toml"
    car.write_text(text)
    out = tmp_path / "est.json"
    assert main(["estimate", str(short_run), "--vehicle", str(car), "--no-polish", "--quiet", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["vehicle"]


def test_every_registry_the_guide_names_is_where_it_says():
    """Each "`NAME` in `path.py`" (or "`NAME` (`path.py`") of the guide's recipes names a thing that module has."""
    text = " ".join(GUIDE.read_text(encoding="utf-8").split())
    section = text[text.index("## Where new things go"):text.index("## Stages and crash reports")]
    named = re.findall(r"`([A-Za-z_]\w*)`(?: in| \()\s*`((?:online_id|drivers|replay)/[\w/]+)\.py`", section)
    assert len(named) >= 6, named
    for name, path in named:
        parts = path.split("/")
        if parts[0] != "online_id":
            parts = ["online_id", *parts]  # drivers/, replay/ install as online_id.drivers, online_id.replay
        if parts[-1] == "__init__":
            parts = parts[:-1]
        module = importlib.import_module(".".join(parts))
        assert hasattr(module, name), f"docs/developers.md names {name} in {path}.py, which has no such thing"
