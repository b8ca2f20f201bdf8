"""Issue 32, "calibration honest by default": two levels unless told otherwise (and the cost of
the fine level announced before it starts), a numerical std at fixed parameters, multi-start
for three or more free parameters.  CI size: the twin dam break at h = 0.06 m (35 particles)
for 0.3 s, a few iterations."""

import json
from pathlib import Path

import numpy as np
import pytest

from calibration.data import Profile, write_profiles_csv

ROOT = Path(__file__).resolve().parent.parent
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
SMALL = ["domain.cell_size_m=0.06", "time.t_end_s=0.3", "time.n_frames=3"]


def _wedge(tmp_path):
    """One made-up profile (SYNTHETIC: a wedge 20 mm at the wall to 0 at 0.6 m, sigma 2 mm)."""
    x = np.linspace(0.0, 0.9, 16)
    data = tmp_path / "p.csv"
    wedge = Profile(x, np.maximum(0.02 * (1 - x / 0.6), 0.0), 0.3, np.full(16, 0.002))
    write_profiles_csv(data, [wedge], "SYNTHETIC: a made-up wedge, not a model run")
    return data


def test_default_is_two_levels_and_the_fine_levels_cost_is_announced_before_it_starts(tmp_path, capsys):
    """``calibrate`` with no --levels / --refine fits at h and h/2 (DEFAULT_REFINE = 1), reports a
    numerical std, and before the fine level estimates its cost from the coarse level's: the cost
    ratio of one run is (particles x steps) fine over coarse, 130 x 153 / (35 x 78) = 7.29 here
    (a 2D halving: about 4x the particles, 2x the steps; not exactly 8 because the block's
    0.2 x 0.15 m does not fill whole cells at 0.06 m and the time step is not exactly halved).
    With a budget below the estimate the warning is printed before the fine level's first
    iteration and kept in fit.json; the fit goes on."""
    from calibration.run import DEFAULT_REFINE, calibrate

    assert DEFAULT_REFINE == 1
    r = calibrate(_wedge(tmp_path), scene=TWIN, overrides=SMALL, fit=["mu0"], init={"mu0": 6.0}, bandwidth_m=0.06,
                  max_iter=2, refine_max_iter=1, out=tmp_path / "o", level_budget_s=1e-3)
    err = capsys.readouterr().err
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())
    assert r.levels == [0.06, 0.03] and [lv["cell_size_m"] for lv in doc["levels"]] == [0.06, 0.03]
    assert doc["resolution_bias"].startswith("estimated") and doc["std_numerical"]["mu0"] is not None
    c, f = doc["levels"]
    est = f["estimate"]
    assert c["estimate"] is None
    assert est["cost_ratio"] == pytest.approx(f["n_particles"] * f["n_steps"] / (c["n_particles"] * c["n_steps"]))
    assert 6.0 < est["cost_ratio"] < 9.0, est
    assert est["evaluations"] == 1 + 2 and est["over_budget"] and est["wall_s"] > 0
    warn = next(w for w in doc["uncertainty"]["warnings"] if "over the budget" in w)
    assert "level 2/2 (h = 0.03 m) is estimated to take" in warn
    assert err.index("over the budget") < err.index("level 2/2 iteration 1/1")
    # the estimate bounds the fine level here: at most max_iter + 2 evaluations were counted
    assert f["wall_s"] <= est["wall_s"] * 1.5 + 5.0, (f["wall_s"], est)


def test_one_level_says_in_words_that_the_resolution_bias_is_not_estimated(tmp_path, capsys):
    """``--levels 1`` is the explicit fast fit: std_numerical null, and fit.json
    (``resolution_bias``, the warnings), the printed summary and the text of fit_profiles.png
    say that the resolution bias is not estimated."""
    from calibration.report import ONE_LEVEL_NOTE, summary_lines
    from mpmjax.cli import main

    out = tmp_path / "o"
    args = ["calibrate", str(_wedge(tmp_path)), "--scene", TWIN, "--fit", "mu0", "--init", "mu0=6",
            "--bandwidth-m", "0.06", "--max-iter", "1", "--levels", "1", "--out", str(out)]
    for o in SMALL:
        args += ["--set", o]
    assert main(args) == 0
    err = capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    assert len(doc["levels"]) == 1 and doc["std_numerical"] == {"mu0": None}
    assert doc["resolution_bias"] == ONE_LEVEL_NOTE and "NOT ESTIMATED" in ONE_LEVEL_NOTE
    assert any("numerical (discretisation) uncertainty not estimated" in w for w in doc["uncertainty"]["warnings"])
    assert ONE_LEVEL_NOTE in err and any(ONE_LEVEL_NOTE in ln for ln in summary_lines(doc))
    assert (out / "fit_profiles.png").stat().st_size > 0


