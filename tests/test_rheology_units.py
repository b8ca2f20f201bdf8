"""Unit tests of the rheology building blocks (pure functions, no MPM run).

Every number checked here is an exact or limiting value quoted in
../shared/REFERENCE.md ("Constitutive laws", "Coussot at constant shear rate") or
follows from the closed form of the update under test.  All arithmetic is float64
(conftest enables x64), so "exact" identities are checked at a few hundred ulps.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mpmjax._constitutive import deviatoric_update, shear_measures, shear_rate
from mpmjax._rheology import (
    Bingham,
    BinghamParams,
    Coussot,
    CoussotParams,
    HerschelBulkley,
    HerschelBulkleyParams,
    coussot_lambda_euler,
    coussot_lambda_exact,
    coussot_mu,
)

F64 = jnp.float64
# Round-off tolerance for identities evaluated in float64 with a handful of
# transcendental calls (exp/expm1/sqrt): a few hundred ulps of 2.2e-16.
RT_EXACT = 1e-12


def simple_shear_L(g, dim):
    """Velocity gradient of simple shear v_x = g y: L = grad v, L[0, 1] = g."""
    L = np.zeros((1, dim, dim))
    L[0, 0, 1] = g
    return jnp.asarray(L, F64)


# --------------------------------------------------------------------------------------
# Shear measures (REFERENCE.md "Shear-rate measure", thesis eq. 3.8 and Annex 1)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("g", [1e-3, 0.7, 5.0, 250.0])
def test_shear_rate_of_simple_shear(dim, g):
    """standard sqrt(2 d':d') recovers the imposed rate g; the thesis measure is g^2/8."""
    L = simple_shear_L(g, dim)
    dprime, dd = shear_measures(L, dim)
    # d' of simple shear is the symmetric off-diagonal g/2 (traceless already).
    expect = np.zeros((dim, dim))
    expect[0, 1] = expect[1, 0] = g / 2
    np.testing.assert_allclose(np.asarray(dprime[0]), expect, rtol=0, atol=RT_EXACT * g)
    np.testing.assert_allclose(float(shear_rate(dd, "standard")[0]), g, rtol=RT_EXACT)
    np.testing.assert_allclose(float(shear_rate(dd, "thesis")[0]), g**2 / 8, rtol=RT_EXACT)


@pytest.mark.parametrize("dim", [2, 3])
def test_shear_rate_ignores_rotation_and_sees_plane_strain_dilation(dim):
    """A rigid rotation has zero rate; an isotropic in-plane expansion in 2D plane strain has
    d'_zz = -tr d / 3 != 0 (the out-of-plane deviator), which shear_measures must include."""
    w = 3.0
    L = np.zeros((1, dim, dim))
    L[0, 0, 1], L[0, 1, 0] = w, -w
    _, dd = shear_measures(jnp.asarray(L, F64), dim)
    assert float(shear_rate(dd, "standard")[0]) == 0.0
    e = 0.2
    L = np.zeros((1, dim, dim))
    L[0, 0, 0] = L[0, 1, 1] = e  # in-plane expansion, no z stretching
    _, dd = shear_measures(jnp.asarray(L, F64), dim)
    # 3-D deviator of diag(e, e, 0): tr = 2e; d' = diag(e/3, e/3, -2e/3); d':d' = 6 e^2/9.
    np.testing.assert_allclose(float(dd[0]), 6 * e**2 / 9, rtol=RT_EXACT)


def test_shear_rate_gradient_finite_at_rest():
    """The standard rate sqrt(.) must not give NaN gradients at L = 0 (MPM at rest)."""

    def f(g):
        L = jnp.zeros((1, 2, 2), F64).at[0, 0, 1].set(g)
        return shear_rate(shear_measures(L, 2)[1], "standard")[0]

    assert np.isfinite(float(jax.grad(f)(0.0)))


# --------------------------------------------------------------------------------------
# Coussot structure update (REFERENCE.md "Coussot (2002)")
# --------------------------------------------------------------------------------------

