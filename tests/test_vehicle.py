"""Vehicle descriptions: the built-in haro2008 car and the errors of a bad TOML file."""

from __future__ import annotations

import pytest

from online_id.errors import VehicleFileError
from online_id.vehicle import PARAMETER_NAMES, Parameters, builtin_vehicle_names, load_vehicle

TABLE3 = dict(Mzz=1571, Mxx=252, D1=84085, D2=87342, Aro=2750, Kro=150000, b1=0.5, b2=0.5)
TABLE6 = dict(Mzz=634.6, Mxx=368.7, D1=111974.6, D2=155840.7, Aro=1991.9, Kro=56756.9, b1=0.64, b2=1.04)
TABLE5 = dict(Mzz=670.9, Mxx=377.2, D1=108260, D2=144250, Aro=2128.9, Kro=55717.5, b1=0.78, b2=0.92)


def test_haro2008_holds_the_papers_tables():
    car = load_vehicle("haro2008")
    assert "haro2008" in builtin_vehicle_names()
    assert car.prior == Parameters(**TABLE3)
    assert car.truth("constructor") == car.prior
    assert car.truth("track") == Parameters(**TABLE6)
    assert car.truth("track60") == Parameters(**TABLE5)
    assert car.prior_relative_std.Kro == 0.15 and car.prior_relative_std.Mxx == 0.5
    k = car.known
    assert (k.M, k.ms, k.Mxz, k.h0, k.h1, k.h2, k.hg, k.l1, k.l2, k.eps1, k.eps2) == (
        1400, 1262, 50, 0.43, 0.0903, 0, 0.535, 1.148, 1.387, -0.027, 0.020)
    assert k.steering_ratio == 16


def test_parameters_vector_round_trip():
    p = Parameters(**TABLE6)
    assert list(PARAMETER_NAMES) == list(TABLE6)
    assert Parameters.from_vector(p.to_vector()) == p
    with pytest.raises(ValueError):
        Parameters.from_vector([1.0, 2.0])


GOOD = """
name = "test"
[known]
M = 1400.0
ms = 1262.0
Mxz = 50.0
h0 = 0.43
h1 = 0.09
h2 = 0.0
hg = 0.535
l1 = 1.148
l2 = 1.387
eps1 = -0.027
eps2 = 0.02
[prior]
Mzz = 1571.0
Mxx = 252.0
D1 = 84085.0
D2 = 87342.0
Aro = 2750.0
Kro = 150000.0
b1 = 0.5
b2 = 0.5
"""


def _write(tmp_path, text):
    p = tmp_path / "car.toml"
    p.write_text(text)
    return p


def test_a_good_file_loads_with_defaults(tmp_path):
    car = load_vehicle(_write(tmp_path, GOOD))
    assert car.name == "test" and car.known.steering_ratio == 16.0
    assert car.prior_relative_std.D1 == 0.5


@pytest.mark.parametrize("edit,needle", [
    (lambda t: t.replace("Kro = 150000.0\n", ""), "missing key prior.Kro"),
    (lambda t: t.replace("l2 = 1.387\n", ""), "missing key known.l2"),
    (lambda t: t.replace("M = 1400.0", "M = -1400.0"), "known.M = -1400.0 must be positive"),
    (lambda t: t.replace("Mzz = 1571.0", "Mzz = -1.0"), "prior.Mzz = -1.0 must be positive"),
    (lambda t: t.replace("b2 = 0.5", "b2 = 0.5\nb3 = 0.5"), "unknown key prior.b3"),
    (lambda t: t.replace("ms = 1262.0", "ms = 1262.0\nmass = 3.0"), "unknown key known.mass"),
    (lambda t: t.replace("ms = 1262.0", "ms = 2000.0"), "exceeds the total mass"),
    (lambda t: t.replace("D1 = 84085.0", 'D1 = "stiff"'), "prior.D1 must be a number"),
    (lambda t: t.replace('name = "test"', ""), "missing key 'name'"),
    (lambda t: t.replace("[prior]", "[prior"), "not valid TOML"),
    (lambda t: t + "[truth.track]\nMzz = 600.0\n", "missing key truth.track.Mxx"),
])
def test_bad_files_name_the_file_and_the_key(tmp_path, edit, needle):
    path = _write(tmp_path, edit(GOOD))
    with pytest.raises(VehicleFileError) as info:
        load_vehicle(path)
    assert needle in str(info.value)
    assert str(path) in str(info.value)


def test_unknown_vehicle_and_unknown_truth_set(tmp_path):
    with pytest.raises(VehicleFileError, match="not a built-in vehicle"):
        load_vehicle(tmp_path / "nope.toml")
    with pytest.raises(VehicleFileError, match="no parameter set named 'track99'"):
        load_vehicle("haro2008").truth("track99")