# ------------------------------------------------------------ item 2: numerical std at fixed parameters
def _flow_curve_levels(delta):
    """make_experiments(h) for two made-up "levels" of a rheometer flow curve (no MPM: CI cost):
    level h = 2 fits 12 noisy points (2 % seeded noise) of the BASE Coussot curve; level h = 1 the
    same points times exp(delta (1 + 0.5 ln gamma_dot)), standing in for the change of the
    model's residuals between two grids (a level shift and a slope change: it moves mu0 and n)."""
    import jax.numpy as jnp

    import mpmjax as m
    from calibration.experiments import FlowCurveExperiment
    from calibration.params import ParameterSet
    from mpmjax.rheometer import steady_flow_curve

    base = m.CoussotParams(*(jnp.float64(v) for v in (1850.0, 15000.0, 4.0, 1.0, 0.5, 2.5, 1.5, 5000.0)))
    g = np.logspace(-1, 2, 12)
    tau = np.asarray(steady_flow_curve(base, g)[0]) * np.exp(0.02 * np.random.default_rng(3).standard_normal(12))

    def make(h):
        scale = 1.0 if h == 2.0 else np.exp(delta * (1.0 + 0.5 * np.log(g)))
        return [FlowCurveExperiment(base, g, tau * scale, sigma_ln=0.02)]

    return make, ParameterSet.from_names(["mu0", "n"], base, init={"mu0": 6.0, "n": 3.0})


def test_fixed_parameter_shift_is_the_refit_shift_to_first_order_and_ignores_the_refits_path():
    """The numerical std at fixed parameters is the Gauss-Newton step of the fine level's residuals
    from the coarse optimum: (a) it does not depend on how the fine level is refitted (1 or 60
    iterations: bit-identical, it is computed from the fine level's first evaluation, so a refit
    that wanders cannot inflate it), while the refit's own shift does; (b) for a small change of
    the residuals (delta = 1 %) it equals the converged refit's shift to first order: measured
    +0.0881 against +0.0890 Pa s for mu0 (1.1 %) and -0.009796 against -0.009792 for n (0.04 %; the
    second-order terms are O(delta) relative to the shift), asserted within 5 %; (c) the step is
    the Gauss-Newton step in the parameters themselves, whatever the transform: without
    Levenberg-Marquardt's residuals (method lbfgs) it is computed in SI from one forward-mode
    Jacobian, and agrees to 1e-6 (mu0) and 3e-6 (n), the difference of the two methods' coarse
    optima; asserted to 1e-4."""
    from calibration.multilevel import fit_multilevel

    make, ps = _flow_curve_levels(0.01)
    kw = {"max_iter": 60, "rtol": 1e-12, "progress": False}
    full = fit_multilevel(make, ps, [2.0, 1.0], refine_max_iter=60, **kw)
    one = fit_multilevel(make, ps, [2.0, 1.0], refine_max_iter=1, **kw)
    lb = fit_multilevel(make, ps, [2.0, 1.0], refine_max_iter=60, method="lbfgs", **{**kw, "max_iter": 200})
    for k in ps.free:
        lin, lin1 = full.numerical.linear[k], one.numerical.linear[k]
        refit = full.numerical.values[k][1] - full.numerical.values[k][0]
        assert lin1 == lin and full.numerical.method[k] == "linear"  # (a)
        assert full.numerical.std[k] == abs(lin) and full.numerical.refit_std[k] == pytest.approx(abs(refit))
        assert abs(lin) > 1e-3 * full.params[k]  # the perturbation moves both parameters
        assert lin == pytest.approx(refit, rel=0.05), (k, lin, refit)  # (b)
        assert lb.numerical.linear[k] == pytest.approx(lin, rel=1e-4), (k, lb.numerical.linear[k], lin)  # (c)
    doc = full.numerical.as_dict()
    assert set(doc["estimators"]) == {"fixed_parameters", "refit", "definition"}
    assert doc["shift_nonlinear"]["mu0"] == pytest.approx(doc["shift_refit"]["mu0"] - doc["shift_linear"]["mu0"])

