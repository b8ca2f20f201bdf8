"""Tests of the 0-D Coussot rheometer (mpmjax.rheometer) against exact solutions.

Exact solutions (../shared/REFERENCE.md, Coussot 2002):
  lam(t) = lam_ss + (lam0 - lam_ss) exp(-alpha gdot t), lam_ss = 1/(alpha T gdot);
  tau_ss = mu0 gdot [1 + (alpha T gdot)^-n];
  gdot_c = (n-1)^(1/n)/(alpha T), tau_c = mu0 n (n-1)^(1/n-1)/(alpha T).
All data used for fitting here are SYNTHETIC (generated from known parameters); rheometer
data are fitted with calibration (FlowCurveExperiment, TransientExperiment, calibration.fit.fit).
"""

import csv
import dataclasses
import json
import math
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax
from calibration.experiments import FlowCurveExperiment, TransientExperiment
from calibration.fit import fit as calibrate
from calibration.params import ParameterSet, ParamSpec
from mpmjax import rheometer as R
from mpmjax._rheology import KAPPA, MU0, RHO, Internal, Param, coussot_lambda_exact

# float64 for the accuracy checks (tests/conftest.py does this too).  Parameters are
# built at call time, so enabling it after the imports is enough.
jax.config.update("jax_enable_x64", True)

RATES = (0.1, 1.0, 10.0, 100.0)  # 1/s, thesis Figs. 7, 26, 31
T_SAVE = np.logspace(-2, 3, 200)  # s, 1e-2 .. 1e3 as in the thesis figures
PARAM_SETS = {
    "BASE": R.BASE_VALUES,  # thesis Table 8
    "Mizani": R.MIZANI_VALUES,  # thesis Table 5 (n = 1.074)
    "Mizani_fast": R.MIZANI_FAST_VALUES,  # thesis Table 6 (n = 1.75)
}


def _p(name, **over):
    return R.make_params(**dict(PARAM_SETS[name], **over))


def _rel(a, b):
    return float(jnp.max(jnp.abs(jnp.asarray(a) - jnp.asarray(b)) / jnp.abs(jnp.asarray(b))))


# --------------------------------------------------------------------------------------
# constant shear vs exact solution
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PARAM_SETS))
def test_constant_shear_matches_exact(name):
    p = _p(name)
    # all four rates in one call (k decoupled equations in one solve), outputs (4, 200)
    res = R.constant_shear(p, jnp.asarray(RATES), T_SAVE)
    assert res.lam.shape == (len(RATES), T_SAVE.size)
    for i, gdot in enumerate(RATES):
        lam_ex = coussot_lambda_exact(p.lambda0, gdot, T_SAVE, p.alpha, p.T)
        err = _rel(res.lam[i], lam_ex)
        # rtol = 1e-10 in the solver; the 1e-6 bound of the brief leaves >30x margin
        # for dense-output interpolation at the save times (measured <= 3e-8).
        assert err < 1e-6, (name, gdot, err)
        # mu and tau are the Coussot law of the returned lam, tau = mu gdot.
        mu_ex = jnp.minimum(p.mu0 * (1.0 + lam_ex**p.n), p.mu_max)
        assert _rel(res.mu_pa_s[i], mu_ex) < 1e-5  # d ln mu / d ln lam <= n = 2.5
        np.testing.assert_allclose(res.tau_pa[i], res.mu_pa_s[i] * gdot, rtol=1e-14)
        assert np.all(np.asarray(res.gamma_dot_1_s[i]) == gdot)
        # At t = 1000 s, alpha gdot t >= 36 e-folds: steady state (flow curve) reached.
        tau_ss, mu_ss = R.steady_flow_curve(p, gdot)
        assert abs(float(res.mu_pa_s[i, -1]) / float(mu_ss) - 1.0) < 1e-5
    # a single rate (scalar) gives the same numbers, outputs (200,)
    one = R.constant_shear(p, 1.0, T_SAVE)
    assert one.lam.shape == T_SAVE.shape
    assert _rel(one.lam, coussot_lambda_exact(p.lambda0, 1.0, T_SAVE, p.alpha, p.T)) < 1e-6


