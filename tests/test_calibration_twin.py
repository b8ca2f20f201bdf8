"""Twin experiments: profiles made by the simulator itself at a finer resolution (plus
noise) are fitted at the calibration resolution from a guess a factor of 2 off.

Data: data/synthetic_twin_small_profiles.csv, made by ``python -m calibration.synthetic``
from data/twin-small-dambreak.toml at h = 0.01 m (Coussot BASE: mu0 = 4 Pa s, alpha = 1,
T = 0.5 s, n = 2.5, lambda0 = 1.5), kernel bandwidth 0.04 m, noise sigma = 1 mm, at
t = 0.5, 1.0 and 1.5 s (138 stations).  The fit runs the same scene at h = 0.02 m.

What the tolerances rest on (measured, docs/calibration-twins.md "Twin experiments"): at the fit
resolution the model cannot reproduce the finer run exactly.  With the true parameters the
h = 0.02 m model leaves a loss (mean squared normalised residual) of 10.27, almost all of it
resolution error (the h = 0.01 m model at the truth leaves 0.75: the noise, partly clipped at
h = 0); the best the coarse model can do is 6.79,
at mu0 = 3.36 Pa s (-16 %) with lambda0 = 1.28 (converged CLI fit).  So:

* the loss must fall by >= 95 % (the issue's criterion; from the factor-2 start above,
  mu0 = 8, lambda0 = 3, loss 164.2, the floor is 95.9 % lower, so this also checks that
  the fit reaches the floor; from the factor-2 start below, mu0 = 2, lambda0 = 0.75, the loss
  is only 25.4 and the floor is 73 % lower, so there the slow test checks the same floor);
* mu0 must come back within 25 % (the measured 16 % resolution bias plus 10 points for a
  fit stopped after a few iterations along the mu0-lambda0 valley);
* lambda0 trades off against mu0 along that valley (both make the initial material
  stiffer) and is biased too (1.28 against 1.5 at the converged fit), so it is not asserted
  on its own: the Gauss-Newton analysis must report it as the weakly constrained
  parameter, negatively correlated with mu0.  (With sigma = 1 mm taken as known, the
  Gauss-Newton std of mu0 is 1 %: far below the 16 % resolution bias, which is not noise.)
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


@pytest.mark.slow  # CI time: the notebook test runs the same fit (docs/calibration-twins.md, figures)
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
    assert 0.75 < r.loss_final < 10.27
    u = gauss_newton([exp], ps, r.params)
    i, j = u.names.index("mu0"), u.names.index("lambda0")
    assert np.all(np.isfinite(u.std)) and np.all(u.std > 0)
    # more mu0 is traded for less initial structure (measured r = -0.55 at the converged fit)
    assert u.corr[i, j] < 0, u.corr
    # lambda0 is the weakly constrained one (measured relative std 7.2 % against 1.0 % for mu0)
    assert u.rel_std[j] > 3 * u.rel_std[i], u.rel_std
    assert abs(u.weakest.get("lambda0", 0.0)) == pytest.approx(1.0)


@pytest.mark.slow
def test_twin_fits_from_above_and_below_reach_the_same_floor(twin):
    """From a factor of 2 below (mu0 = 2, lambda0 = 0.75: more fluid than the truth) and from
    a factor of 2 above, the fits end at the same resolution floor and the same biased mu0.
    Tolerances: 3 % in loss and 5 % in mu0, the spread of the iterates once the loss has
    flattened (the last 5 iterations of the converged CLI fit span 6.787-6.804 in loss and
    3.358-3.404 in mu0)."""
    setup, exp = twin
    res = []
    for init in ({"mu0": 8.0, "lambda0": 3.0}, {"mu0": 2.0, "lambda0": 0.75}):
        ps = ParameterSet.from_names(["mu0", "lambda0"], setup.params.material, init=init)
        res.append(fit([exp], ps, method="lbfgs", max_iter=20, rtol=1e-3, patience=3, progress=False))
    a, b = res
    assert b.loss_final == pytest.approx(a.loss_final, rel=0.03), (a.loss_final, b.loss_final)
    assert b.params["mu0"] == pytest.approx(a.params["mu0"], rel=0.05), (a.params, b.params)
    assert abs(b.params["mu0"] / TRUTH["mu0"] - 1.0) < 0.25


# --- multi-fidelity: the numerical std (issue 15 item 1) -------------------------------------
# Truth not in the repository (the data/ twin uses mu0 = 4, lambda0 = 1.5); lambda0 is fixed at
# it here (as if measured on a rheometer): fitted together from profiles, mu0 and lambda0 trade
# off along a valley (docs/calibration.md, "Numerical uncertainty").
ML_TRUTH = {"mu0": 5.5, "lambda0": 1.2}


def _multilevel_twin(tmp_path, capsys, times_s, max_iter, refine_max_iter):
    """Twin data at h = 0.015 m (truth ML_TRUTH, 1 mm seeded noise, profiles at ``times_s``), fitted
    through the CLI with ``--levels 0.03,0.015`` (mu0 free, lambda0 fixed at the truth), and the
    assertions of both tests below (their docstrings say why)."""
    import json

    from calibration.data import write_profiles_csv
    from calibration.synthetic import synthetic_profiles
    from mpmjax.cli import main

    truth = ML_TRUTH["mu0"]
    mat = [f"material.mu0_pa_s={truth}", f"material.lambda0={ML_TRUTH['lambda0']}"]
    profs, _ = synthetic_profiles(
        TWIN, [f"time.t_end_s={times_s[-1]}", *mat, "domain.cell_size_m=0.015"], times_s, np.linspace(0.0, 0.9, 46),
        sigma_m=0.001, seed=5, bandwidth_m=0.04,
    )
    data = tmp_path / "twin.csv"
    write_profiles_csv(data, profs, "SYNTHETIC twin (test): h = 0.015 m, mu0 = 5.5, lambda0 = 1.2")
    out = tmp_path / "fit"
    args = ["calibrate", str(data), "--scene", TWIN, "--fit", "mu0", "--init", "mu0=9",
            "--init", f"lambda0={ML_TRUTH['lambda0']}", "--bandwidth-m", "0.04", "--levels", "0.03,0.015",
            "--max-iter", str(max_iter), "--refine-max-iter", str(refine_max_iter), "--rtol", "1e-3",
            "--patience", "2", "--out", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    coarse, fine = (lv["params"]["mu0"] for lv in doc["levels"])
    stat, num, tot = (doc[k]["mu0"] for k in ("std_statistical", "std_numerical", "std"))
    refit = doc["std_numerical_refit"]["mu0"]
    print(f"\nmultilevel twin: mu0 coarse {coarse:.4g}, fine {fine:.4g} (truth {truth}); std statistical "
          f"{stat:.3g}, numerical {num:.3g} at fixed parameters (refit shift {refit:.3g}), total {tot:.3g}; "
          f"losses {[lv['loss_final'] for lv in doc['levels']]}")
    # the bookkeeping: the fitted value is the fine level's; std_numerical the shift at fixed
    # parameters (issue 32), std_numerical_refit the refitted values' shift, std the quadrature sum
    # of the statistical and the fixed-parameter std; the summary and the figure carry both
    assert doc["params"]["mu0"] == fine and [lv["cell_size_m"] for lv in doc["levels"]] == [0.03, 0.015]
    assert refit == pytest.approx(abs(fine - coarse)) and tot == pytest.approx(np.hypot(num, stat))
    assert doc["numerical_uncertainty"]["method"]["mu0"] == "linear"
    assert f"numerical {num:.3g} from the shift at fixed parameters; refit shift {refit:.3g})" in err
    assert "Richardson: mu0 not extrapolated" in err
    assert "domain.cell_size_m=0.015" in doc["scene_overrides"]
    assert (out / "fit_profiles.png").stat().st_size > 0
    # the physics and statistics (issue 15 item 1 acceptance)
    assert abs(fine / truth - 1) < 0.05, (coarse, fine)
    assert abs(fine - truth) <= 2 * tot or "mu0" in doc["poorly_identified"]
    assert num > 5 * stat and abs(coarse - truth) > 2 * stat
    assert doc["levels"][1]["loss_final"] < 1.5 < doc["levels"][0]["loss_final"]


def test_multilevel_twin_mu0_with_a_true_total_error_bar_ci(tmp_path, capsys):
    """CI size of the test below (issue 15 item 1): the same twin and fit through the CLI, cut to
    the first 0.3 s (profiles at 0.15 and 0.3 s: half the steps) and to 4 + 4 iterations (coarse,
    fine) of the default Levenberg-Marquardt.

    Measured (2026-12-02, LM): mu0 = 1.247 Pa s at h = 0.03 m (-77 %, loss 1.705) and 5.688 Pa s at
    0.015 m (+3.4 %, loss 0.511); std statistical 0.195, numerical 4.44, total 4.45 Pa s, so mu0
    is named poorly identified (total relative std 0.78 > 0.5).  In the first 0.3 s the coarse
    model is a poor judge of mu0 (5 cells over the block height): its loss is flat and it slides
    far below the truth, so the resolution error dominates even more than at 0.6 s.  The fine
    level needs its 4 steps from there (with 2 it stopped at 5.983, +8.8 %, on its way; L-BFGS,
    the default before, measured 1.494 and 5.697 with 2 fine iterations of one or more line-search
    evaluations each).  Asserted, as in the full test: mu0 within 5 % of the truth at the fine
    level, the truth inside the 2 sigma total interval (or mu0 named poorly identified),
    std_numerical > 5 std_statistical and the coarse level more than 2 statistical std from the
    truth (the resolution error dominates), the fine loss at the noise level (< 1.5) and the
    coarse one above it."""
    _multilevel_twin(tmp_path, capsys, (0.15, 0.3), 4, 4)


@pytest.mark.slow
def test_multilevel_twin_mu0_with_a_true_total_error_bar(tmp_path, capsys):
    """Data made at h = 0.015 m (half the working cell size 0.03 m) with 1 mm seeded noise,
    profiles at 0.3 and 0.6 s.  ``mpmjax calibrate --levels 0.03,0.015`` fits mu0 at 0.03 m (the
    cheap iterations), then continues at 0.015 m from that result (``fit_multilevel``).

    Asserted (issue 15 item 1 acceptance): mu0 within 5 % of the truth, and the truth inside the
    reported 2 sigma total interval (or mu0 named poorly identified); fit.json's std_numerical is
    the shift between the levels and std the quadrature sum.  Also asserted, because it is why
    the numerical std exists: the resolution error dominates, std_numerical > 5 std_statistical
    (measured with L-BFGS 2.65 against 0.087 Pa s, docs/calibration-twins.md; with the default
    Levenberg-Marquardt since 2026-12-02: coarse 2.932, fine 5.627 Pa s (+2.3 %), numerical 2.7
    against statistical 0.087), and the coarse level alone is off by more than 2 statistical std;
    at the data's resolution the loss falls to the noise level (0.60).  About 170 s on the idle
    2-core VM with L-BFGS, 41 s with LM (one core): in CI its reduced form above runs instead."""
    _multilevel_twin(tmp_path, capsys, (0.3, 0.6), 8, 4)
