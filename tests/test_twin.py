"""Twin experiments: profiles made by the simulator itself at a finer resolution (plus
noise) are fitted at the calibration resolution from a guess a factor of 2 off.

Data: data/synthetic_twin_small_profiles.csv, made by ``python -m calibration.synthetic``
from data/twin-small-dambreak.toml at h = 0.01 m (Coussot BASE: mu0 = 4 Pa s, alpha = 1,
T = 0.5 s, n = 2.5, lambda0 = 1.5), kernel bandwidth 0.04 m, noise sigma = 1 mm, at
t = 0.5, 1.0 and 1.5 s (138 stations).  The fit runs the same scene at h = 0.02 m.

What the tolerances rest on (measured, docs/calibration.md "Twin experiments"): at the fit
resolution the model cannot reproduce the finer run exactly.  With the true parameters the
h = 0.02 m model leaves a loss (mean squared normalised residual) of 9.85, almost all of it
resolution error (pure noise would give 1.0); the best the coarse model can do is about 6.8,
at mu0 ~ 3.4 Pa s (-15 %) with lambda0 ~ 1.3.  So:

* the loss must fall by >= 95 % (the issue's criterion; the measured floor is 96 % below
  the factor-2 start, so this also checks that the fit reaches the floor, not a plateau);
* mu0 must come back within 25 % (the measured 15 % resolution bias plus 10 points for a
  fit stopped after a few iterations along the mu0-lambda0 valley);
* lambda0 trades off against mu0 along that valley (both make the initial material
  stiffer), so it is not asserted on its own: the Gauss-Newton analysis must report their
  strong correlation instead.
"""

from pathlib import Path

import numpy as np
import pytest

import mpmjax as m
from calibration.data import load_profiles
from calibration.experiments import ProfileExperiment
from calibration.fit import fit
from calibration.params import ParameterSet
from calibration.uncertainty import gauss_newton

ROOT = Path(__file__).resolve().parent.parent
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
DATA = ROOT / "data" / "synthetic_twin_small_profiles.csv"
TRUTH = {"mu0": 4.0, "alpha": 1.0, "T": 0.5, "n": 2.5, "lambda0": 1.5}


@pytest.fixture(scope="module")
def twin():
    setup = m.build(m.load_scene(TWIN))
    profs = load_profiles(DATA)
    assert [p.t_s for p in profs] == [0.5, 1.0, 1.5]
    return setup, ProfileExperiment(setup, profs, bandwidth_m=0.04)


def test_twin_data_are_what_the_header_says(twin):
    """The fit scene is the data's scene at twice the cell size, and its material is the
    truth (so the test starts from a known factor-2 error, not an unknown one)."""
    setup, exp = twin
    assert setup.scene.h == pytest.approx(0.02)
    for k, v in TRUTH.items():
        assert float(getattr(setup.params.material, k)) == pytest.approx(v)
    assert exp.n_residuals == 138
    assert max(abs(o) for o in exp.time_offsets_s) < 1e-9


def test_twin_fit_mu0_lambda0_from_a_factor_two_guess(twin):
    setup, exp = twin
    ps = ParameterSet.from_names(["mu0", "lambda0"], setup.params.material, init={"mu0": 8.0, "lambda0": 3.0})
    r = fit([exp], ps, method="lbfgs", max_iter=6, rtol=1e-3, patience=2, progress=False)
    assert np.isfinite(r.history).all()
    drop = 1.0 - r.loss_final / r.loss_initial
    assert drop >= 0.95, (r.loss_initial, r.loss_final, r.params)
    assert abs(r.params["mu0"] / TRUTH["mu0"] - 1.0) < 0.25, r.params
    # the loss cannot go below what pure noise leaves (1.0 per residual), and the coarse
    # model's resolution error keeps it well above that
    assert 1.0 < r.loss_final < 9.85
    u = gauss_newton([exp], ps, r.params)
    i, j = u.names.index("mu0"), u.names.index("lambda0")
    assert u.corr[i, j] < -0.5, u.corr  # more mu0 is traded for less initial structure
    assert np.all(np.isfinite(u.std)) and np.all(u.std > 0)


@pytest.mark.slow
def test_twin_fit_from_below_reaches_the_same_floor(twin):
    """The same fit from a factor of 2 below (mu0 = 2, lambda0 = 0.75): more fluid than the
    truth instead of stiffer."""
    setup, exp = twin
    ps = ParameterSet.from_names(["mu0", "lambda0"], setup.params.material, init={"mu0": 2.0, "lambda0": 0.75})
    r = fit([exp], ps, method="lbfgs", max_iter=20, rtol=1e-3, patience=3, progress=False)
    assert 1.0 - r.loss_final / r.loss_initial >= 0.95, (r.loss_initial, r.loss_final, r.params)
    assert abs(r.params["mu0"] / TRUTH["mu0"] - 1.0) < 0.25, r.params