def test_viscosity_cap_is_applied():
    # BASE at 0.1 1/s: lam_ss = 1/(1*0.5*0.1) = 20, mu0 (1 + 20^2.5) = 7159.6 > mu_max = 5000.
    p = _p("BASE")
    res = R.constant_shear(p, jnp.asarray(RATES), T_SAVE)
    assert float(res.mu_pa_s[0, -1]) == 5000.0
    assert abs(float(res.lam[0, -1]) - 20.0) < 20.0 * 1e-6  # lam itself is not capped
    # and at 100 1/s the viscosity relaxes towards mu0 (1 + 0.02^2.5) = 4.000226 Pa s
    assert abs(float(res.mu_pa_s[3, -1]) - 4.0 * (1.0 + 0.02**2.5)) < 1e-6


# --------------------------------------------------------------------------------------
# steady flow curve and its minimum
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PARAM_SETS))
def test_flow_curve_minimum_is_critical_point(name):
    p = _p(name, mu_max=1e300)  # uncapped curve: the analytic minimum is global
    gc, tc = (float(x) for x in R.critical_point(p))
    # fixed log grid 1e-4..1e4 1/s (independent of gdot_c, which is not a grid point),
    # spacing h in ln(gdot)
    npts = 200_001
    g = np.geomspace(1e-4, 1e4, npts)
    h = 8 * math.log(10) / (npts - 1)  # 9.2e-5
    tau, _ = R.steady_flow_curve(p, jnp.asarray(g))
    i = int(jnp.argmin(tau))
    # The argmin of a sampled smooth minimum lies within h/2 of the true one in ln(gdot);
    # allow one full spacing.
    assert abs(math.log(g[i] / gc)) <= h, (g[i], gc)
    # d^2 ln(tau)/d(ln gdot)^2 = n - 1 at the minimum, so one spacing off the minimum
    # tau exceeds tau_c by (n-1) h^2/2 (relative); 2x margin, plus round-off.
    n = float(p.n)
    assert 0.0 <= float(tau[i]) / tc - 1.0 <= (n - 1.0) * h * h + 1e-13
    assert float(jnp.min(tau)) >= tc * (1.0 - 1e-13)  # nothing on the grid below tau_c
    # and the derivative vanishes there (automatic differentiation of the flow curve)
    dtau = jax.grad(lambda x: R.steady_flow_curve(p, x)[0])(jnp.asarray(gc))
    assert abs(float(dtau)) * gc / tc < 1e-12


def test_flow_curve_numbers_base_and_cap():
    p = _p("BASE")
    gc, tc = (float(x) for x in R.critical_point(p))
    # BASE: gdot_c = 1.5^0.4 / 0.5 = 2.3522 1/s, tau_c = 4 * 2.5 * 1.5^-0.6 / 0.5 = 15.681 Pa
    assert abs(gc - 1.5**0.4 / 0.5) < 1e-12 and abs(gc - 2.35216) < 1e-5
    assert abs(tc - 20.0 * 1.5**-0.6) < 1e-12 and abs(tc - 15.6811) < 1e-4
    # With the BASE cap (5000 Pa s) gdot_c is still the minimum over [gdot_c/100, 100 gdot_c]
    # (mu_ss(gdot_c) = mu0 n/(n-1) = 6.67 Pa s << mu_max); below ~3e-3 1/s the capped
    # curve tau = mu_max gdot drops below tau_c, so the minimum is only local.
    g = np.geomspace(gc / 100, gc * 100, 40_001)
    tau, mu = R.steady_flow_curve(p, jnp.asarray(g))
    assert abs(math.log(g[int(jnp.argmin(tau))] / gc)) <= math.log(1e4) / 40_000
    assert float(jnp.max(mu)) == 5000.0
    tau_low, _ = R.steady_flow_curve(p, 1e-3)
    assert abs(float(tau_low) - 5.0) < 1e-12 and float(tau_low) < tc


@pytest.mark.parametrize("n", [1.0, 0.8])
def test_critical_point_requires_n_above_one(n):
    with pytest.raises(ValueError, match=r"n > 1.*n = " + str(n).rstrip("0").rstrip(".")):
        R.critical_point(_p("BASE", n=n))


# --------------------------------------------------------------------------------------
# shear-rate steps
# --------------------------------------------------------------------------------------


