"""Experiment design by Fisher information (calibration.design, ``mpmjax design``; issue 15 item 3)."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax
from calibration.design import (
    ProfileRequest,
    design,
    flow_curve_candidate,
    profile_candidates,
    rheometer_candidate,
)
from calibration.experiments import FlowCurveExperiment
from calibration.fit import fit
from calibration.params import ParameterSet
from calibration.uncertainty import gauss_newton

TRUTH = {"mu0": 4.0, "alpha": 1.0, "T": 0.5, "n": 2.5, "lambda0": 1.5}
RATES = np.geomspace(0.1, 100.0, 8)


def _material():
    return mpmjax.rheometer.make_params(law="coussot", **TRUTH)


def _flow_curve(mat, seed=None, sigma_ln=0.05):
    tau, _ = mpmjax.rheometer.steady_flow_curve(mat, jnp.asarray(RATES))
    tau = np.asarray(tau)
    if seed is not None:
        tau = tau * np.exp(sigma_ln * np.random.default_rng(seed).standard_normal(tau.shape))
    return FlowCurveExperiment(mat, RATES, tau, sigma_ln=sigma_ln, name="flow curve")


def test_gain_equals_log_det_of_the_stacked_jacobian():
    """The D-optimal gain of each candidate equals ln det(I0 + J^T J) of the current and the
    candidate's residuals stacked, minus that of the current ones alone, with the Jacobian computed
    here independently (jax.jacfwd of the concatenated residuals in ln theta, no shared code):
    1e-6 absolute in float64 (the two differ only by summation order; measured ~1e-12).  Current:
    an 8-point flow curve; candidates: a transient at 1 1/s after 10 s of rest and a duplicate
    flow curve (one rheometer candidate only: each diffrax Jacobian costs a compilation).  A duplicate
    of the whole flow curve doubles its information, so with a negligible
    prior its gain is (identified directions) * ln 2: mu0, n and alpha*T (the flow curve cannot
    separate alpha and T), 3 ln 2 = 2.079 to the prior's 1e-3."""
    mat = _material()
    current = _flow_curve(mat)
    ps = ParameterSet.from_names(["mu0", "alpha", "T", "n"], mat)
    theta = {k: TRUTH[k] for k in ps.free}
    cands = [
        rheometer_candidate(mat, [1.0], t_end_s=20.0, n_times=15, rest_s=10.0),
        flow_curve_candidate(mat, RATES),
    ]
    res = design([current], ps, theta, cands, prior_factor=10.0)

    u = jnp.log(jnp.asarray([theta[k] for k in ps.free]))

    def jac(e):
        return np.asarray(jax.jacfwd(lambda v: e.residuals(dict(zip(ps.free, jnp.exp(v), strict=True))))(u))

    I0 = np.eye(4) / math.log(10.0) ** 2
    J0 = jac(current)
    ld0 = np.linalg.slogdet(I0 + J0.T @ J0)[1]
    for c, gain in zip(cands, res.gains, strict=True):
        J = np.vstack([J0, jac(c.experiment)])
        assert gain == pytest.approx(np.linalg.slogdet(I0 + J.T @ J)[1] - ld0, abs=1e-6), c.label
    assert res.gains[1] == pytest.approx(3 * math.log(2.0), abs=1e-3)
    # the transient after rest separates alpha from T: it pins one of them and ranks first
    assert res.ranking == [0, 1] and res.pins[0] in ("alpha", "T")
    # alpha: unconstrained by the flow curve (the prior's ~ln 10) -> a few per cent (measured 1.63 -> 0.016)
    assert res.std_before[1] > 1.0 and res.std_after[0][1] < 0.05
    json.dumps(res.as_dict())


def test_rheometer_transient_ranks_above_a_duplicate_profile_time_for_alpha_and_T():
    """Dam-break profiles (the twin scene, coarse: h = 0.03 m, 0.6 s, profiles at 0.3 and 0.6 s,
    1 mm noise) constrain alpha and T only through their effect on the slump.  A second profile at
    0.6 s repeats information already in hand; a constant-shear transient at 1 1/s measures the
    breakdown rate alpha*gdot and the structure 1/T directly.  The design must rank the transient
    first and say it pins alpha or T.  Noise is stated for both (sigma known), so the ranking does
    not depend on the data values (the Jacobian does not)."""
    cfg = mpmjax.load_scene("data/twin-small-dambreak.toml",
                            ["domain.cell_size_m=0.03", "time.t_end_s=0.6", "time.n_frames=2"])
    setup = mpmjax.build(cfg)
    mat = setup.params.material
    ps = ParameterSet.from_names(["mu0", "alpha", "T"], mat)
    theta = {k: TRUTH[k] for k in ps.free}
    # the profiles in hand and the duplicate share one simulation (one forward-mode Jacobian)
    *in_hand, dup = profile_candidates(setup, [ProfileRequest(t, 0.03, 0.001) for t in (0.3, 0.6, 0.6)],
                                       bandwidth_m=0.04)
    rheo = rheometer_candidate(_rheo_material(mat), [1.0], t_end_s=20.0, n_times=15)
    res = design(in_hand, ps, theta, [dup, rheo])
    print(f"\ngains: duplicate profile {res.gains[0]:.3f}, transient {res.gains[1]:.3f} nats; "
          f"rel std before {res.std_before}, after {res.std_after}")
    assert res.ranking[0] == 1 and res.gains[1] > res.gains[0]
    assert res.pins[1] in ("alpha", "T")