ALPHA, T_S = 1.0, 0.5  # thesis BASE (Table 8)
LAM0 = 1.5


def lam_closed_form(t, gdot, lam0=LAM0, alpha=ALPHA, T=T_S):
    """lam(t) = lam_ss + (lam0 - lam_ss) exp(-alpha gdot t), lam_ss = 1/(alpha T gdot)."""
    lam_ss = 1.0 / (alpha * T * gdot)
    return lam_ss + (lam0 - lam_ss) * np.exp(-alpha * gdot * t)


def iterate(update, lam0, gdot, dt, n):
    def body(lam, _):
        lam = update(lam, gdot, dt, ALPHA, T_S)
        return lam, lam

    _, hist = jax.lax.scan(body, jnp.asarray(lam0, F64), None, length=n)
    return np.asarray(hist)


@pytest.mark.parametrize("a_dt", [1e-4, 0.1, 1.0, 2.5, 50.0])  # alpha * gdot * dt
def test_coussot_exact_update_matches_closed_form_for_any_dt(a_dt):
    """At constant rate the exponential update is the exact solution, whatever dt is."""
    gdot = 4.0
    dt = a_dt / (ALPHA * gdot)
    n = 400
    hist = iterate(coussot_lambda_exact, LAM0, gdot, dt, n)
    t = dt * np.arange(1, n + 1)
    # Composition of n exact steps: error grows at most linearly in n, ~n ulps.
    np.testing.assert_allclose(hist, lam_closed_form(t, gdot), rtol=RT_EXACT)
    assert np.all(hist > 0)


def test_coussot_euler_fails_where_exact_stays_positive():
    """alpha gdot dt = 50: explicit Euler (thesis eq. 3.9) multiplies the distance to
    lam_ss by (1 - 50) = -49 each step, so it goes negative at once and oscillates with
    growing amplitude; the exact update lands on lam_ss to within exp(-50) ~ 2e-22."""
    gdot = 10.0
    dt = 50.0 / (ALPHA * gdot)
    lam_ss = 1.0 / (ALPHA * T_S * gdot)
    euler = iterate(coussot_lambda_euler, LAM0, gdot, dt, 6)
    exact = iterate(coussot_lambda_exact, LAM0, gdot, dt, 6)
    assert euler[0] < 0  # negative structure after one step
    assert np.all(np.sign(euler[:-1] - lam_ss) != np.sign(euler[1:] - lam_ss))  # oscillates
    err = np.abs(euler - lam_ss)
    np.testing.assert_allclose(err[1:] / err[:-1], 49.0, rtol=1e-9)  # |1 - a dt| = 49 amplification
    assert np.all(exact > 0)
    np.testing.assert_allclose(exact, lam_ss, rtol=1e-15)


@pytest.mark.parametrize("dt", [1e-6, 1e-3, 0.7, 40.0])
def test_coussot_exact_update_pure_aging_at_rest(dt):
    """gdot = 0: dlam/dt = 1/T, so lam + dt/T exactly (linear aging, no divide-by-zero)."""
    lam = jnp.asarray([0.0, 1.5, 20.0], F64)
    out = coussot_lambda_exact(lam, jnp.zeros(3, F64), dt, ALPHA, T_S)
    np.testing.assert_allclose(np.asarray(out), np.asarray(lam) + dt / T_S, rtol=RT_EXACT)