def _exact_history(p, times, rates, t):
    """Exact piecewise solution: restart the constant-rate solution at each step."""
    lam = float(p.lambda0)
    out = np.empty_like(t)
    bounds = list(times[1:]) + [np.inf]
    for k, (t0, t1, g) in enumerate(zip(times, bounds, rates)):
        sel = (t >= t0) & (t < t1) if k < len(rates) - 1 else (t >= t0)
        out[sel] = np.asarray(coussot_lambda_exact(lam, g, t[sel] - t0, p.alpha, p.T))
        if np.isfinite(t1):
            lam = float(coussot_lambda_exact(lam, g, t1 - t0, p.alpha, p.T))
    return out


@pytest.mark.parametrize(
    "times,rates",
    [
        # break down at 100 1/s, rebuild at 0.1 1/s (third segment repeats the rate)
        ((0.0, 10.0, 500.0), (100.0, 0.1, 0.1)),
        ((0.0, 100.0, 110.0), (0.1, 100.0, 1.0)),  # build, break, partial rebuild
    ],
)
def test_shear_rate_steps_follow_restarted_exact_solution(times, rates):
    p = _p("BASE")
    # 401 uniform points (containing the step times) plus 1 ms after each step;
    # same shape for both schedules, so one compilation serves both.
    t = np.sort(np.concatenate([np.linspace(0.0, 1000.0, 401), np.asarray(times[1:]) + 1e-3]))
    res = R.shear_history(p, times, rates, t)
    lam_ex = _exact_history(p, np.asarray(times), rates, t)
    err = _rel(res.lam, lam_ex)
    assert err < 1e-6, err
    # the imposed rate is reported right-continuously
    for t0, g in zip(times, rates):
        assert float(res.gamma_dot_1_s[np.searchsorted(t, t0)]) == g
    np.testing.assert_allclose(res.tau_pa, res.mu_pa_s * res.gamma_dot_1_s, rtol=1e-14)


