"""The coverage study (issue 32 item 4, ``calibration.coverage``): the coverage arithmetic on
made-up rows, and one CI-sized twin through the whole pipeline (data at h/2 with noise, the
default two-level fit, the z-scores).  The study's figures are in docs/calibration-coverage.md."""

import json
import math

import pytest

from calibration.coverage import SIZES, coverage_study, summarise


def _row(z_tot, z_refit, z_stat, rel=0.1, err=0.05):
    return {"truth": {"mu0": 4.0}, "fit": {"mu0": 4.0 * (1 + err)}, "rel_std": {"mu0": rel},
            "z": {"total": {"mu0": z_tot}, "total_refit": {"mu0": z_refit}, "statistical": {"mu0": z_stat}},
            "wall_s": 10.0, "cpu_s": 5.0}


def test_coverage_is_the_fraction_of_twins_whose_interval_holds_the_truth():
    """Five made-up twins with |error|/std of 0.5, 1.0 (on the edge: covered), 1.5, 2.0, 3.0 for
    the total std: 1 sigma covers 2 of 5 (40 %), 2 sigma 4 of 5 (80 %); a failed fit is counted
    apart and not in the coverages; the binomial standard error at 95 % and N = 5 is
    sqrt(0.95 x 0.05 / 5) = 0.0975."""
    rows = [_row(z, 10 * z, 100 * z, rel=r) for z, r in zip((0.5, 1.0, 1.5, 2.0, 3.0), (0.1, 0.2, 0.3, 0.4, 0.5),
                                                             strict=True)]
    rows.append({"twin": 5, "truth": {"mu0": 4.0}, "error": "non-finite", "wall_s": 1.0, "cpu_s": 1.0})
    s = summarise(rows, ["mu0"])
    assert s["mu0"]["total"] == {"cover_1sigma": 0.4, "cover_2sigma": 0.8, "n": 5}
    assert s["mu0"]["total_refit"]["cover_1sigma"] == 0.0 and s["mu0"]["statistical"]["cover_2sigma"] == 0.0
    assert s["mu0"]["median_rel_std"] == pytest.approx(0.3) and s["mu0"]["median_abs_rel_error"] == pytest.approx(0.05)
    assert (s["n_twins"], s["n_failed"]) == (5, 1)
    assert s["binomial_se_at_95"] == pytest.approx(math.sqrt(0.95 * 0.05 / 5))
    assert s["wall_s"] == 51.0 and s["cpu_s"] == 26.0


def test_one_ci_twin_through_the_default_two_level_fit(tmp_path):
    """One twin at the CI size (the twin dam break at h = 0.06 m, data at 0.03 m with 1 mm noise, one
    profile at 0.3 s): the truth is drawn inside the bounds, the fit runs the default two levels
    (0.06, 0.03 m), and each z-score is |fitted - truth| / the std it names, with the refit
    estimator's total the quadrature sum of the statistical std and the refit's shift."""
    doc = coverage_study(1, fit=["mu0"], size="ci", seed=3, out=tmp_path)
    (row,) = doc["twins"]
    assert row.get("error") is None, row
    t, f = row["truth"]["mu0"], row["fit"]["mu0"]
    assert 2.0 <= t <= 8.0 and doc["settings"]["data_cell_size_m"] == pytest.approx(SIZES["ci"]["cell_size_m"] / 2)
    assert len(row["levels"]) == 2
    assert row["z"]["total"]["mu0"] == pytest.approx(abs(f - t) / row["std"]["mu0"])
    assert row["z"]["statistical"]["mu0"] == pytest.approx(abs(f - t) / row["std_statistical"]["mu0"])
    refit_tot = math.hypot(row["std_statistical"]["mu0"], row["std_numerical_refit"]["mu0"])
    assert row["z"]["total_refit"]["mu0"] == pytest.approx(abs(f - t) / refit_tot)
    assert row["z"]["total"]["mu0"] <= row["z"]["statistical"]["mu0"]  # the numerical std only widens
    saved = json.loads((tmp_path / "coverage.json").read_text())
    assert saved["summary"]["n_twins"] == 1 and saved["twins"][0]["fit"] == row["fit"]


@pytest.mark.parametrize("value", ["1", "9", "2.5"])
def test_the_data_refinement_out_of_its_range_exits_2(capsys, tmp_path, value):
    """``--data-refine`` (the data's grid is the fit's first cell size over it): 1 would fit the data with the
    model that made them (no resolution error at all), above 8 the data run costs more than the study; refused
    before anything runs, naming the option, the value and the range."""
    from mpmjax import cli

    try:  # a range is checked by the command (returns 2), a non-integer by argparse (exits 2)
        rc = cli.main(["calibrate-coverage", "--data-refine", value, "--out", str(tmp_path / "o")])
    except SystemExit as e:
        rc = e.code
    assert rc == 2
    err = capsys.readouterr().err
    assert "--data-refine" in err and not (tmp_path / "o").exists()
