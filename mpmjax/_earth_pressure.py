"""Savage & Hutter's earth-pressure coefficient of a depth-averaged granular (Mohr-Coulomb) column
(``model.internal_friction_deg``; docs/earth-pressure.md).

A column of a fluid carries a hydrostatic depth-integrated pressure, rho g_n H^2 / 2 in every direction (k = 1).
A column of a frictional material (internal friction angle phi) sliding on a Coulomb bed (bed friction angle
delta, tan(delta) = ``terrain.friction``) carries k times it along the flow, with Savage & Hutter's (1989, J. Fluid
Mech. 199, 177-215) coefficient from the Mohr-Coulomb stress state at the bed:

    k_act/pass = 2 / cos^2(phi) (1 -/+ sqrt(1 - cos^2(phi) / cos^2(delta))) - 1,    delta <= phi,

active (the smaller) where the column extends, passive where it is compressed.  Without bed friction they are
Rankine's, (1 -/+ sin phi) / (1 +/- sin phi); at delta = phi both are (1 + sin^2 phi) / cos^2 phi.

The step (``_shallow``) takes one coefficient per column, isotropic in the plan: active where the plan velocity's
divergence at the column (the trace of its APIC affine matrix, the velocity gradient) is >= 0, passive where it is
< 0.  In a 1-D plan that is Savage & Hutter's sign of du/dx; in a 2-D plan it is a simplification of the
anisotropic coefficients of Hutter, Siegel, Savage & Nohguchi (1993) and Pudasaini & Hutter (2007), which take a
different k along and across the flow (not built: docs/earth-pressure.md).
"""

from __future__ import annotations

import math

import jax.numpy as jnp


def coefficients(phi_deg: float, tan_delta):
    """(k_act, k_pass) for internal friction ``phi_deg`` [deg] (static) and bed friction ``tan_delta`` (traced,
    ``Basal.friction``).  A bed friction above the internal one (which the scene refuses, but a calibration may
    reach) is taken at delta = phi: the two coefficients meet there."""
    cos2_phi = math.cos(math.radians(phi_deg)) ** 2
    cos2_delta = 1.0 / (1.0 + tan_delta * tan_delta)
    x = 1.0 - cos2_phi / cos2_delta
    pos = x > 0.0
    root = jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)  # a finite derivative at delta = phi
    return 2.0 / cos2_phi * (1.0 - root) - 1.0, 2.0 / cos2_phi * (1.0 + root) - 1.0


def largest(phi_deg: float) -> float:
    """The largest coefficient at ``phi_deg`` over every bed friction: Rankine's passive (1 + sin phi) /
    (1 - sin phi), at a frictionless bed; the time step's wave speed takes it (``_shallow.time_step_limits``)."""
    s = math.sin(math.radians(phi_deg))
    return (1.0 + s) / (1.0 - s)


def per_column(phi_deg: float, tan_delta, divergence):
    """Each column's coefficient: active where its plan velocity's ``divergence`` [1/s] is >= 0, else passive."""
    k_act, k_pass = coefficients(phi_deg, tan_delta)
    return jnp.where(divergence >= 0.0, k_act, k_pass)
