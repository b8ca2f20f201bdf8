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
