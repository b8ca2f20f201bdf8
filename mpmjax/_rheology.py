"""Rheology plug-ins: effective viscosity laws with traced parameter pytrees.

Every model is a small frozen (hashable, static) dataclass that describes *how*
to compute an effective viscosity, plus a ``NamedTuple`` of parameters that are
traced arrays, so that ``jax.grad`` and ``jax.vmap`` reach them.

The MPM step never branches on the model: it asks the model for

* ``init_internal(params, n)``: per-particle internal variables (a dict pytree);
* ``viscosity(params, shear, internal, dt, aging)``: the effective viscosity
  ``mu_eff`` [Pa s] at the given shear measure and the updated internal variables;
* ``max_viscosity(params)``: the largest viscosity the law can produce (used for
  the viscous time-step limit);

and builds the Cauchy stress ``sigma = -p I + s`` itself, where ``s`` is the
deviatoric stress from ``mu_eff`` (see ``_constitutive.deviatoric_update``).

Shear measures (see ../shared/REFERENCE.md, thesis eqs. 3.8-3.9 and Annex 1):

* ``"standard"``: gamma_dot = sqrt(2 d':d') [1/s]; equals the imposed rate in
  simple shear.
* ``"thesis"``: |0.5 * II_d'| = d':d'/4, which is gamma_dot**2/8 in simple
  shear.  It is *not* a rate; it is kept only to reproduce the thesis.

Units: SI throughout (Pa, Pa s, s, kg/m^3).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp

# Smallest shear measure used in divisions (1/s).  Below it the regularised laws
# use their analytic limit, so gradients stay finite at rest.
_GDOT_EPS = 1e-12


class NewtonianParams(NamedTuple):
    """Weakly compressible Newtonian fluid.

    rho: reference density [kg/m^3]; kappa: bulk modulus of the Tait EOS [Pa];
    mu: dynamic viscosity [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu: jnp.ndarray


class BinghamParams(NamedTuple):
    """Bingham fluid (bi-viscosity or Papanastasiou).

    tau_y: yield stress [Pa]; mu: plastic viscosity [Pa s];
    alpha_b: bi-viscosity ratio below yield [-] (thesis, Hosseini et al. 2006,
    >= 100 recommended); m: Papanastasiou regularisation time [s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu: jnp.ndarray
    tau_y: jnp.ndarray
    alpha_b: jnp.ndarray
    m: jnp.ndarray


class HerschelBulkleyParams(NamedTuple):
    """Regularised Herschel-Bulkley: tau = tau_y + K gdot^n_hb.

    K: consistency [Pa s^n_hb]; n_hb: flow index [-]; m: Papanastasiou time [s];
    mu_max: viscosity cap [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    tau_y: jnp.ndarray
    K: jnp.ndarray
    n_hb: jnp.ndarray
    m: jnp.ndarray
    mu_max: jnp.ndarray


class CoussotParams(NamedTuple):
    """Coussot (2002) thixotropy: dlam/dt = 1/T - alpha gdot lam, mu = mu0 (1 + lam^n).

    mu0: minimum viscosity [Pa s]; alpha: destructuration coefficient [-];
    T: characteristic restructuring time [s]; n: exponent [-];
    lambda0: initial structure [-]; mu_max: viscosity cap [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu0: jnp.ndarray
    alpha: jnp.ndarray
    T: jnp.ndarray
    n: jnp.ndarray
    lambda0: jnp.ndarray
    mu_max: jnp.ndarray


def _safe_inv(x):
    """1/x with x floored at _GDOT_EPS (x >= 0)."""
    return 1.0 / jnp.maximum(x, _GDOT_EPS)


def _one_minus_exp_over(a, t):
    """(1 - exp(-a t)) / a for a >= 0, continuous (-> t) and differentiable at a = 0."""
    small = a * t < 1e-6
    a_safe = jnp.where(small, 1.0, a)
    return jnp.where(small, t * (1.0 - 0.5 * a * t), -jnp.expm1(-a_safe * t) / a_safe)


def coussot_lambda_exact(lam, gdot, dt, alpha, T):
    """Exact update of dlam/dt = 1/T - alpha gdot lam over dt at constant gdot.

    lam(t+dt) = lam exp(-alpha gdot dt) + (1 - exp(-alpha gdot dt)) / (alpha gdot T),
    which is lam_ss + (lam - lam_ss) exp(-alpha gdot dt) with lam_ss = 1/(alpha T gdot),
    and reduces to lam + dt/T at gdot = 0 (REFERENCE.md).  Positive and bounded for any dt.
    """
    a = alpha * gdot
    return lam * jnp.exp(-a * dt) + _one_minus_exp_over(a, dt) / T


def coussot_lambda_euler(lam, gdot, dt, alpha, T):
    """Thesis eq. 3.9 (explicit Euler); unstable once alpha gdot dt > 1.  Comparison only."""
    return lam + dt * (1.0 / T - alpha * gdot * lam)


def coussot_mu(lam, mu0, n, mu_max):
    """mu = min(mu0 (1 + lam^n), mu_max) [Pa s] (thesis eq. 3.7 plus its cap)."""
    lam_pos = jnp.maximum(lam, 0.0)
    return jnp.minimum(mu0 * (1.0 + lam_pos**n), mu_max)


@dataclasses.dataclass(frozen=True)
class Newtonian:
    """Constant viscosity."""

    name = "newtonian"
    params_type = NewtonianParams
    internal_fields = ()

    def init_internal(self, params, n):
        return {}

    def viscosity(self, params, shear, internal, dt, aging):
        return jnp.full_like(shear, params.mu), internal

    def max_viscosity(self, params):
        return params.mu


@dataclasses.dataclass(frozen=True)
class Bingham:
    """Bingham plastic.

    variant = "biviscosity": the thesis's model (Hosseini et al. 2006, eqs. 3.12-3.13).
      With the standard measure, mu_eff = alpha_b mu below gdot_c = tau_y/((alpha_b-1) mu)
      and mu + tau_y/gdot above (continuous at gdot_c).  With the thesis measure the
      thesis's own switch is reproduced: alpha_b mu below II < tau_y/(2 alpha_b mu), else
      mu + tau_y/(2 II).
    variant = "papanastasiou": mu_eff = mu + tau_y (1 - exp(-m gdot))/gdot, smooth, for
      gradients (Papanastasiou 1987).
    """

    variant: str = "papanastasiou"
    shear_measure: str = "standard"
    name = "bingham"
    params_type = BinghamParams
    internal_fields = ()

    def init_internal(self, params, n):
        return {}

    def viscosity(self, params, shear, internal, dt, aging):
        mu, ty = params.mu, params.tau_y
        if self.variant == "papanastasiou":
            reg = ty * _one_minus_exp_over(shear, params.m)
            return mu + reg, internal
        ab = params.alpha_b
        if self.shear_measure == "thesis":
            below = shear < ty / (2.0 * ab * mu)
            above_mu = mu + ty * 0.5 * _safe_inv(shear)
        else:
            below = shear < ty / ((ab - 1.0) * mu)
            above_mu = mu + ty * _safe_inv(shear)
        return jnp.where(below, ab * mu, above_mu), internal

    def max_viscosity(self, params):
        if self.variant == "papanastasiou":
            return params.mu + params.tau_y * params.m
        return params.alpha_b * params.mu


@dataclasses.dataclass(frozen=True)
class HerschelBulkley:
    """Regularised Herschel-Bulkley: mu_eff = K gdot^(n-1) + tau_y (1 - e^{-m gdot})/gdot,
    capped at mu_max (the power-law term diverges at rest when n < 1)."""

    name = "herschel_bulkley"
    params_type = HerschelBulkleyParams
    internal_fields = ()

    def init_internal(self, params, n):
        return {}

    def viscosity(self, params, shear, internal, dt, aging):
        g = jnp.maximum(shear, _GDOT_EPS)
        mu = params.K * g ** (params.n_hb - 1.0) + params.tau_y * _one_minus_exp_over(shear, params.m)
        return jnp.minimum(mu, params.mu_max), internal

    def max_viscosity(self, params):
        return params.mu_max


@dataclasses.dataclass(frozen=True)
class Coussot:
    """Coussot (2002) thixotropic fluid (thesis §3.4.1).

    integrator = "exact": exact exponential update at constant shear over a step (default).
    integrator = "euler": the thesis's explicit Euler (eq. 3.9), for comparison only.
    Where ``aging`` is False (material not yet past the aging gate) lam is held at its
    current value: the material neither ages nor de-structures (thesis §3.4.2).
    """

    integrator: str = "exact"
    name = "coussot"
    params_type = CoussotParams
    internal_fields = ("lam",)

    def init_internal(self, params, n):
        return {"lam": jnp.full((n,), params.lambda0, dtype=jnp.result_type(params.lambda0))}

    def viscosity(self, params, shear, internal, dt, aging):
        lam = internal["lam"]
        update = coussot_lambda_exact if self.integrator == "exact" else coussot_lambda_euler
        lam_new = update(lam, shear, dt, params.alpha, params.T)
        lam_new = jnp.where(aging, lam_new, lam)
        return coussot_mu(lam_new, params.mu0, params.n, params.mu_max), {"lam": lam_new}

    def max_viscosity(self, params):
        return params.mu_max


MODELS = {
    "newtonian": Newtonian,
    "bingham": Bingham,
    "herschel_bulkley": HerschelBulkley,
    "coussot": Coussot,
}
