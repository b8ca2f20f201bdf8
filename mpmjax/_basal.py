"""Basal shear of a depth-averaged flow: each law of the rheology registry (``_rheology``) as the
shear stress tau_b [Pa] that a layer of bed-normal depth h [m], moving at the depth-averaged speed
U [m/s], exerts on its bed (docs/depth-averaged.md, "Closures").

The closure (one for every law; nothing here re-implements a law):

* the basal shear rate is that of the Newtonian (parabolic) velocity profile, gamma_b = 3 U / h;
* the law's viscous part is its own effective viscosity at that rate with the yield stress
  removed: tau_v = mu_law(gamma_b; tau_y = 0, internal) gamma_b.  Newtonian: tau_v = 3 mu U / h,
  the exact basal stress of a steady uniform laminar layer; Herschel-Bulkley: K gamma_b^n_hb (capped
  at mu_max gamma_b); Coussot: mu(lambda) gamma_b, lambda the particle's structure (advanced by the
  same gamma_b in ``_shallow``, with the law's exact exponential update);
* a law with a yield stress (a ``tau_y`` parameter: Bingham, Herschel-Bulkley) takes the Bingham
  plug-flow relation of a steady uniform layer, U = tau_b h / (3 mu) (1 - 3/2 xi + xi^3 / 2),
  xi = tau_y / tau_b (Pastor et al. 2004, their cubic), written as tau_b^3 - (3/2 tau_y + tau_v)
  tau_b^2 + tau_y^3 / 2 = 0 with tau_v = 3 mu U / h; tau_b is its largest root, >= tau_y: tau_y at
  rest, 3/2 tau_y + tau_v for a thin plug.  For Bingham it is exact for the steady uniform layer;
  for Herschel-Bulkley it is the same plug correction on the power-law tau_v (an approximation);
* the regularisation of the 3-D laws (Papanastasiou's m, the bi-viscosity alpha_b) is not used:
  the yield part is applied as a capped friction instead (``_shallow``), which holds a layer at
  rest while rho g h |grad(z_b + h)| <= tau_y, exactly.

``closure`` returns tau_b(U) split for the step's implicit friction, tau_b = tau_0 + c U at the
current U: the yield part tau_0 (what a layer at rest must exceed; plus a Coulomb part
mu_c sigma_n with ``terrain.type = "coulomb"`` or ``"voellmy"``, whose drag ``_shallow`` adds to c) and the secant c = (tau_b - tau_0) / U [Pa s/m],
so the step can apply the viscous part implicitly (any c, any dt) and cap the yield part.
"""

from __future__ import annotations

import jax.numpy as jnp

# speeds below this [m/s] are evaluated at it (the secant (tau_b - tau_0) / U and the shear rate stay
# finite; a node this slow is stopped or dominated by the yield part)
U_EPS = 1e-6
# Newton iterations for the plug-flow cubic, from an upper bound of the root (module docstring):
# monotone convergence; 8 reach float64 round-off over tau_v / tau_y in [1e-12, 1e6]
NEWTON_ITERATIONS = 8


def has_yield(law) -> bool:
    """Whether the law has a yield stress parameter ``tau_y`` (the plug-flow closure applies)."""
    return "tau_y" in law.params_type._fields


def plug_excess(tau_y, tau_v):
    """s = tau_b - tau_y >= 0 of the Bingham plug-flow cubic (module docstring) for tau_y >= 0 and
    tau_v > 0: the positive root of s^3 + (3/2 tau_y - tau_v) s^2 - 2 tau_v tau_y s - tau_v tau_y^2 = 0
    (the cubic in tau_b shifted by tau_y), by Newton from s0 = tau_v + sqrt(tau_v tau_y), an upper
    bound of the root on the convex branch, so the iterates decrease monotonically to it.

    Solved scaled by S = tau_v + tau_y (a = tau_v / S, y = tau_y / S, sigma = s / S: every term of
    order 1), which leaves Newton's iterates unchanged but keeps their forward-mode tangents finite in
    float32: unscaled, a thin front column (tau_v ~ 1e7 Pa) made the quotient rule's g' gp ~ 1e35 and
    the Jacobian of a friction fit NaN (2026-12-06)."""
    scale = tau_v + tau_y
    a = tau_v / scale
    y = tau_y / scale
    b = 1.5 * y - a
    s = a + jnp.sqrt(jnp.maximum(a * y, 1e-30))
    for _ in range(NEWTON_ITERATIONS):
        g = ((s + b) * s - 2.0 * a * y) * s - a * y * y
        gp = (3.0 * s + 2.0 * b) * s - 2.0 * a * y
        ok = gp > 0
        s = s - jnp.where(ok, g / jnp.where(ok, gp, 1.0), 0.0)
    return jnp.maximum(s, 0.0) * scale


def shear_rate(speed, depth_n):
    """The basal shear rate gamma_b = 3 U / h [1/s] of the closure (U floored at ``U_EPS``)."""
    return 3.0 * jnp.maximum(speed, U_EPS) / depth_n


def closure(law, params, speed, depth_n, internal, normal_stress=None, friction=None):
    """(tau_0 [Pa], c [Pa s/m], mu [Pa s]) of the basal shear at bed speed ``speed`` [m/s] and
    bed-normal depth ``depth_n`` [m] (> 0) with the law's internal variables ``internal``:
    tau_b = tau_0 + c U (module docstring); mu: the law's effective viscosity at gamma_b (without
    its yield part), for the outputs.  ``friction``: a Coulomb coefficient mu_c (traced; None: no
    Coulomb part), adding mu_c ``normal_stress`` [Pa] to tau_0."""
    u = jnp.maximum(speed, U_EPS)
    rate = shear_rate(u, depth_n)
    yield_ = has_yield(law)
    p0 = params._replace(tau_y=jnp.zeros_like(params.tau_y)) if yield_ else params
    mu = law.mu(p0, rate, internal)
    tau_v = mu * rate
    if yield_:
        tau_0 = jnp.broadcast_to(params.tau_y, tau_v.shape)
        excess = plug_excess(tau_0, tau_v)
    else:
        tau_0 = jnp.zeros_like(tau_v)
        excess = tau_v
    if friction is not None:
        tau_0 = tau_0 + friction * normal_stress
    return tau_0, excess / u, mu
