"""The material's stress at a particle: equation of state, shear measures, deviatoric update.

The Cauchy stress is sigma = -p(J) I + tau:

* pressure: the Tait-type EOS p = C kappa [exp((1 - J)/C) - 1], C = ``TAIT_C`` (thesis
  eq. 3.11), of the volume ratio J (current over reference volume) and the bulk modulus
  kappa [Pa];
* shear: d = sym(L) of the velocity gradient L [1/s], its 3-D deviator d' and the
  scalar shear measure the rheology reads (``shear_rate``); the viscosity law itself
  is in ``_rheology``;
* deviatoric stress tau [Pa] from the effective viscosity mu [Pa s]: the Maxwell
  exponential update or the explicit viscous law (``deviatoric_update``).

Arrays are per particle, leading axis n: J (n,), L, tau, d' (n, dim, dim).  In 2D (plane
strain) d_zz = 0 but d'_zz = -tr(d)/3 is not, and it counts in d':d'.  SI units throughout.
"""

from __future__ import annotations

import jax.numpy as jnp

# numerics.pressure = incompressible, numerics.maxwell_shear_modulus_pa = 0: the Maxwell modulus is at least this many
# times the law's yield stress, so that material held at its yield stress strains at most 1/100 = 1 % elastically.
# With G = rho v^2 alone, a Bingham plug flow whose plug speed sets v had G below tau_y (the plug test channel:
# G = 345 Pa, tau_y = 490 Pa) and lost every particle; a Bingham layer held on a slope by tau_y = 250 Pa strained
# 12 % (1.6 cm at its surface).  Measured on that channel: plug speed +0.40 % at G = 4 tau_y, +0.015 % at 40 tau_y.
# 100 since 2026-12-06 (20 before): a deposit at its yield limit deforms by 2-3 tau_y/G of its size, and validate's
# block that must not move at all moved +10.4 % at 20 tau_y, +3.4 % at 100, +0.6 % at 400; B = 0.5, L = 3 H0 reads
# -6.6 / -2.7 % of x_inf at 16 / 32 cells and 60 s with 100 (-1.6 % at 240 s, still creeping; -3.1 % in float64) and -1.2 / +1.3 %
# (past x_inf and moving out) with 20
# (docs/incompressible-default.md, "The held block").  The step follows sqrt(G): 1.5x the CPU of those cases.
MAXWELL_YIELD_FACTOR = 100.0

# Tait-type EOS constant (thesis eq. 3.11, Macdonald 1969).
TAIT_C = 0.0894


def tait_pressure(J, kappa):
    """Tait-type EOS p = C kappa [exp((1 - J)/C) - 1], C = 0.0894 (thesis eq. 3.11) [Pa]."""
    return TAIT_C * kappa * jnp.expm1((1.0 - J) / TAIT_C)


def shear_measures(L, dim):
    """Deviatoric rate d' (n, dim, dim) and d':d' including the out-of-plane part in 2D.

    d = sym(L); d' = d - tr(d)/3 I (3-D deviator; in plane strain d_zz = 0 so
    d'_zz = -tr(d)/3 contributes to d':d').
    """
    d = 0.5 * (L + jnp.swapaxes(L, -1, -2))
    tr = jnp.trace(d, axis1=-2, axis2=-1)
    eye = jnp.eye(dim, dtype=L.dtype)
    dprime = d - (tr / 3.0)[:, None, None] * eye[None]
    dd = jnp.sum(dprime * dprime, axis=(-2, -1))
    if dim == 2:
        dd = dd + (tr / 3.0) ** 2
    return dprime, dd


def _safe_sqrt(x):
    pos = x > 1e-30
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def shear_rate(dd, measure: str):
    """Shear measure from d':d': ``standard`` sqrt(2 d':d') [1/s] or ``thesis`` d':d'/4."""
    if measure == "standard":
        return _safe_sqrt(2.0 * dd)
    if measure == "thesis":
        return 0.25 * dd
    raise ValueError(f"shear_measure {measure!r}; allowed: 'standard', 'thesis'")


