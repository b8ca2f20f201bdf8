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

With ``numerics.depth_layers`` = K > 1 (a law with internal variables, Coussot) each column carries its
internal variables in K layers across its depth instead of one value (Hewitt & Balmforth 2013's thixotropic
lubrication model, layered): the shear stress of a uniform shallow layer falls linearly from tau_b at the bed to
0 at the surface, tau(zeta) = tau_b (1 - zeta) (zeta = height / h), each layer shears at its own rate
tau / mu_k with its own viscosity mu_k = mu_law(lambda_k), and the mean speed is
U = h tau_b F, F = sum_k w_k / mu_k, w_k = int over layer k of (1 - zeta)^2 dzeta ("fluidity", 1/(Pa s)).
So tau_b = c U with c = 1 / (h F), exact for a quasi-steady layer whose viscosity depends on its structure
only (Coussot's), and each layer's structure advances at its own rate tau_b (1 - zeta_k) / mu_k: a band
that breaks down at the bed under a plug that ages is the layer's own outcome, as across the depth of a
film (docs/depth-layers.md).  One layer of the uniform profile is the
Newtonian closure above (c = 3 mu / h).  The layers are graded towards the bed (edges (k / K)^2), where the
band forms.

``closure`` returns tau_b(U) split for the step's implicit friction, tau_b = tau_0 + c U at the
current U: the yield part tau_0 (what a layer at rest must exceed; plus a Coulomb part
mu_c sigma_n with ``terrain.type = "coulomb"`` or ``"voellmy"``, whose drag ``_shallow`` adds to c) and the secant c = (tau_b - tau_0) / U [Pa s/m],
so the step can apply the viscous part implicitly (any c, any dt) and cap the yield part.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

# speeds below this [m/s] are evaluated at it (the secant (tau_b - tau_0) / U and the shear rate stay
# finite; a node this slow is stopped or dominated by the yield part)
U_EPS = 1e-6
# Newton iterations for the plug-flow cubic, from an upper bound of the root (module docstring):
# monotone convergence; 8 reach float64 round-off over tau_v / tau_y in [1e-12, 1e6]
NEWTON_ITERATIONS = 8


# the layers' edges across the depth, zeta_k = (k / K)^LAYER_GRADING: thinner at the bed, where a
# thixotropic layer's band forms (docs/depth-layers.md)
LAYER_GRADING = 2.0


def layer_edges(n_layers: int) -> np.ndarray:
    """The K + 1 edges zeta_k in [0, 1] (bed to surface) of ``n_layers`` layers across the depth."""
    return (np.arange(n_layers + 1) / n_layers) ** LAYER_GRADING


def layer_weights(n_layers: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(w_k, s_k, t_k) of the K layers: w_k = int (1 - zeta)^2 dzeta over the layer (sum 1/3), s_k = 1 - zeta
    at its centre (the stress there over tau_b) and t_k its thickness (sum 1)."""
    e = layer_edges(n_layers)
    return ((1.0 - e[:-1]) ** 3 - (1.0 - e[1:]) ** 3) / 3.0, 1.0 - 0.5 * (e[:-1] + e[1:]), np.diff(e)


def layered(law, params, speed, depth_n, internal):
    """The layered column (module docstring) at bed speed ``speed`` [m/s] and bed-normal depth ``depth_n`` [m],
    its internal variables ``internal`` carrying the K layers on their last axis: (mu [Pa s] per layer, F
    [1/(Pa s)]).  The law's viscosity is taken at each layer's rate in a Newtonian profile of the same U (a
    guess; Coussot's viscosity does not depend on the rate, so for it the result is exact).  The basal shear
    is tau_b = U / (h F) (:func:`closure` with ``fluidity``) and the layers' rates :func:`layer_rates`."""
    lead = next(iter(internal.values())).shape
    dt = next(iter(internal.values())).dtype
    w, s, _ = (jnp.asarray(a, dt).reshape((1,) * (len(lead) - 1) + (-1,)) for a in layer_weights(lead[-1]))
    u = jnp.maximum(speed, U_EPS)[..., None]
    mu = law.mu(params, 3.0 * u / depth_n[..., None] * s, internal)
    return mu, jnp.sum(w / mu, axis=-1)


def layer_rates(speed, depth_n, mu, fluidity):
    """The K layers' shear rates [1/s], tau_b (1 - zeta_k) / mu_k with tau_b = U / (h F), of columns whose layers
    have the viscosities ``mu`` (last axis) and the fluidity ``fluidity`` (:func:`layered`)."""
    s = jnp.asarray(layer_weights(mu.shape[-1])[1], mu.dtype).reshape((1,) * (mu.ndim - 1) + (-1,))
    tau_b = jnp.maximum(speed, U_EPS) / (depth_n * fluidity)
    return tau_b[..., None] * s / mu


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


def closure(law, params, speed, depth_n, internal, normal_stress=None, friction=None, fluidity=None):
    """(tau_0 [Pa], c [Pa s/m], mu [Pa s]) of the basal shear at bed speed ``speed`` [m/s] and
    bed-normal depth ``depth_n`` [m] (> 0) with the law's internal variables ``internal``:
    tau_b = tau_0 + c U (module docstring); mu: the law's effective viscosity at gamma_b (without
    its yield part), for the outputs.  ``friction``: a Coulomb coefficient mu_c (traced; None: no
    Coulomb part), adding mu_c ``normal_stress`` [Pa] to tau_0.  ``fluidity``: a layered column's F
    (:func:`layered`; then ``internal`` is not used): c = 1 / (h F), mu = c h / 3 (the Newtonian
    viscosity of the same basal shear)."""
    if fluidity is not None:
        c = 1.0 / (depth_n * fluidity)
        tau_0 = jnp.zeros_like(c)
        if friction is not None:
            tau_0 = tau_0 + friction * normal_stress
        return tau_0, c, 1.0 / (3.0 * fluidity)  # = c h / 3
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
