"""A layer flowing down a no-slip plane, solved in one dimension across its depth: the reference of
``mpmjax validate``'s ``coussot-film``, for any registered law (``mpmjax._rheology``).

A uniform layer of depth H on a plane at angle theta, started from rest, shears in planes parallel to
the bed, so u(y, t) and the law's internal variables z(y, t) (y the height over the bed) obey

    rho du/dt = d tau/dy + rho g sin(theta),   tau = mu(|du/dy|, z) du/dy,   dz/dt = law.rate(|du/dy|, z),

with u = 0 at the bed and tau = 0 at the free surface; the shear rate |du/dy| is the law's standard
measure for simple shear.  A law with internal variables (Coussot's structure lambda) carries its
history at every height: where its steady flow curve is not monotone (Coussot with n > 1) a layer's
steady state depends on how it started, so the reference is this transient, not the steady flow curve
(``benchmarks/accuracy/coussot_film.py`` gives the one steady state in which every height above the
curve's minimum stress flows; a layer started at lambda0 from rest finds another: docs/coussot-film.md).

Numerics: the method of lines on ``n`` equal layers (velocity at the layer boundaries, stress and
internal variables at their centres; the top node carries half a layer), diffrax's Kvaerno5 (L-stable:
the capped viscosity makes the layer stiff, mu_max / (rho dy^2) about 1e8 1/s) with an adaptive step;
float64, inside ``jax.enable_x64``.  Measured: a Newtonian layer's steady speed rho g sin(theta) H^2 / (3 mu)
to 2.5e-5 at 100 layers (tests/test_film.py); the lab's Coussot layer at twice its flow curve's minimum stress,
whose band edge is resolved to a layer here too, converges unevenly: its mean speed over 5-6 s moves by -1.8 %
from 50 to 100 layers, +0.06 % to 200 and +0.18 % to 400 (docs/coussot-film.md).
"""

from __future__ import annotations

import functools
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .._rheology import law_of
from ._ode import solve_saved

N_LAYERS = 100
RTOL, ATOL = 1e-6, 1e-9  # the adaptive step's tolerances (ATOL in m/s and in the internal variables' units)
MAX_STEPS = 1_000_000


@functools.lru_cache(maxsize=None)
def _solver(law, n: int):
    w = np.ones(n)
    w[-1] = 0.5  # the top node's share of a layer

    def rhs(t, y, args):
        params, dy, g_s = args
        u = jnp.concatenate([jnp.zeros(1), y[0]])
        gd = (u[1:] - u[:-1]) / dy
        s = jnp.abs(gd)
        mu = law.mu(params, s, y[1])
        tau = mu * gd
        up = jnp.concatenate([tau[1:], jnp.zeros(1)])
        du = (up - tau) / (dy * params.rho * jnp.asarray(w)) + g_s
        return du, law.rate(params, s, y[1])

    @jax.jit
    def solve(params, internal0, ts, dy, g_s):
        y0 = (jnp.zeros(n), internal0)
        return solve_saved(
            rhs, diffrax.Kvaerno5(), y0, ts, 1e-6 * ts[-1], (params, dy, g_s), rtol=RTOL, atol=ATOL, max_steps=MAX_STEPS
        )

    return solve


def film_profiles(
    params, depth_m: float, slope_deg: float, times_s, *, g_m_s2: float = 9.81, n_layers: int = N_LAYERS, law=None
):
    """The layer at ``times_s`` [s] (increasing, > 0), started from rest with the law's initial internal
    variables: (y (n + 1,) node heights [m], u (len(times), n + 1) velocity along the slope [m/s], internal
    {name: (len(times), n)} at the layer centres, steps taken).  ``params``: a law's parameter NamedTuple
    (``mpmjax.rheometer.make_params`` or a scene's ``Params.material``); ``law``: its law instance (default: the
    registered law of that type with default options)."""
    for name, v in (("depth_m", depth_m), ("g_m_s2", g_m_s2)):
        if not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"{name} = {v!r} is invalid: allowed range > 0")
    if not (math.isfinite(slope_deg) and 0.0 < slope_deg < 90.0):
        raise ValueError(f"slope_deg = {slope_deg!r} is invalid: allowed range (0, 90)")
    if int(n_layers) != n_layers or n_layers < 4:
        raise ValueError(f"n_layers = {n_layers!r} is invalid: allowed whole numbers >= 4")
    ts = np.asarray(times_s, float)
    if ts.ndim != 1 or ts.size == 0 or not np.all(np.isfinite(ts)) or ts[0] <= 0.0 or np.any(np.diff(ts) <= 0.0):
        raise ValueError(f"times_s = {times_s!r} is invalid: allowed increasing times > 0")
    law = law_of(params)() if law is None else law
    n = int(n_layers)
    dy = depth_m / n
    with jax.enable_x64(True):  # for this solve only: the process's float32 runs stay as they are
        p64 = type(params)(*(jnp.asarray(v, jnp.float64) for v in params))
        internal0 = {i.name: jnp.full(n, getattr(p64, i.init), jnp.float64) for i in law.internals}
        (u, z), steps = _solver(law, n)(
            p64, internal0, jnp.asarray(ts), dy, g_m_s2 * math.sin(math.radians(slope_deg))
        )
        u = np.concatenate([np.zeros((ts.size, 1)), np.asarray(u)], axis=1)
        z = {k: np.asarray(v) for k, v in z.items()}
    return np.linspace(0.0, depth_m, n + 1), u, z, int(steps)


def mean_speed(y, u) -> np.ndarray:
    """The depth-averaged speed [m/s] of ``film_profiles``' u (trapezoids between the nodes), per time."""
    u = np.atleast_2d(u)
    return np.sum(0.5 * (u[:, 1:] + u[:, :-1]) * np.diff(y)[None, :], axis=1) / (y[-1] - y[0])