def test_coussot_exact_update_gradients_at_rest():
    """Derivatives at gdot = 0 are finite and equal their analytic limits:
    d lam+/d gdot = -alpha dt (lam + dt/(2T)), d lam+/d alpha = 0, d lam+/d T = -dt/T^2."""
    lam, dt = 1.5, 0.01
    f = lambda g, a, T: coussot_lambda_exact(jnp.asarray(lam, F64), g, dt, a, T)  # noqa: E731
    dg, da, dT = jax.grad(f, argnums=(0, 1, 2))(jnp.asarray(0.0, F64), jnp.asarray(ALPHA, F64), jnp.asarray(T_S, F64))
    # The small-a branch is the 2-term series of (1 - e^{-a t})/a, exact in its first derivative.
    np.testing.assert_allclose(float(dg), -ALPHA * dt * (lam + dt / (2 * T_S)), rtol=RT_EXACT)
    assert float(da) == 0.0
    np.testing.assert_allclose(float(dT), -dt / T_S**2, rtol=RT_EXACT)
    # Across the branch switch (a t = 1e-6) the value is continuous to O((a t)^2 t) ~ 1e-14 t.
    a_t = 1e-6
    g_lo, g_hi = a_t / dt * (1 - 1e-9), a_t / dt * (1 + 1e-9)
    lo, hi = float(f(g_lo, ALPHA, T_S)), float(f(g_hi, ALPHA, T_S))
    np.testing.assert_allclose(lo, hi, rtol=1e-12)


def test_coussot_model_holds_lam_behind_gate_and_caps_mu():
    """Coussot.viscosity: aging=False freezes lam; mu = min(mu0 (1 + lam^n), mu_max)."""
    p = CoussotParams(*(jnp.asarray(v, F64) for v in (1850.0, 1.5e4, 4.0, ALPHA, T_S, 2.5, LAM0, 5000.0)))
    lam = jnp.asarray([1.5, 1.5, 100.0], F64)
    shear = jnp.asarray([2.0, 2.0, 0.0], F64)
    gate = jnp.asarray([True, False, True])
    mu, internal = Coussot().viscosity(p, shear, {"lam": lam}, 0.1, gate)
    lam_new = np.asarray(internal["lam"])
    np.testing.assert_allclose(lam_new[0], float(coussot_lambda_exact(1.5, 2.0, 0.1, ALPHA, T_S)), rtol=RT_EXACT)
    assert lam_new[1] == 1.5
    np.testing.assert_allclose(np.asarray(mu)[:2], 4.0 * (1 + lam_new[:2] ** 2.5), rtol=RT_EXACT)
    assert float(mu[2]) == 5000.0  # 4 (1 + 100.2^2.5) ~ 4e5 is capped
    # steady viscosity mu_ss = mu0 [1 + (alpha T gdot)^-n] (REFERENCE.md)
    g = 3.0
    np.testing.assert_allclose(float(coussot_mu(1 / (ALPHA * T_S * g), 4.0, 2.5, 5000.0)),
                               4.0 * (1 + (ALPHA * T_S * g) ** -2.5), rtol=RT_EXACT)


# --------------------------------------------------------------------------------------
# Bingham and Herschel-Bulkley (REFERENCE.md "Bingham bi-viscosity", "Herschel-Bulkley")
# --------------------------------------------------------------------------------------

def bingham_params(mu=0.65, tau_y=36.0, alpha_b=100.0, m=100.0):
    # Henriquez & Simms gold tailings (REFERENCE.md scenario 3): tau_y = 36 Pa, mu = 0.65 Pa s.
    return BinghamParams(*(jnp.asarray(v, F64) for v in (1400.0, 1.5e4, mu, tau_y, alpha_b, m)))


def test_bingham_biviscosity_continuous_at_switch_and_exact_above():
    p = bingham_params()
    model = Bingham(variant="biviscosity", shear_measure="standard")
    mu, ty, ab = 0.65, 36.0, 100.0
    gc = ty / ((ab - 1) * mu)  # switch rate
    g = jnp.asarray([gc * (1 - 1e-12), gc * (1 + 1e-12)], F64)
    m_eff, _ = model.viscosity(p, g, {}, 1e-3, True)
    # Both sides equal alpha_b mu to O(1e-12) relative: the law is continuous.
    np.testing.assert_allclose(np.asarray(m_eff), ab * mu, rtol=1e-10)
    # Above the switch the stress is exactly Bingham: tau = tau_y + mu gdot.
    g = jnp.asarray(np.geomspace(gc * 1.001, 1e4, 50), F64)
    m_eff, _ = model.viscosity(p, g, {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff * g), ty + mu * np.asarray(g), rtol=RT_EXACT)
    # Below it: the Newtonian branch alpha_b mu.
    m_eff, _ = model.viscosity(p, jnp.asarray([0.0, 0.5 * gc], F64), {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff), ab * mu, rtol=0)
    assert float(model.max_viscosity(p)) == pytest.approx(ab * mu, rel=1e-15)