# The batched matrix product of the Jaumann rotation, written as broadcast-multiply-sum like
# the contraction helpers of ``_transfer`` (see there why).  It lives here, with its only user,
# because ``_transfer`` imports ``tait_pressure`` from this module.
def _mm(A, B):
    """(n, i, k) x (n, k, j) -> (n, i, j)."""
    d = A.shape[-1]
    rows = [
        jnp.stack([sum(A[:, i, k] * B[:, k, j] for k in range(d)) for j in range(B.shape[-1])], axis=-1)
        for i in range(A.shape[1])
    ]
    return jnp.stack(rows, axis=1)


def deviatoric_update(tau, L, dprime, mu, G, dt, method: str, rotation: str):
    """Deviatoric stress update [Pa].

    ``maxwell``: a Maxwell element integrated exactly at constant d' over dt:
    tau <- tau* e^{-G dt/mu} + 2 mu d' (1 - e^{-G dt/mu}), with tau* the stored stress turned
    by the spin W over dt.  The step response is bounded by 2 G dt d', so the step is stable
    at the wave-speed limit with c^2 = (kappa + 4G/3)/rho for any mu.  For mu << G dt it is
    the viscous law 2 mu d'; the lag is the relaxation time mu/G.  G is a numerical device, and
    so is what the spin turns (``rotation``):

    * ``jaumann``: tau* = tau + dt (W tau - tau W), the corotational (Jaumann) Maxwell model.
      Objective, but in steady simple shear its shear stress is mu gamma_dot / (1 + Wi^2),
      Wi = mu gamma_dot / G = tau / G: the viscous law is missed by Wi^2 (Poiseuille with
      G = rho v^2: 2.7 % too fast; the Bingham plug 4.3 %; docs/incompressible.md).
    * ``lag``: only the stored stress's departure from the viscous stress is turned:
      tau* = tau + dt (W l - l W), l = tau - c 2 mu d', with c = min(1, |tau| / |2 mu d'|) (the
      viscous stress capped at the stored stress's magnitude: in a plug 2 mu d' is far larger than
      the stress the element holds, and turning it uncapped injects mu |W| |d'| dt, which blew up
      the shear-wave test at mu = 5000 Pa s).  Steady shear then has the fixed point 2 mu d'
      exactly, and a rigid plug (d' = 0) turns its stress as ``jaumann`` does; what remains is an
      O(Wi) departure from objectivity in flow that both spins and changes.
    ``explicit``: tau = 2 mu d' (thesis eq. 3.1); stable only for dt < rho h^2 / (2 d mu).
    """
    if method == "explicit":
        return 2.0 * mu[:, None, None] * dprime
    W = 0.5 * (L - jnp.swapaxes(L, -1, -2))
    if rotation == "jaumann":
        turned = tau
    else:
        # the viscous stress 2 mu d', capped at the stored stress's magnitude: in a plug (mu huge, the
        # element elastic) 2 mu d' is far larger than any stress the element holds, and turning it
        # would inject mu |W| |d'| dt; capped, the turned part is bounded by 2 |tau| as with jaumann
        visc = 2.0 * mu[:, None, None] * dprime
        # _safe_sqrt: a zero stress (every particle at the start) must give a zero derivative, not NaN
        n_tau = _safe_sqrt(jnp.sum(tau * tau, axis=(-2, -1)))
        n_visc = _safe_sqrt(jnp.sum(visc * visc, axis=(-2, -1)))
        over = n_visc > n_tau
        cap = jnp.where(over, n_tau / jnp.where(over, n_visc, 1.0), 1.0)
        turned = tau - cap[:, None, None] * visc
    tau_rot = tau + dt * (_mm(W, turned) - _mm(turned, W))
    x = G * dt / mu
    decay = jnp.exp(-x)[:, None, None]
    # 1 - e^{-x} via expm1: keeps the elastic limit 2 G dt d' exact in float32 for huge mu
    return tau_rot * decay + 2.0 * (mu * -jnp.expm1(-x))[:, None, None] * dprime
