"""Numerical (discretisation) uncertainty from fits at several cell sizes (issue 15 item 1):
``calibration.uncertainty.numerical_uncertainty`` / ``combine``, ``calibration.multilevel``,
and ``mpmjax calibrate --refine / --levels``.  The twin test is in tests/test_calibration_twin.py."""

import math

import numpy as np
import pytest

from calibration.multilevel import check_levels
from calibration.uncertainty import Uncertainty, combine, numerical_uncertainty


def _unc(names, theta, std, poorly=()):
    p = len(names)
    return Uncertainty(
        tuple(names), np.asarray(theta, float), np.asarray(std, float), np.asarray(std) / np.abs(theta),
        np.diag(np.square(std)), np.eye(p), np.eye(p), [1.0], {}, 1.0, [], tuple(poorly),
    )


@pytest.mark.parametrize("p", [0.7, 1.0, 1.6, 3.0])
def test_richardson_recovers_limit_and_order_of_a_power_law(p):
    """theta(h) = theta_inf + C h^p at unequal refinement ratios (0.03, 0.017, 0.01): the
    observed order and the extrapolate are exact to the bisection's tolerance, and the
    numerical std is the finest level's true remaining error C h_3^p."""
    h = [0.03, 0.017, 0.01]
    th = {"a": [4.0 - 50.0 * x**p for x in h], "b": [2.0 + 3.0 * x**p for x in h]}
    n = numerical_uncertainty(h, th)
    for k, lim, c in (("a", 4.0, -50.0), ("b", 2.0, 3.0)):
        assert n.method[k] == "richardson" and n.reason[k] is None
        assert n.order[k] == pytest.approx(p, rel=1e-9)
        assert n.extrapolated[k] == pytest.approx(lim, rel=1e-10)
        assert n.std[k] == pytest.approx(abs(c) * h[-1] ** p, rel=1e-8)


def test_no_extrapolation_without_a_sane_order_and_the_last_shift_is_kept():
    h = [0.04, 0.02, 0.01]
    n = numerical_uncertainty(
        h,
        {
            "sign": [1.0, 1.3, 1.1],  # differences change sign: not asymptotic
            "slow": [1.0, 1.1, 1.199],  # d1/d2 ~ 1: order ~ 0.01 < 0.5
            "fast": [1.0, 1.5, 1.5001],  # d1/d2 = 5000: order ~ 12 > 6
            "flat": [1.0, 1.0, 1.0],
        },
    )
    for k in ("sign", "slow", "fast", "flat"):
        assert n.method[k] == "shift" and n.extrapolated[k] is None and n.reason[k], (k, n.reason[k])
    assert "change sign" in n.reason["sign"]
    assert "outside 0.5 .. 6" in n.reason["slow"] and "outside 0.5 .. 6" in n.reason["fast"]
    assert n.std["sign"] == pytest.approx(0.2) and n.std["slow"] == pytest.approx(0.099)
    two = numerical_uncertainty([0.02, 0.01], {"mu0": [3.4, 3.9]})
    assert two.std["mu0"] == pytest.approx(0.5) and two.method["mu0"] == "shift"
    assert "two levels" in two.reason["mu0"]
    with pytest.raises(ValueError, match="strictly decreasing"):
        numerical_uncertainty([0.01, 0.02], {"mu0": [1.0, 2.0]})


def test_combine_adds_in_quadrature_and_names_poorly_identified():
    """std = sqrt(stat^2 + num^2); a parameter whose total relative std exceeds 0.5 (its 2 sigma
    interval reaches 0) or that the statistical analysis flagged is named poorly identified."""
    unc = _unc(["mu0", "lambda0", "n"], [4.0, 1.2, 2.5], [0.03, 0.2, 2.0], poorly=("n",))
    num = numerical_uncertainty([0.02, 0.01], {"mu0": [3.6, 4.0], "lambda0": [0.4, 1.2], "n": [2.5, 2.5]})
    c = combine(unc, num)
    assert c["std"]["mu0"] == pytest.approx(math.hypot(0.03, 0.4))
    assert c["std_numerical"]["lambda0"] == pytest.approx(0.8)
    assert c["poorly_identified"] == ["lambda0", "n"]  # total 0.82/1.2 > 0.5; n flagged statistically
    one = combine(unc, None)
    assert one["std_numerical"] == {"mu0": None, "lambda0": None, "n": None}
    assert one["std"]["mu0"] == pytest.approx(0.03) and one["poorly_identified"] == ["n"]