def test_bingham_biviscosity_thesis_measure_switch():
    """Thesis measure (II = gdot^2/8 in simple shear): switch at II = tau_y/(2 alpha_b mu) and
    mu + tau_y/(2 II) above it, as in the thesis's code (REFERENCE.md)."""
    p = bingham_params()
    model = Bingham(variant="biviscosity", shear_measure="thesis")
    II_c = 36.0 / (2 * 100.0 * 0.65)
    m_eff, _ = model.viscosity(p, jnp.asarray([0.5 * II_c, 2 * II_c], F64), {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff), [65.0, 0.65 + 36.0 / (4 * II_c)], rtol=RT_EXACT)


def test_papanastasiou_limits():
    mu, ty, m = 0.65, 36.0, 100.0
    p = bingham_params(m=m)
    model = Bingham(variant="papanastasiou")
    # Large m gdot: e^{-m gdot} <= e^{-100} ~ 4e-44, so mu_eff = tau_y/gdot + mu to round-off.
    g = jnp.asarray([1.0, 10.0, 1e3], F64)
    m_eff, _ = model.viscosity(p, g, {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff), ty / np.asarray(g) + mu, rtol=RT_EXACT)
    # At rest: the limit mu + tau_y m (exactly at 0; within O(m gdot / 2) relative just above).
    m_eff, _ = model.viscosity(p, jnp.asarray([0.0, 1e-10], F64), {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff), mu + ty * m, rtol=1e-8)
    assert float(model.max_viscosity(p)) == pytest.approx(mu + ty * m, rel=1e-15)
    # Finite, correct slope at rest: d mu_eff/d gdot (0) = -tau_y m^2 / 2.
    dmu = jax.grad(lambda s: model.viscosity(p, s[None], {}, 1e-3, True)[0][0])(jnp.asarray(0.0, F64))
    np.testing.assert_allclose(float(dmu), -ty * m**2 / 2, rtol=1e-9)
    # Monotone decreasing mu_eff and increasing stress: a well-posed flow curve.
    g = jnp.asarray(np.geomspace(1e-8, 1e4, 400), F64)
    m_eff = np.asarray(model.viscosity(p, g, {}, 1e-3, True)[0])
    assert np.all(np.diff(m_eff) < 0) and np.all(np.diff(m_eff * np.asarray(g)) > 0)


def test_herschel_bulkley_law_and_cap():
    ty, K, n_hb, m, mu_max = 20.0, 3.0, 0.5, 1e3, 500.0
    p = HerschelBulkleyParams(*(jnp.asarray(v, F64) for v in (1400.0, 1.5e4, ty, K, n_hb, m, mu_max)))
    model = HerschelBulkley()
    # Yielded (m gdot >= 1e3 so the exponential is gone): tau = tau_y + K gdot^n.
    g = jnp.asarray([1.0, 30.0, 1e3], F64)
    m_eff, _ = model.viscosity(p, g, {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff * g), ty + K * np.asarray(g) ** n_hb, rtol=RT_EXACT)
    # Near rest the shear-thinning term (gdot^-0.5) and tau_y m = 2e4 both exceed the cap.
    m_eff, _ = model.viscosity(p, jnp.asarray([0.0, 1e-9, 1e-3], F64), {}, 1e-3, True)
    np.testing.assert_allclose(np.asarray(m_eff), mu_max, rtol=0)
    assert np.all(np.isfinite(np.asarray(jax.grad(
        lambda s: model.viscosity(p, s, {}, 1e-3, True)[0].sum())(jnp.asarray([0.0, 1e-3, 1.0], F64)))))