def _rheo_material(mat):
    """The scene's material as a rheometer material (same values)."""
    return mpmjax.rheometer.make_params(law="coussot", **{k: float(getattr(mat, k)) for k in TRUTH})


def test_predicted_std_after_the_top_candidate_matches_the_refit():
    """Start from a 4-point flow curve across the crossover (0.3-30 1/s, alpha T gdot = 0.15-15:
    mu0, n and T, alpha fixed, are all identified, if loosely; synthetic, 5 % noise, seed 1), rank
    three candidate flow curves (0.02-0.2 1/s, 50-500 1/s and a repeat), make the top candidate's
    data (synthetic, truth plus 5 % noise, seed 2), refit both together and compare the
    Gauss-Newton std of the refit with the design's prediction.  They differ by where the Jacobian
    is evaluated (the first estimate against the refit), by the new data's noise realisation (sigma is known, so only through the estimate) and by
    the weak prior (factor 10, negligible once identified): asserted within a factor 1.5 for every
    parameter (measured: 1.03, 1.00, 1.00).  Here the repeat ranks first (2.08 nats = 3 ln 2: it
    doubles the information in all three directions) above the low (1.01) and high (1.18) rates,
    which mostly add one direction each.  Flow curves (closed-form model) keep this cheap
    (34 s CPU, mostly compiling the two fits); the dam-break twin with a rheometer transient is in
    benchmarks/calibration/design_twin.py."""
    mat = _material()
    mid = np.geomspace(0.3, 30.0, 4)

    def curve(rates, seed):
        tau, _ = mpmjax.rheometer.steady_flow_curve(mat, jnp.asarray(rates))
        tau = np.asarray(tau) * np.exp(0.05 * np.random.default_rng(seed).standard_normal(len(rates)))
        return FlowCurveExperiment(mat, rates, tau, sigma_ln=0.05)

    fc = curve(mid, 1)
    ps = ParameterSet.from_names(["mu0", "n", "T"], mat, init={"mu0": 5.0, "n": 2.0, "T": 0.4})
    r0 = fit([fc], ps, max_iter=60, rtol=1e-10, patience=3, progress=False)
    u0 = gauss_newton([fc], ps, r0.params)
    rate_sets = (np.geomspace(0.02, 0.2, 4), np.geomspace(50.0, 500.0, 4), mid)
    cands = [flow_curve_candidate(mat, g) for g in rate_sets]
    res = design([fc], ps, r0.params, cands)
    top = res.ranking[0]
    new = curve(rate_sets[top], 2)
    ps1 = ParameterSet.from_names(["mu0", "n", "T"], mat, init=r0.params)
    r1 = fit([fc, new], ps1, max_iter=60, rtol=1e-10, patience=3, progress=False)
    u1 = gauss_newton([fc, new], ps1, r1.params)
    pred = res.std_after[top] * np.asarray([r0.params[k] for k in ps.free])
    print(f"\nfirst curve alone {r0.params} std {u0.std}; top candidate {cands[top].label}; refit {r1.params}; "
          f"predicted std {pred}, refit std {u1.std}, ratio {pred / u1.std}")
    ratio = pred / u1.std
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio


def test_design_cli_rejects_bad_candidates_with_exit_2(tmp_path, capsys):
    """A candidate file with an unknown kind, a negative spacing or an unknown key stops with exit
    status 2 and a message naming the entry, the key, the value and the allowed range (checked
    before any simulation is built)."""
    from mpmjax.cli import main

    data = tmp_path / "p.csv"
    data.write_text("x_m,h_m,t_s\n0.0,0.1,0.5\n0.1,0.05,0.5\n")
    cases = {
        'kind = "viscometer"': "kind = 'viscometer'; allowed: profile, runout, transient",
        'kind = "profile"\ntimes_s = [0.5]\nspacing_m = -0.02': "spacing_m = -0.02; allowed range: > 0 [m]",
        'kind = "transient"\nrates_1_s = [1.0]\nrest = 5': "unknown key(s) ['rest']",
    }
    for body, msg in cases.items():
        f = tmp_path / "c.toml"
        f.write_text("[[candidate]]\n" + body + "\n")
        rc = main(["design", str(data), "--scene", "data/twin-small-dambreak.toml", "--fit", "mu0",
                   "--candidates", str(f), "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert rc == 2 and "candidate 1" in err and msg in err, err
    rc = main(["design", str(data), "--scene", "data/twin-small-dambreak.toml", "--fit", "mu0",
               "--station-spacing-m", "0.02", "--out", str(tmp_path / "o")])
    assert rc == 2 and "--station-spacing-m needs --profile-times" in capsys.readouterr().err
