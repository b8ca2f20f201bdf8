"""Observables computed from particle data (pure JAX: safe under ``jit``, ``vmap`` and ``grad``).

Runout (docs/output.md "Runout"): two definitions, both measured along the runout axis from
the runout origin [m].

``free_surface_front`` (the headline ``runout_m`` of summary.json, and calibration's front):
    the farthest position where the deposit thickness is at least ``FRONT_FRACTION`` (10 %)
    of the thickest point of the same frame.  The thickness is the kernel height profile of
    the particles' rest volumes (``height_profile``, Gaussian bandwidth one cell h) in 2D; in
    3D (``mpmjax._metrics.plan_front``) the largest thickness across the flow in each
    plan-view column of one cell.  It is a functional of the free surface, so it converges
    with h and ppc; a single particle carries a height of at most V_p / (sqrt(2 pi) h), far
    below 10 % of any deposit a few particle layers thick.  Why 10 %: the convention of the
    lobe width (``_metrics``) and of calibration's runout data; for the Bingham slump's
    sqrt profile it stops short of the tip by 1 % of the deposit length (the last 10 % of
    the thickness spans 1 % of the length), below the discretisation error at affordable h.
``runout`` (secondary: ``runout_farthest_particle_m``):
    x_front = max over active particles of x_p[axis] + s/2 - origin,
    where s is the initial particle spacing (h / ppc), so that a block at rest reports its
    own edge.  It is a hard maximum, so a single stray particle moves it and it does not
    converge with h (docs/validation.md).

Differentiable observables: height profile, smooth front, deposited volume.

All functions are pure JAX (safe under ``jit``, ``vmap`` and ``grad``), take particle
arrays as saved in a ``Frame`` (``x`` (n, dim) [m], ``active`` (n,)) plus a per-particle
volume ``vol`` (n,) [m^dim; in 2D plane strain m^2 per metre of depth], and return SI
quantities.  Add a leading batch axis with ``jax.vmap`` (e.g. over frames).

Particle volume
---------------
``V_p = vol_p * J_p`` when ``J`` is passed (the current volume, so that the profile is the
geometric height of the weakly compressible MPM material), else ``V_p = vol_p`` (the
volume at rest, i.e. mass / rho: the height the same mass would have if it were exactly
incompressible).  The default is the volume at rest: the real tailings are practically
incompressible and the Tait compressibility of the model is a numerical device, so the
rest-volume height is the better estimate of what a laboratory measures and its integral
is exactly the (conserved) released volume.  Pass ``J=frames.J[i]`` for the geometric
height.  Inactive particles (``active`` False) contribute nothing, whatever their ``x``.

Kernel
------
``K_b(u) = exp(-u^2 / (2 b^2)) / (sqrt(2 pi) b)`` (Gaussian, unit integral, C-infinity, never
exactly zero, so every derivative exists and stays finite however thin the material is),
with bandwidth ``b`` [m].  Choose ``b`` >= the particle spacing (h / ppc) so that the estimate
does not resolve single particles; ``b`` ~ one cell is a good default.  In 3D the kernel is
the product of two such Gaussians over the horizontal axes (unit integral over the plane).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = [
    "FRONT_FRACTION",
    "runout",
    "free_surface_front",
    "front_threshold",
    "gaussian_kernel",
    "height_profile",
    "smooth_front",
    "deposited_volume",
    "particle_volume",
]

FRONT_FRACTION = 0.1  # headline front: thickness >= 10 % of the frame's thickest point (docstring)


def runout(x, active, axis: int, origin: float, spacing: float):
    """Front position [m] per frame. ``x``: (..., n, dim); ``active``: (..., n)."""
    xa = jnp.where(active, x[..., axis], -jnp.inf)
    return jnp.max(xa, axis=-1) + 0.5 * spacing - origin




def gaussian_kernel(u, bandwidth):
    """K_b(u) = exp(-u^2/(2 b^2)) / (sqrt(2 pi) b) [1/m]; unit integral over u."""
    b = bandwidth
    return jnp.exp(-0.5 * (u / b) ** 2) / (math.sqrt(2.0 * math.pi) * b)


def particle_volume(vol, active, J=None):
    """V_p [m^dim]: ``vol * J`` (if ``J`` given) on active particles, 0 on inactive ones."""
    v = vol if J is None else vol * J
    return jnp.where(active, v, jnp.zeros_like(v))


def _horizontal_axes(dim: int, vertical_axis: int) -> list[int]:
    va = vertical_axis % dim
    return [a for a in range(dim) if a != va]


def height_profile(x, vol, active, x_grid, *, bandwidth, dim=2, vertical_axis=-1, J=None):
    """Depth-integrated height h at fixed horizontal stations [m].

    2D (plane strain): ``x_grid`` (M,) horizontal positions [m] and

        h(x_j) = sum_p V_p K_b(x_j - x_p),

    with x_p the particle's horizontal coordinate, V_p its area per metre of depth [m^2]
    (see the module docstring: rest volume, or current volume when ``J`` is given) and K_b
    the Gaussian kernel of bandwidth b = ``bandwidth`` [m].  Since K_b has unit integral,
    the integral of h over x equals the total area: h is the kernel estimate of the
    thickness of a single-layer flow without overhangs (a fold or splash that puts
    material above material counts once per layer, which is still the depth integral).

    3D: ``x_grid`` (M, 2) horizontal positions (the two non-vertical axes in increasing
    order) and h(x_j) = sum_p V_p K_b(x_j1 - x_p1) K_b(x_j2 - x_p2) [m].

    Returns (M,) [m].  Finite with finite gradients for any particle configuration
    (including none active: h = 0).
    """
    if dim not in (2, 3):
        raise ValueError(f"dim = {dim}; allowed: 2 or 3")
    if x.shape[-1] != dim:
        raise ValueError(f"x has shape {x.shape}; expected (n, {dim})")
    axes = _horizontal_axes(dim, vertical_axis)
    V = particle_volume(vol, active, J)
    # inactive particles may sit anywhere (or be non-finite): park them at 0 so that
    # neither the value nor the gradient sees their coordinates (double-where)
    xs = jnp.where(active[:, None], x, jnp.zeros_like(x))
    grid = jnp.asarray(x_grid, x.dtype)
    if dim == 2:
        if grid.ndim != 1:
            raise ValueError(f"x_grid has shape {grid.shape}; expected (M,) in 2D")
        K = gaussian_kernel(grid[:, None] - xs[None, :, axes[0]], bandwidth)
    else:
        if grid.ndim != 2 or grid.shape[-1] != 2:
            raise ValueError(f"x_grid has shape {grid.shape}; expected (M, 2) in 3D")
        K = gaussian_kernel(grid[:, None, 0] - xs[None, :, axes[0]], bandwidth) * gaussian_kernel(
            grid[:, None, 1] - xs[None, :, axes[1]], bandwidth
        )
    return K @ V


def smooth_front(
    x,
    vol,
    active,
    *,
    threshold_height,
    bandwidth,
    x_lo,
    x_hi,
    n_grid=400,
    softness=None,
    vertical_axis=-1,
    J=None,
):
    """Smooth front (runout) position along the horizontal axis, 2D [m].

    Definition: with h the height profile of ``height_profile`` (bandwidth b), threshold
    h_c = ``threshold_height`` [m], softness s (default h_c / 10) [m], and the envelope
    from the right H(x) = max_{x' >= x} h(x'),

        x_front = x_lo + integral_{x_lo}^{x_hi} sigmoid((H(x) - h_c) / s) dx,

    evaluated by the trapezoidal rule on ``n_grid`` equally spaced stations of
    [x_lo, x_hi] (H is the reverse cumulative maximum over the stations).  H is
    non-increasing, so the integrand is a smooth step from ~1 to ~0 located where the
    smoothed height last falls below h_c: x_front is that position, whatever lies behind
    it (gaps, a block that does not start at x_lo).  Take x_lo behind the material and
    x_hi beyond the farthest reach.

    Why this form: it is continuous in every particle coordinate and volume and smooth
    wherever the last crossing of h_c is a single crossing (Gaussian kernel, logistic
    step, fixed quadrature; H(x) = h(x) near a decreasing front); it ignores stray
    particles (one particle alone gives a height V_p / (sqrt(2 pi) b), below any sensible
    h_c); and it stays finite with finite gradients when the material is thin: h << h_c
    makes the integrand and its derivative tend to 0 exponentially (x_front -> x_lo),
    never to 0/0.  A volume-weighted soft maximum of the particle x would instead be
    dominated by the farthest particle, like the hard maximum in ``mpmjax.runout``.
    Bias: the integrand is sigmoid(-h_c/s) (4.5e-5 at the default s = h_c/10), not 0,
    where there is no material, and 1 - sigmoid((h_max - h_c)/s) below 1 under the
    deposit: with a large s (e.g. h_c/4: 1.8e-2) these add a few mm per metre of
    [x_lo, x_hi].  Keep s <= h_c/10.  Caveat: the derivative jumps when two separate humps both reach about h_c and the
    farther one drops below (the maximum switches); the station spacing
    (x_hi - x_lo)/(n_grid - 1) should be well below b.

    Returns a scalar [m].
    """
    dim = x.shape[-1]
    if dim != 2:
        raise ValueError(f"smooth_front is defined for 2D (plane strain) data; got dim = {dim}")
    grid = jnp.linspace(x_lo, x_hi, n_grid, dtype=x.dtype)
    h = height_profile(x, vol, active, grid, bandwidth=bandwidth, dim=2, vertical_axis=vertical_axis, J=J)
    return _front_of_profile(h, threshold_height, softness, x_lo, x_hi)


def _front_of_profile(h, threshold_height, softness, x_lo, x_hi):
    """x_lo + integral of sigmoid((H - h_c)/s) over [x_lo, x_hi], with H the envelope of ``h``
    (on equally spaced stations) from the right, linear between stations (``smooth_front``).

    The integral over each station interval is exact for the linear H:
    s/(H1 - H0) (softplus((H1 - h_c)/s) - softplus((H0 - h_c)/s)), or the midpoint value
    where H1 - H0 is below s/100 (the two agree there to ~1e-5).  So a front whose step is
    sharper than the station spacing (a vertical edge) still lands where the linear
    envelope crosses h_c, not on a station.
    """
    s = threshold_height / 10.0 if softness is None else softness
    env = jax.lax.cummax(h, axis=0, reverse=True)
    z0, z1 = (env[:-1] - threshold_height) / s, (env[1:] - threshold_height) / s
    dz = z1 - z0
    flat = jnp.abs(dz) < 1e-2
    dz_safe = jnp.where(flat, 1.0, dz)  # double where: no 0/0 in the value or the gradient
    exact = (jax.nn.softplus(z1) - jax.nn.softplus(z0)) / dz_safe
    seg = jnp.where(flat, jax.nn.sigmoid(0.5 * (z0 + z1)), exact)
    dx = (x_hi - x_lo) / (h.shape[0] - 1)
    return x_lo + dx * jnp.sum(seg)


def front_threshold(h, fraction=FRONT_FRACTION):
    """Threshold height [m] of the free-surface front: ``fraction`` of the largest height of
    the profile ``h`` (the thickest point of the frame)."""
    return fraction * jnp.max(h)


def free_surface_front(x, vol, active, *, bandwidth, x_lo, x_hi, fraction=FRONT_FRACTION, n_grid=None, J=None):
    """Free-surface front [m] of a 2D (plane strain) frame: ``smooth_front`` of the height
    profile with the threshold ``front_threshold`` (``fraction`` of the profile's largest
    height) and the default softness (a tenth of the threshold).

    ``bandwidth``: kernel bandwidth [m] (the headline runout uses one cell h); ``x_lo`` /
    ``x_hi``: the stretch searched (the domain along x) [m]; ``n_grid``: stations (default 3
    per bandwidth, at least 50).  Pure JAX and differentiable (the threshold moves with the
    largest height; its gradient is that of the maximum).  With no active particle it
    returns ``x_lo``.  Returns a position [m] (not yet minus a runout origin).
    """
    dim = x.shape[-1]
    if dim != 2:
        raise ValueError(f"free_surface_front is defined for 2D (plane strain) data; got dim = {dim}")
    if n_grid is None:
        n_grid = front_stations(x_lo, x_hi, bandwidth)
    grid = jnp.linspace(x_lo, x_hi, n_grid, dtype=x.dtype)
    h = height_profile(x, vol, active, grid, bandwidth=bandwidth, dim=2, J=J)
    # an empty frame has h = 0: a positive floor keeps the sigmoid finite (the front is x_lo)
    h_c = jnp.maximum(front_threshold(h, fraction), 1e-30)
    return _front_of_profile(h, h_c, None, x_lo, x_hi)


def front_stations(x_lo, x_hi, bandwidth) -> int:
    """Default number of stations of ``free_surface_front``: 3 per bandwidth, at least 50."""
    return max(50, int(math.ceil(3 * (x_hi - x_lo) / bandwidth)) + 1)


def deposited_volume(x, vol, active, region_lo, region_hi, *, softness, J=None):
    """Volume of material inside the box [region_lo, region_hi] [m^dim; 2D: m^2 per metre].

    Definition, with s = ``softness`` [m] and sigma the logistic function:

        V = sum_p V_p prod_d [ sigma((x_pd - lo_d)/s) - sigma((x_pd - hi_d)/s) ],

    a smooth indicator of the box (-> the hard count of V_p inside as s -> 0; at a face
    the indicator is 1/2).  ``region_lo`` / ``region_hi``: scalars or (dim,) [m]; use
    -inf / +inf for an unbounded side (e.g. ``region_lo=(0.4, -inf)`` is "beyond x = 0.4
    m").  Choose s ~ the particle spacing.  Returns a scalar.
    """
    dim = x.shape[-1]
    lo = jnp.broadcast_to(jnp.asarray(region_lo, x.dtype), (dim,))
    hi = jnp.broadcast_to(jnp.asarray(region_hi, x.dtype), (dim,))
    V = particle_volume(vol, active, J)
    xs = jnp.where(active[:, None], x, jnp.zeros_like(x))
    # sigma(+-inf) is exactly 0 or 1 with zero derivative: unbounded sides are safe
    ind = jax.nn.sigmoid((xs - lo[None, :]) / softness) - jax.nn.sigmoid((xs - hi[None, :]) / softness)
    return jnp.sum(V * jnp.prod(ind, axis=-1))