def test_shear_history_rejects_bad_schedule():
    p = _p("BASE")
    with pytest.raises(ValueError, match="same length"):
        R.shear_history(p, [0.0, 1.0], [1.0], [0.0, 2.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        R.shear_history(p, [0.0, 0.0], [1.0, 2.0], [0.0, 2.0])


# --------------------------------------------------------------------------------------
# gradients
# --------------------------------------------------------------------------------------


def test_gradient_matches_finite_differences_and_exact():
    p = _p("BASE")

    # rheometer output: sum of ln(mu) over the save times at 1 1/s (cap inactive there)
    def out(p):
        return jnp.sum(jnp.log(R.constant_shear(p, 1.0, T_SAVE).mu_pa_s))

    def out_exact(p):
        lam = coussot_lambda_exact(p.lambda0, 1.0, T_SAVE, p.alpha, p.T)
        return jnp.sum(jnp.log(p.mu0 * (1.0 + lam**p.n)))

    g = jax.jit(jax.grad(out))(p)  # also checks that the solve is jit-able under grad
    g_ex = jax.grad(out_exact)(p)
    for k in ("mu0", "alpha", "T", "n", "lambda0"):
        v = float(getattr(p, k))
        # central FD, step 1e-4 v: truncation ~1e-8, solver noise ~rtol/1e-4 = 1e-6 relative
        h = 1e-4 * v
        fd = (out(p._replace(**{k: jnp.asarray(v + h)})) - out(p._replace(**{k: jnp.asarray(v - h)}))) / (2 * h)
        ad = float(getattr(g, k))
        assert abs(ad / float(fd) - 1.0) < 1e-4, (k, ad, float(fd))
        # and against the derivative of the exact solution (solver error ~1e-8)
        assert abs(ad / float(getattr(g_ex, k)) - 1.0) < 1e-6, (k, ad, float(getattr(g_ex, k)))


# --------------------------------------------------------------------------------------
# fitting (synthetic data)
# --------------------------------------------------------------------------------------

TRUE = dict(mu0=4.0, alpha=1.0, T=0.5, n=2.5, lambda0=1.5, mu_max=5000.0)


def _log_specs(**init):
    """Free parameters with the unbounded log transform, z = ln(theta / init): the
    parametrisation of the old rheometer.fit.  With it d loss/d z_alpha and d loss/d z_T are
    bitwise equal for flow-curve data (alpha and T enter only as alpha*T), so the optimiser
    moves ln alpha and ln T together; a bounded log transform maps z to ln theta through each
    parameter's own sigmoid and would let alpha/T drift."""
    return [ParamSpec(k, v) for k, v in init.items()]


@pytest.mark.parametrize("method,max_iter", [("adam", 2000), ("lbfgs", 100)])
def test_fit_flow_curve_recovers_identifiable_params(method, max_iter):
    true = R.make_params(**TRUE)
    # SYNTHETIC steady flow curve, 0.2..200 1/s (cap inactive: mu_ss(0.2) = 2.4e3 Pa s)
    g = np.geomspace(0.2, 200.0, 25)
    tau, _ = R.steady_flow_curve(true, g)
    exp = FlowCurveExperiment(true, g, np.asarray(tau))  # sigma_ln = 0.05: loss = mean(r_ln^2)/0.05^2
    # start about a factor 2 off: mu0 /2, alpha x2 (alpha*T x2), n x0.6; lambda0, mu_max fixed
    ps = ParameterSet(_log_specs(mu0=2.0, alpha=2.0, T=0.5, n=1.5), true)
    # rtol = 0, atol = 0: run until the gradient norm in z is below gtol (or max_iter); for Adam,
    # whose loss is not monotonic, patience = max_iter turns the stagnation test off.
    fr = calibrate(
        [exp], ps, method=method, max_iter=max_iter, learning_rate=0.05, rtol=0.0, gtol=1e-12, atol=0.0,
        patience=max_iter if method == "adam" else 5, progress=False,
    )  # fmt: skip
    assert fr.loss_final < 0.05 * fr.loss_initial  # > 95 % drop
    # noise-free data: the minimum is exactly zero.  Bound: the old one, mean ln-residual^2 < 1e-12,
    # times 1/sigma_ln^2 = 400 (measured ~1e-27 to 1e-29).
    assert fr.loss_final < 4e-10
    assert fr.history.shape == (fr.iterations + 1, 1) and fr.history[0, 0] == fr.loss_initial
    q = fr.params
    # Identifiable: mu0, n, alpha*T.  The ln-residual vector (25 points) has norm
    # sigma_ln sqrt(25 L) < 5e-6; the smallest singular value of d r / d(ln mu0, ln n, ln aT)
    # is O(0.1) here, so the parameter error is < ~5e-5; assert 1e-4 (measured ~1e-15).
    for got, want in ((q["mu0"], 4.0), (q["n"], 2.5), (q["alpha"] * q["T"], 0.5)):
        assert abs(got / want - 1.0) < 1e-4, (got, want)
    # Not identifiable: alpha/T.  d tau_ss/d ln(alpha) == d tau_ss/d ln(T), so the
    # gradient never changes ln(alpha) - ln(T): the ratio stays at its initial value 4
    # (truth: 2) to rounding (measured ~2e-16), and alpha, T individually are NOT recovered.
    assert abs(q["alpha"] / q["T"] / 4.0 - 1.0) < 1e-10
    assert abs(q["alpha"] - 1.0) > 0.3 and abs(q["T"] - 0.5) > 0.1


def test_flow_curve_jacobian_is_rank_deficient_in_alpha_T():
    true = R.make_params(**TRUE)
    g = jnp.geomspace(0.2, 200.0, 25)

    def resid(th):
        q = true._replace(mu0=jnp.exp(th[0]), alpha=jnp.exp(th[1]), T=jnp.exp(th[2]), n=jnp.exp(th[3]))
        return jnp.log(R.steady_flow_curve(q, g)[0])

    th0 = jnp.log(jnp.array([4.0, 1.0, 0.5, 2.5]))
    J = jax.jacfwd(resid)(th0)
    np.testing.assert_allclose(J[:, 1], J[:, 2], rtol=1e-12, atol=1e-15)
    s = np.linalg.svd(np.asarray(J), compute_uv=False)
    assert s[-1] / s[0] < 1e-12  # exactly one null direction: ln(alpha) - ln(T)
    assert s[-2] / s[0] > 1e-3  # the other three combinations are identified


def test_fit_transient_identifies_alpha_and_T_separately():
    true = R.make_params(**TRUE)
    # SYNTHETIC constant-shear transients at 0.5 and 5 1/s, t = 0.01..100 s
    t = np.geomspace(1e-2, 1e2, 20)
    rates = np.array([0.5, 5.0])
    lam = np.stack([np.asarray(coussot_lambda_exact(true.lambda0, r, t, true.alpha, true.T)) for r in rates])
    mu = 4.0 * (1.0 + lam**2.5)  # exact solution (cap not reached: mu <= 58 Pa s)
    exp = TransientExperiment(true, t, rates, mu)  # solver rtol 1e-8, atol 1e-10 (default)
    assert exp.n_residuals == 40
    # Start with alpha x2 and T x1.5: alpha/T = 2.67 (truth 2), alpha*T = 1.5 (truth 0.5).
    ps = ParameterSet(_log_specs(alpha=2.0, T=0.75), true)
    # Adam, 400 iterations at learning rate 0.1 (the old test's settings); cheaper to compile
    # than L-BFGS's line search (L-BFGS converges in ~17 iterations, but its compilation
    # doubles the test's time).  The gradient is forward mode (2 parameters).
    fr = calibrate(
        [exp], ps, method="adam", max_iter=400, learning_rate=0.1, rtol=0.0, atol=0.0, patience=400, progress=False
    )
    assert fr.gradient == "forward"
    assert fr.loss_final < 1e-8 * fr.loss_initial  # converged (measured ~3.5e-14)
    q = fr.params
    # The relaxation rate alpha*gdot fixes alpha and lam_ss = 1/(alpha T gdot) then T,
    # so both are recovered individually (unlike the flow-curve fit).  The model is solved
    # at rtol 1e-8 against exact data: a model error ~1e-8..1e-7 in ln(mu) (dense output),
    # i.e. parameter errors ~1e-6 (measured 4e-7); assert 1e-4.
    assert abs(q["alpha"] - 1.0) < 1e-4, q["alpha"]
    assert abs(q["T"] / 0.5 - 1.0) < 1e-4, q["T"]


def test_fit_rejects_bad_arguments():
    p = R.make_params(**TRUE)
    g, tau = [1.0, 2.0], [10.0, 12.0]
    # unknown parameter names
    with pytest.raises(ValueError, match="parameter 'tau_y' is not a field of the scene's material CoussotParams"):
        ParameterSet.from_names(["tau_y"], p)
    with pytest.raises(ValueError, match="'bogus': not a parameter of coussot; allowed: rho, kappa, mu0"):
        R.make_params(bogus=1.0)
    # bad values: a material outside its declared range, a log-fitted start <= 0, bad data
    with pytest.raises(ValueError, match=r"flow curve: mu0 = -1 is invalid; allowed range: > 0 Pa s"):
        FlowCurveExperiment(p._replace(mu0=jnp.asarray(-1.0)), g, tau)
    with pytest.raises(ValueError, match=r"transient: n = 12 is invalid; allowed range: > 0 and <= 10"):
        TransientExperiment(p._replace(n=jnp.asarray(12.0)), [0.0, 1.0], [1.0], [[5.0, 6.0]])
    with pytest.raises(ValueError, match=r"mu0: init = -1 \[Pa s\]; the log transform needs a value > 0"):
        ParameterSet([ParamSpec("mu0", -1.0)], p)
    with pytest.raises(ValueError, match=r"tau_pa\[1\] = -12.0; allowed range: > 0 and finite"):
        FlowCurveExperiment(p, g, [10.0, -12.0])
    with pytest.raises(ValueError, match=r"mu_pa_s has shape \(2,\); expected \(rates, times\) = \(1, 2\)"):
        TransientExperiment(p, [0.0, 1.0], [1.0], [5.0, 6.0])
    with pytest.raises(ValueError, match=r"gamma_dot_1_s\[0\] = -1.0; allowed range: >= 0"):
        TransientExperiment(p, [0.0, 1.0], [-1.0], [[5.0, 6.0]])
    # a bad optimiser
    with pytest.raises(ValueError, match="method = 'bogus' is invalid"):
        calibrate([FlowCurveExperiment(p, g, tau)], ParameterSet.from_names(["mu0"], p), method="bogus")


# --------------------------------------------------------------------------------------
# other laws: the rheometer reads the law's declared rate, viscosity and steady state
# --------------------------------------------------------------------------------------


def test_laws_without_internal_variables_need_no_solve():
    t = np.array([0.0, 1.0, 10.0])
    newt = R.make_params(law="newtonian", mu=2.0)
    res = R.constant_shear(newt, jnp.array([1.0, 10.0]), t)
    assert res.internal == {} and res.mu_pa_s.shape == (2, 3)
    np.testing.assert_array_equal(res.mu_pa_s, 2.0)
    np.testing.assert_array_equal(res.tau_pa, 2.0 * np.array([[1.0], [10.0]]) * np.ones(3))
    with pytest.raises(AttributeError, match="no internal variable 'lam'"):
        res.lam
    # Bingham (Papanastasiou, default options): mu = mu + tau_y (1 - exp(-m gdot))/gdot at all t
    bing = R.make_params(law=mpmjax.Bingham, mu=1.0, tau_y=10.0)
    assert float(bing.m) == 100.0  # the declared default
    res = R.shear_history(bing, [0.0, 1.0], [2.0, 5.0], [0.5, 2.0])
    want = 1.0 + 10.0 * (1.0 - np.exp(-100.0 * np.array([2.0, 5.0]))) / np.array([2.0, 5.0])
    np.testing.assert_allclose(res.mu_pa_s, want, rtol=1e-14)
    tau, mu = R.steady_flow_curve(bing, jnp.array([2.0, 5.0]))
    np.testing.assert_allclose(mu, want, rtol=1e-14)
    R.validate_params(bing)
    with pytest.raises(ValueError, match="tau_y = -1 is invalid; allowed range: >= 0 Pa"):
        R.validate_params(bing._replace(tau_y=jnp.asarray(-1.0)))
    with pytest.raises(ValueError, match="critical_point is defined for the Coussot law only; got bingham"):
        R.critical_point(bing)
    # a flow-curve experiment of another law: zero residual at the truth
    hb = R.make_params(law="herschel_bulkley", tau_y=5.0, K=2.0, n_hb=0.5)
    g = np.geomspace(0.1, 100.0, 8)
    fc = FlowCurveExperiment(hb, g, np.asarray(R.steady_flow_curve(hb, g)[0]))
    np.testing.assert_allclose(fc.residuals({"K": 2.0, "n_hb": 0.5}), 0.0, atol=1e-12)
    assert float(jnp.max(jnp.abs(fc.residuals({"K": 3.0})))) > 1.0


def test_a_registered_law_with_two_internal_variables(tmp_path):
    """The rheometer integrates any law's declared rate (here two internal variables, a
    dict pytree for diffrax) and writes each variable under its label."""
    k_param = Param("k_fc", "material.test_k_fc", "-", "Test: breakdown per unit strain.", 0.5, lo=0.0, lo_open=True)
    a0 = Param("a0_fc", "material.test_a0_fc", "-", "Test: initial a.", 1.0, lo=0.0)

    class P(NamedTuple):
        rho: jnp.ndarray
        kappa: jnp.ndarray
        mu0: jnp.ndarray
        k_fc: jnp.ndarray
        a0_fc: jnp.ndarray

    @dataclasses.dataclass(frozen=True)
    class TwoStage(mpmjax.Law):
        """Test law: da/dt = -k gdot a, db/dt = k gdot a, mu = mu0 (1 + a + 2 b)."""

        name: ClassVar[str] = "test_two_stage"
        params_type: ClassVar[type] = P
        params: ClassVar[tuple] = (RHO, KAPPA, MU0, k_param, a0)
        internals: ClassVar[tuple] = (
            Internal("a", "a_structure", "-", "a", "a0_fc"),
            Internal("b", "b_broken", "-", "b", "a0_fc"),
        )

        def rate(self, params, shear, internal):
            d = params.k_fc * shear * internal["a"]
            return {"a": -d, "b": d}

        def update_internal(self, params, shear, internal, dt):
            e = jnp.exp(-params.k_fc * shear * dt)
            return {"a": internal["a"] * e, "b": internal["b"] + internal["a"] * (1 - e)}

        def mu(self, params, shear, internal):
            return params.mu0 * (1.0 + internal["a"] + 2.0 * internal["b"])

        def max_viscosity(self, params):
            return 3.0 * params.mu0 * params.a0_fc

        def steady_internal(self, params, shear):
            return {"a": jnp.zeros_like(shear), "b": 2.0 * params.a0_fc + 0 * shear}

    mpmjax.register_law(TwoStage)
    try:
        p = R.make_params(law="test_two_stage")  # declared defaults (mu0 4, k 0.5, a0 1)
        t = np.geomspace(1e-2, 10.0, 30)
        res = R.constant_shear(p, jnp.array([1.0, 4.0]), t)
        e = np.exp(-0.5 * np.array([[1.0], [4.0]]) * t)
        # solver rtol 1e-10: global errors ~1e-10 absolute where a has decayed to ~1e-9 (measured)
        np.testing.assert_allclose(res.internal["a"], e, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(res.internal["b"], 2.0 - e, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(res.mu_pa_s, 4.0 * (1.0 + e + 2.0 * (2.0 - e)), rtol=1e-7)
        meta = R.write_outputs(tmp_path, p, [1.0, 4.0], t)
        assert meta["csv_columns"] == ["t_s", "gamma_dot_1_s", "a_structure", "b_broken", "mu_pa_s", "tau_pa"]
        assert meta["critical_point"] is None and "Coussot law only" in meta["critical_point_note"]
        assert meta["steady_state"][0]["b_broken_ss"] == 2.0 and meta["steady_state"][0]["mu_ss_pa_s"] == 20.0
        assert meta["params"]["k_fc"] == {"value": 0.5, "unit": "-"}
        with open(tmp_path / "rheometer.csv") as fh:
            assert next(csv.reader(fh)) == meta["csv_columns"]
    finally:
        mpmjax.unregister_law("test_two_stage")


# --------------------------------------------------------------------------------------
# CLI and files
# --------------------------------------------------------------------------------------


def _rheometer(argv):
    """``mpmjax rheometer ARGV``: its exit status."""
    from mpmjax.cli import main

    return main(["rheometer", *argv])


def test_cli_writes_outputs(tmp_path, capsys):
    out = tmp_path / "rheo"
    rc = _rheometer(["--out", str(out), "--rates", "0.1,1,10,100", "--t-end", "1000"])
    assert rc == 0
    for f in ("viscosity_vs_time.png", "flow_curve.png", "rheometer.csv", "rheometer.json"):
        assert (out / f).stat().st_size > 0
    for f in ("viscosity_vs_time.png", "flow_curve.png"):
        assert (out / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(out / "rheometer.csv") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["t_s", "gamma_dot_1_s", "lambda", "mu_pa_s", "tau_pa"]
    data = np.array(rows[1:], dtype=float)
    assert data.shape == (4 * 200, 5)
    assert sorted(set(data[:, 1])) == [0.1, 1.0, 10.0, 100.0]
    assert abs(data[:, 0].min() - 1e-2) < 1e-14 and abs(data[:, 0].max() - 1e3) < 1e-9
    p = R.make_params()  # CLI defaults = thesis BASE
    lam_ex = coussot_lambda_exact(p.lambda0, data[:, 1], data[:, 0], p.alpha, p.T)
    assert _rel(data[:, 2], lam_ex) < 1e-6
    np.testing.assert_allclose(data[:, 4], data[:, 3] * data[:, 1], rtol=1e-10)
    meta = json.loads((out / "rheometer.json").read_text())
    assert meta["params"]["mu0"] == {"value": 4.0, "unit": "Pa s"}
    assert meta["params"]["T"]["unit"] == "s" and meta["params"]["mu_max"]["value"] == 5000.0
    assert abs(meta["critical_point"]["gamma_dot_c_1_s"] - 1.5**0.4 / 0.5) < 1e-12
    assert abs(meta["critical_point"]["tau_c_pa"] - 20.0 * 1.5**-0.6) < 1e-12
    assert set(meta["files"]) == {"viscosity_vs_time.png", "flow_curve.png", "rheometer.csv", "rheometer.json"}
    assert "critical point" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv,option",
    [
        (["--mu0", "-1"], "--mu0"),
        (["--alpha", "0"], "--alpha"),
        (["--T", "abc"], "--T"),
        (["--n", "nan"], "--n"),
        (["--lambda0", "-0.5"], "--lambda0"),
        (["--mu-max", "2"], "--mu-max"),  # below mu0 = 4
        (["--rates", "0.1,,10"], "--rates"),
        (["--rates", "1,-3"], "--rates"),
        (["--t-end", "0"], "--t-end"),
    ],
)
def test_cli_rejects_bad_input(tmp_path, capsys, argv, option):
    out = tmp_path / "o"
    rc = _rheometer(argv + ["--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert option in err and "allowed range" in err, err
    assert argv[1] in err  # names the offending value
    assert "Traceback" not in err
    assert not out.exists()  # nothing written
