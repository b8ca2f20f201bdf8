"""Goodness of fit against a known noise level (``calibration.uncertainty.goodness_of_fit``): the chi^2 of the
experiments whose sigma is known, its upper-tail probability, and the warning when a fit's residuals exceed the noise
their sigma allows (a fit stopped before its optimum; docs/calibration-coverage.md, "On the joint experiments")."""

import math

import numpy as np
import pytest

from calibration.uncertainty import GOF_P_WARN, _goodness_warning, goodness_of_fit


def test_tail_probability_is_the_exact_chi2_law_at_two_degrees_of_freedom():
    """With nu = 2 the upper tail of chi^2 is exp(-x/2) exactly: three residuals and one parameter."""
    for x in (0.5, 3.0, 14.0):
        r = np.array([math.sqrt(x), 0.0, 0.0])
        g = goodness_of_fit(["profiles"], [r], [True], 1)
        assert g["dof"] == 2 and g["chi2"] == pytest.approx(x)
        assert g["p_value"] == pytest.approx(math.exp(-x / 2), rel=1e-5)
        assert g["reduced"] == pytest.approx(x / 2)


def test_noise_at_its_stated_sigma_passes_and_one_and_a_half_times_it_is_named():
    """Residuals drawn at the stated noise (N = 600, p = 5): chi^2/nu within 3 sqrt(2/nu) = 0.17 of 1 and no
    warning; the same residuals 1.5x larger (chi^2/nu about 2.25, p far below 1e-3): the warning, with the
    Birge ratio sqrt(chi^2/nu) about 1.5 and the experiments' mean squares."""
    rng = np.random.default_rng(3)
    rs = [rng.standard_normal(300), rng.standard_normal(300)]
    g = goodness_of_fit(["profiles", "front series"], rs, [True, True], 5)
    assert g["dof"] == 595 and abs(g["reduced"] - 1) < 3 * math.sqrt(2 / 595)
    assert g["p_value"] > GOF_P_WARN and _goodness_warning(g) == []
    g = goodness_of_fit(["profiles", "front series"], [1.5 * r for r in rs], [True, True], 5)
    assert g["p_value"] < 1e-12
    (w,) = _goodness_warning(g)
    assert "profiles" in w and "front series" in w and "sqrt(chi^2/nu) = 1.5" in w


def test_only_experiments_with_a_known_sigma_count():
    """An experiment whose scale is estimated from its own residuals has chi^2 = N - p by construction: left out;
    none known: None (nothing to test against)."""
    big = np.full(50, 10.0)
    assert goodness_of_fit(["profiles"], [big], [False], 2) is None
    g = goodness_of_fit(["profiles", "rheometer"], [big, np.zeros(20)], [False, True], 2)
    assert list(g["experiments"]) == ["rheometer"] and g["chi2"] == 0.0 and g["dof"] == 18


def test_two_experiments_with_one_name_both_count():
    """Labels are file names, which may repeat (a/lab1.csv, b/lab1.csv): both experiments count in chi^2 and nu,
    the second listed as "lab1.csv (2)"."""
    g = goodness_of_fit(["lab1.csv", "lab1.csv"], [np.ones(10), 2 * np.ones(10)], [True, True], 1)
    assert g["chi2"] == pytest.approx(10 + 40) and g["dof"] == 19
    assert g["experiments"]["lab1.csv (2)"]["mean_square"] == pytest.approx(4.0)