# --------------------------------------------------------------------------------------
# Maxwell deviatoric update (_constitutive.deviatoric_update)
# --------------------------------------------------------------------------------------

G_MOD = 1.5e4  # Maxwell modulus = thesis bulk modulus kappa (the default G)


def _shear_inputs(g, n=1, dim=2):
    L = jnp.broadcast_to(simple_shear_L(g, dim), (n, dim, dim))
    dprime, _ = shear_measures(L, dim)
    return L, dprime


def test_maxwell_viscous_limit():
    """mu << G dt: the memory e^{-G dt/mu} vanishes and tau = 2 mu d' exactly."""
    dt, g = 1e-3, 7.0
    L, dprime = _shear_inputs(g, 3)
    mu = jnp.asarray([1e-3, 0.1, 0.3], F64)  # G dt/mu = 1.5e4, 150, 50: e^-50 ~ 2e-22
    tau0 = jnp.asarray(np.random.default_rng(0).normal(size=(3, 2, 2)) * 1e3, F64)
    tau0 = 0.5 * (tau0 + jnp.swapaxes(tau0, 1, 2))
    tau = deviatoric_update(tau0, L, dprime, mu, G_MOD, dt, "maxwell", "lag")
    # The memory term |tau0| e^{-G dt/mu} <= 1e3 Pa * e^{-50} ~ 2e-19 Pa: atol 1e-15 Pa, and the
    # viscous part 2 mu d' (7e-3 .. 2.1 Pa) to round-off.
    np.testing.assert_allclose(np.asarray(tau), 2 * np.asarray(mu)[:, None, None] * np.asarray(dprime),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.asarray(deviatoric_update(tau0, L, dprime, mu, G_MOD, dt, "explicit", "lag")),
                               2 * np.asarray(mu)[:, None, None] * np.asarray(dprime), rtol=RT_EXACT)


def test_maxwell_elastic_limit_and_bound():
    """mu -> huge: an elastic (hypo-elastic, Jaumann) increment tau+ - tau* = 2 G dt d'
    (relative error G dt/(2 mu)); for every mu the increment is bounded by 2 G dt |d'|."""
    dt, g = 1e-3, 7.0
    L, dprime = _shear_inputs(g)
    tau0 = jnp.zeros((1, 2, 2), F64)
    mu = jnp.asarray([1e8], F64)
    tau = deviatoric_update(tau0, L, dprime, mu, G_MOD, dt, "maxwell", "lag")
    # x = G dt/mu = 1.5e-10: exactly, mu (1 - e^{-x}) = G dt (1 - x/2 + ...), and the engine's
    # 1 - e^{-x} by subtraction costs up to 1.1e-16/x = 7e-7 relative: rtol 1e-5.
    np.testing.assert_allclose(np.asarray(tau), 2 * G_MOD * dt * np.asarray(dprime), rtol=1e-5, atol=1e-12)
    # Bounded increment for mu from 1e-6 to 1e10 Pa s; the explicit law grows without bound.
    # (Above mu ~ 1e10 Pa s the engine's 1 - exp(-G dt/mu) loses digits to cancellation: see
    # test_maxwell_elastic_increment_float32_large_mu.)
    mus = jnp.asarray(np.geomspace(1e-6, 1e10, 200), F64)
    L, dprime = _shear_inputs(g, 200)
    tau = deviatoric_update(jnp.zeros((200, 2, 2), F64), L, dprime, mus, G_MOD, dt, "maxwell", "lag")
    bound = 2 * G_MOD * dt * g / 2  # |tau_xy| <= 2 G dt d'_xy, d'_xy = g/2
    # mu (1 - e^{-x}) = G dt (1 - e^{-x})/x <= G dt; the cancellation in 1 - e^{-x} costs
    # eps/x <= 2.2e-16 / 1.5e-9 ~ 1.5e-7 relative at mu = 1e10, hence 1e-6.
    assert np.all(np.abs(np.asarray(tau)[:, 0, 1]) <= bound * (1 + 1e-6))
    explicit = deviatoric_update(jnp.zeros((200, 2, 2), F64), L, dprime, mus, G_MOD, dt, "explicit", "lag")
    assert float(jnp.max(jnp.abs(explicit))) > 1e8 * bound  # 2 mu d' at mu = 1e10: 6.7e8 x bound
    # Jaumann rotation of an existing stress at mu = inf-like: tau* = tau + dt (W tau - tau W).
    tau0 = jnp.asarray([[[100.0, 0.0], [0.0, -100.0]]], F64)
    L0 = simple_shear_L(g, 2)
    zero_d = jnp.zeros((1, 2, 2), F64)
    out = deviatoric_update(tau0, L0, zero_d, jnp.asarray([1e300], F64), G_MOD, dt, "maxwell", "lag")
    W = 0.5 * (np.asarray(L0[0]) - np.asarray(L0[0]).T)
    np.testing.assert_allclose(np.asarray(out[0]), np.asarray(tau0[0]) + dt * (W @ tau0[0] - tau0[0] @ W), rtol=1e-14)