@pytest.mark.parametrize(
    "levels, needle",
    [([], "one or more"), ([0.01, 0.02], "strictly decreasing"), ([0.02, -0.01], "> 0"), (["a"], "cell sizes")],
)
def test_check_levels_names_the_option_value_and_range(levels, needle):
    with pytest.raises(ValueError, match=needle) as e:
        check_levels(levels, "--levels")
    assert "--levels" in str(e.value)


def test_calibrate_cli_bad_levels_exit_2_naming_the_option(tmp_path, capsys):
    from pathlib import Path

    from mpmjax.cli import main

    root = Path(__file__).resolve().parent.parent
    base = ["calibrate", str(root / "data" / "synthetic_twin_small_profiles.csv"), "--scene",
            str(root / "data" / "twin-small-dambreak.toml"), "--fit", "mu0", "--quiet", "--out", str(tmp_path / "o")]
    for extra, needle in (
        (["--refine", "4"], "--refine = 4; allowed range: 0 .. 3"),
        (["--refine", "-1"], "--refine = -1; allowed range: 0 .. 3"),
        (["--levels", "0.01,0.02"], "--levels = [0.01, 0.02]; allowed: one or more cell sizes > 0 [m], strictly"),
        (["--levels", "0.02,x"], "--levels = "),
        (["--levels", "5"], "--levels = 5; allowed range: 1 .. 4 levels (a plain integer), or cell sizes [m]"),
        (["--levels", "0"], "--levels = 0; allowed range: 1 .. 4 levels"),
        (["--levels", "0.02,0.007"], "--levels / --refine: cell size 0.007 m: domain.cell_size_m = 0.007"),
        (["--refine", "1", "--refine-max-iter", "0"], "--refine-max-iter = 0 is invalid: allowed range: integer >= 1"),
    ):
        assert main(base + extra) == 2, extra
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1, (extra, err)



def test_summary_names_the_method_the_extrapolate_and_the_poorly_identified():
    """The printed summary (also the text box of fit_profiles.png) for three levels: mu0 converges
    at first order (3, 3.5, 3.75 -> 4), lambda0 oscillates (no extrapolation, last shift)."""
    from calibration.report import summary_lines

    num = numerical_uncertainty([0.04, 0.02, 0.01], {"mu0": [3.0, 3.5, 3.75], "lambda0": [1.0, 1.3, 1.1]})
    assert num.std["mu0"] == pytest.approx(0.25) and num.std["lambda0"] == pytest.approx(0.2)
    doc = {
        "params": {"mu0": 3.75, "lambda0": 1.1},
        "std": {"mu0": 0.2502, "lambda0": None},
        "std_statistical": {"mu0": 0.01, "lambda0": None},
        "std_numerical": num.std,
        "units": {"mu0": "Pa s", "lambda0": "-"},
        "poorly_identified": ["lambda0"],
        "numerical_uncertainty": num.as_dict(),
    }
    text = "\n".join(summary_lines(doc))
    assert "mu0 = 3.75 +- 0.25 [Pa s] (statistical 0.01, numerical 0.25 from the Richardson estimate)" in text
    assert "lambda0 = 1.1 +- inf [-] (statistical inf, numerical 0.2 from the shift)  POORLY IDENTIFIED" in text
    assert "Richardson: mu0 -> 4 (h -> 0, observed order 1.00)" in text
    assert "Richardson: lambda0 not extrapolated: the differences between levels change sign" in text
