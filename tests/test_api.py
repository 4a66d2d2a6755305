"""The Python API: online_id.estimate / fit / diagnose on a DataFrame give the CLI's numbers; importing
online_id stays cheap."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import online_id
from online_id.cli.main import main
from online_id.errors import OnlineIdError
from online_id.io.tracklog import write_track_run
from online_id.sim.simulator import simulate
from online_id.vehicle import PARAMETER_NAMES, load_vehicle

#: The API and the CLI must agree within this (relative; the issue's 0.1 %). The CLI reads a CSV written
#: with 10 significant digits, the API the DataFrame's full floats.
SAME = 1e-3


@pytest.fixture(scope="module")
def run():
    car = load_vehicle("haro2008")
    return simulate(car, car.truth("track"), duration_s=6.0, rate_hz=200.0, seed=21).run


@pytest.fixture(scope="module")
def frame(run):
    return pd.DataFrame({c: getattr(run, c) for c in run.channels})


def cli_params(path):
    data = json.loads(path.read_text())
    return np.array([data["parameters"][n]["value"] for n in PARAMETER_NAMES])


def api_params(result):
    return np.array([result.parameters[n].value for n in PARAMETER_NAMES])


def test_import_online_id_loads_neither_drivers_nor_pandas():
    code = ("import sys, online_id; heavy = [m for m in ('online_id.drivers', 'drivers', 'pandas', 'scipy', 'can',"
            " 'asammdf', 'online_id.api') if m in sys.modules]; print(','.join(heavy));"
            " assert callable(online_id.estimate)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", out.stdout


def test_every_name_of_the_api_is_importable_from_online_id():
    """``online_id.X`` for every X in ``online_id.api.__all__`` (``online_id.Value`` raised AttributeError), and
    ``dir(online_id)`` lists them."""
    import online_id.api

    for name in online_id.api.__all__:
        assert getattr(online_id, name) is getattr(online_id.api, name), name
        assert name in dir(online_id), name
    assert sorted(online_id._API) == sorted(online_id.api.__all__)


def test_estimate_on_a_dataframe_gives_the_cli_numbers(tmp_path, run, frame, capsys):
    csv = write_track_run(run, tmp_path / "run.csv")
    for channels in (None, ["yaw_rate", "lateral_acceleration"]):
        argv = ["estimate", str(csv), "--quiet", "--json", str(tmp_path / "cli.json")]
        if channels:
            argv += ["--channels", ",".join(channels)]
        assert main(argv) == 0
        est = online_id.estimate(frame, vehicle="haro2008", filter="ekf", channels=channels)
        np.testing.assert_allclose(api_params(est), cli_params(tmp_path / "cli.json"), rtol=SAME)
        cli_std = json.loads((tmp_path / "cli.json").read_text())["parameters"]["Mzz"]["std"]
        assert est.parameters["Mzz"].std == pytest.approx(cli_std, rel=SAME)
    capsys.readouterr()
    hist = est.to_dataframe()
    assert len(hist) > 100 and list(hist.columns[:3]) == ["time", "Mzz", "Mzz_std"]
    data = json.loads(est.to_json(tmp_path / "api.json"))
    # the history is the online filter's; the final estimate is its batch polish (the CLI's default too)
    assert hist["Mzz"].iloc[-1] == pytest.approx(data["online"]["parameters"]["Mzz"]["value"])
    assert data["channels"] == ["yaw_rate", "lateral_acceleration"]
    assert json.loads((tmp_path / "api.json").read_text())["samples"] == len(run)


def test_estimate_takes_a_path_in_any_format_and_a_fit_as_prior(tmp_path, run, frame):
    import can
    from online_id.drivers.frames import frames_from_run

    blf = tmp_path / "run.blf"
    with can.Logger(str(blf)) as w:
        for m in frames_from_run(run):
            w.on_message_received(m)
    from_log = online_id.estimate(blf, signals="online_id")
    from_frame = online_id.estimate(frame)  # one run, one answer: a CAN log is polished as a table is
    assert from_log.result.polish is not None and "error" not in from_log.result.polish
    np.testing.assert_allclose(api_params(from_log), api_params(from_frame), rtol=1e-6)
    assert from_log.result.source_report["frames"]["samples"] == len(run)
    fit = online_id.fit(frame, generations=3, groups=2)
    assert len(fit.to_dataframe()) == 3 and set(fit.parameters) == set(PARAMETER_NAMES)
    started = online_id.estimate(frame, prior=fit)
    assert started.result.prior.to_vector() == pytest.approx(api_params(fit))


def test_fit_and_diagnose_on_a_dataframe_give_the_cli_numbers(tmp_path, run, frame, capsys):
    csv = write_track_run(run, tmp_path / "run.csv")
    assert main(["fit", str(csv), "--generations", "3", "--groups", "2", "--quiet",
                 "--json", str(tmp_path / "fit.json")]) == 0
    fit = online_id.fit(frame, generations=3, groups=2)
    np.testing.assert_allclose(api_params(fit), cli_params(tmp_path / "fit.json"), rtol=SAME)
    assert main(["diagnose", str(csv), "--validate", str(csv), "--effects", "sensor_bias", "--quiet",
                 "--json", str(tmp_path / "d.json")]) == 0
    d = online_id.diagnose(frame, validate=frame, effects=["sensor_bias"])
    cli = json.loads((tmp_path / "d.json").read_text())
    assert d.verdict == cli["verdict"]
    np.testing.assert_allclose(api_params(d), [cli["base_model"]["parameters"][n] for n in PARAMETER_NAMES],
                               rtol=SAME)
    table = d.to_dataframe()
    assert len(table) == 1 and table["name"].iloc[0] == "sensor_bias"
    assert json.loads(d.to_json())["verdict"] == cli["verdict"]
    capsys.readouterr()


def test_a_dataframe_with_bad_columns_is_refused_by_name(frame):
    with pytest.raises(OnlineIdError, match="missing required column"):
        online_id.estimate(frame.drop(columns=["yaw_rate"]))
    bad = frame.copy()
    bad.loc[10, "speed"] = np.nan
    with pytest.raises(OnlineIdError, match="row 10, column 'speed': NaN"):
        online_id.estimate(bad)
    with pytest.raises(OnlineIdError, match="source: a path, a pandas DataFrame or a TrackRun"):
        online_id.estimate(42)


def test_one_intersample_keyword_reaches_every_job():
    """``intersample`` (``--intersample``, issue 36): one keyword of every workflow, the filter's and the polish's
    for estimate, the fit's, the diagnosis's and the check's; each result says which it took; None is the
    filter's default (FilterConfig.intersample); an unknown kind is one line."""
    from online_id.cli.main import build_parser
    from online_id.filters import FilterConfig

    car = load_vehicle("haro2008")
    run = simulate(car, car.truth("track"), duration_s=24.0, rate_hz=50.0, seed=21).run  # a held-out segment
    est = online_id.estimate(run, intersample="cubic")
    assert est.result.polish["intersample"] == "cubic"
    assert online_id.estimate(run).result.polish["intersample"] == FilterConfig().intersample
    assert online_id.fit(run, generations=2, groups=2, intersample="linear").result.to_json_dict()["intersample"] \
        == "linear"
    assert online_id.diagnose(run, effects=["sensor_delay"], intersample="cubic").result.intersample == "cubic"
    assert online_id.check(run, intersample="cubic").result.to_json_dict()["crlb"]["intersample"] == "cubic"
    with pytest.raises(OnlineIdError, match="--intersample: unknown intersample model 'spline'"):
        online_id.fit(run, intersample="spline")
    parser = build_parser()
    for argv in (["estimate"], ["fit"], ["diagnose"], ["check"], ["batch", "x.csv", "--out", "d"],
                 ["listen", "--interface", "virtual", "--channel", "0"], ["plot", "convergence", "--out", "x.png"],
                 ["report", "--out", "x.html"]):
        assert parser.parse_args([*argv, "--intersample", "cubic"]).intersample == "cubic", argv
    from online_id.workflows.report_job import commands

    assert all("--intersample cubic" in line for line in commands("x.csv", intersample="cubic").values())