@pytest.mark.parametrize("wi", [0.1, 0.5, 2.0])
def test_maxwell_steady_shear_stress_by_rotation(wi):
    """Steady simple shear of the Maxwell element, iterated to its fixed point: with the whole
    stress turned (jaumann) the shear stress is mu g / (1 + Wi^2), Wi = mu g / G (the corotational
    Maxwell model's exact steady state, to the O(dt) of the explicit rotation); with only the
    departure from 2 mu d' turned (lag) it is the viscous mu g exactly."""
    g, dt = 5.0, 1e-4
    mu = wi * G_MOD / g
    L, dprime = _shear_inputs(g)
    mus = jnp.asarray([mu], F64)
    for rotation, expect in (("jaumann", mu * g / (1 + wi**2)), ("lag", mu * g)):
        def body(tau, _):
            return deviatoric_update(tau, L, dprime, mus, G_MOD, dt, "maxwell", rotation), None

        # relaxation time mu/G = wi/g: 40 of them (8e4 steps at wi = 2) leave e^-40 of the start
        n = int(40 * wi / g / dt) + 1
        tau, _ = jax.lax.scan(body, jnp.zeros((1, 2, 2), F64), None, length=n)
        # jaumann: the rotation's explicit step shifts the fixed point by O(g dt) = 5e-4 relative
        rtol = 2e-3 if rotation == "jaumann" else 1e-10
        np.testing.assert_allclose(float(tau[0, 0, 1]), expect, rtol=rtol)


