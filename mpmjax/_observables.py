"""Observables computed from particle data.

``runout``: front position along ``axis`` measured from ``origin`` [m]:
    x_front = max over active particles of x_p[axis] + s/2 - origin,
where s is the initial particle spacing (h / ppc), so that a block at rest reports its
own edge.  It is a hard maximum, so a single stray particle moves it; smooth estimates
for calibration are in ``calibration``.
"""

from __future__ import annotations

import jax.numpy as jnp


def runout(x, active, axis: int, origin: float, spacing: float):
    """Front position [m] per frame. ``x``: (..., n, dim); ``active``: (..., n)."""
    xa = jnp.where(active, x[..., axis], -jnp.inf)
    return jnp.max(xa, axis=-1) + 0.5 * spacing - origin