def test_maxwell_lag_turns_a_rigid_plug_as_jaumann():
    """d' = 0 (a spinning plug): lag turns the whole stored stress, bit for bit as jaumann."""
    tau0 = jnp.asarray([[[100.0, 30.0], [30.0, -100.0]]], F64)
    spin = jnp.asarray([[[0.0, 3.0], [-3.0, 0.0]]], F64)
    zero_d = jnp.zeros((1, 2, 2), F64)
    mu = jnp.asarray([1e6], F64)
    a = deviatoric_update(tau0, spin, zero_d, mu, G_MOD, 1e-3, "maxwell", "jaumann")
    b = deviatoric_update(tau0, spin, zero_d, mu, G_MOD, 1e-3, "maxwell", "lag")
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _shear_wave(method, mu, rho, h, dt, n_steps, n_cells=16):
    """1-D periodic shear-wave model: v_x on nodes j h, tau on cells; the cell's velocity
    gradient is L = [[0, (v_{j+1} - v_j)/h], [0, 0]] (simple shear), its stress comes from
    deviatoric_update, and rho dv/dt = d tau_xy/dy.  Explicit viscous stress (tau = 2 mu d')
    makes this the FTCS heat equation, stable iff dt <= rho h^2 / (2 mu) (d = 1 here;
    REFERENCE.md quotes rho h^2 / (2 d mu) in d dimensions)."""
    y = np.arange(n_cells) * h
    v0 = jnp.asarray(np.sin(2 * np.pi * y / (n_cells * h)), F64)  # 1 m/s amplitude

    def body(carry, _):
        v, tau = carry
        gy = (jnp.roll(v, -1) - v) / h
        L = jnp.zeros((n_cells, 2, 2), F64).at[:, 0, 1].set(gy)
        dprime, _ = shear_measures(L, 2)
        tau = deviatoric_update(tau, L, dprime, jnp.full((n_cells,), mu, F64), G_MOD, dt, method, "lag")
        txy = tau[:, 0, 1]
        v = v + dt / rho * (txy - jnp.roll(txy, 1)) / h
        return (v, tau), jnp.max(jnp.abs(v))

    _, vmax = jax.lax.scan(body, (v0, jnp.zeros((n_cells, 2, 2), F64)), None, length=n_steps)
    return np.asarray(vmax)


def test_maxwell_stable_beyond_explicit_viscous_limit():
    """mu = mu_max = 5000 Pa s (thesis Annex 2), rho = 1850, h = 0.01 m: the explicit viscous
    limit is rho h^2/(2 mu) = 1.85e-5 s; the shear-wave CFL limit h/sqrt(G/rho) = 3.5e-3 s.
    At dt = 1e-3 s (54x the viscous limit) the explicit law blows up (amplification
    |1 - 4 mu dt/(rho h^2)| ~ 107 per step) while the Maxwell update stays bounded by the
    initial amplitude (it is dissipative: the wave can only lose energy)."""
    rho, h, mu, dt = 1850.0, 0.01, 5000.0, 1e-3
    assert dt > 50 * rho * h**2 / (2 * mu) and dt < 0.5 * h / np.sqrt(G_MOD / rho)
    vmax_m = _shear_wave("maxwell", mu, rho, h, dt, 2000)
    vmax_e = _shear_wave("explicit", mu, rho, h, dt, 20)
    assert np.all(np.isfinite(vmax_m))
    # Discrete energy of the staggered scheme can exceed the initial |v| by at most the
    # interpolation of kinetic/elastic exchange; 1 % covers it (observed: no growth at all).
    assert vmax_m.max() <= 1.01
    assert not np.all(np.isfinite(vmax_e)) or vmax_e[-1] > 1e20
    # Physical check of the stable run: with relaxation time mu/G = 0.33 s and
    # 2 s of simulated time the mode is an elastic wave damped by viscosity, so it decays.
    assert vmax_m[-200:].max() < 0.9


def test_maxwell_elastic_increment_float32_large_mu():
    """float32 (the default numerics.dtype): a near-rigid plug (mu_eff 1e6 .. 1e9 Pa s, e.g.
    Papanastasiou with tau_y m large, or bi-viscosity with a large alpha_b mu) must still get the
    elastic increment 2 G dt d' ((1 - e^{-x})/x = 1 - x/2 with x <= 1.5e-5 here), to float32
    precision of the expm1 form (~1e-6 relative; 1e-4 allowed)."""
    f32 = jnp.float32
    dt, g = 5e-4, 7.0
    L = jnp.zeros((4, 2, 2), f32).at[:, 0, 1].set(g)
    dprime, _ = shear_measures(L, 2)
    mu = jnp.asarray([1e6, 1e7, 1e8, 1e9], f32)
    tau = deviatoric_update(jnp.zeros((4, 2, 2), f32), L, dprime, mu, G_MOD, dt, "maxwell", "lag")
    assert tau.dtype == f32
    np.testing.assert_allclose(np.asarray(tau[:, 0, 1], np.float64), G_MOD * dt * g, rtol=1e-4)
