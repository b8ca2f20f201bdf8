"""The inertia-free Bingham slump in the lubrication limit, solved in time: the reference of
``mpmjax validate``'s slumps at the run's own frame times, not only at rest.

A block H0 x L of Bingham fluid (density rho, plastic viscosity mu, yield stress tau_y) against a
wall at x = 0 on a horizontal no-slip bed spreads as a thin layer h(x, t) with

    h_t + q_x = 0,   q = -(rho g h_x / (6 mu)) Y^2 (3 h - Y),   Y = max(h - tau_y / (rho g |h_x|), 0),

Y the height of the yield surface (sheared below, pseudo-plug above; Liu & Mei 1989, Balmforth,
Craster, Rust & Sassi 2006, Matson & Hogg 2007).  At rest the profile is the critical one,
rho g h |h_x| = tau_y, whose front is REFERENCE.md's x_inf; a Newtonian layer (tau_y = 0) tends to
Huppert's (1982) similarity current.  The static x_inf is the end of the slump; at a Galileo
number of 1 the approach to it is slow (B = 0.05, L = 2 H0: the headline front 13 % short of it at
60 s, 2.3 % at 1000 s), so a run that stops at 60 s is compared with this solution at 60 s.

Numerics: finite volumes on n cells over [0, X] (zero flux at both ends; h at a face the mean of its
cells, h_x their difference), the block's cell averages at t = 0, and diffrax's Tsit5 with an
adaptive step (the layer's diffusion limits the explicit step; about 5e4 steps and 2 s of CPU for
60 s on 200 cells); float64, inside ``jax.enable_x64`` (float32 fails to keep the adaptive step going).
Measured (``tests/test_lubrication.py``): the volume to round-off, the front at rest within a cell
of x_inf, the Newtonian front within 1 % of Huppert's; the headline front at 60 s moves by at most
0.15 points between 200 and 400 cells.
"""

from __future__ import annotations

import functools
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .._observables import FRONT_FRACTION
from ._ode import solve_saved

# the solve: cells over [0, X], relative tolerance of the adaptive step, the most steps
N_CELLS = 200
RTOL = 1e-6
ATOL = 1e-7  # of the block height
MAX_STEPS = 4_000_000

# Huppert (1982): the front of a two-dimensional viscous current of area q released against a wall,
# x_N = eta (g q^3 t / (3 nu))^(1/5)
HUPPERT_ETA = 1.411


@functools.lru_cache(maxsize=None)
def _solver(rtol: float):
    def rhs(t, h, args):
        dx, k, ty = args
        s = (h[1:] - h[:-1]) / dx
        hf = 0.5 * (h[1:] + h[:-1])
        a = jnp.abs(s)
        yielded = hf * a > ty
        y = jnp.where(yielded, hf - ty / jnp.where(yielded, a, 1.0), 0.0)
        q = jnp.concatenate([jnp.zeros(1), -k * s * y * y * (3.0 * hf - y), jnp.zeros(1)])
        return -(q[1:] - q[:-1]) / dx

    @jax.jit
    def solve(h0, ts, dx, k, ty, atol, dt0):
        return solve_saved(rhs, diffrax.Tsit5(), h0, ts, dt0, (dx, k, ty), rtol=rtol, atol=atol, max_steps=MAX_STEPS)

    return solve


def slump_profiles(
    length_m: float,
    height_m: float,
    yield_stress_pa: float,
    viscosity_pa_s: float,
    times_s,
    *,
    density_kg_m3: float = 1000.0,
    g_m_s2: float = 9.81,
    extent_m: float | None = None,
    n_cells: int = N_CELLS,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Layer thickness h [m] of the slump at ``times_s`` [s] (increasing, > 0): (cell centres x (n,),
    h (len(times), n), steps taken).  ``extent_m``: the domain [0, X] (default 1.5 x_inf, or 1.5 x the
    Newtonian front at the last time); the layer must not reach its end (ValueError)."""
    for name, v in (("length_m", length_m), ("height_m", height_m), ("viscosity_pa_s", viscosity_pa_s)):
        if not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"{name} = {v!r} is invalid: allowed range > 0")
    if not (math.isfinite(yield_stress_pa) and yield_stress_pa >= 0.0):
        raise ValueError(f"yield_stress_pa = {yield_stress_pa!r} is invalid: allowed range >= 0")
    if int(n_cells) != n_cells or n_cells < 10:
        raise ValueError(f"n_cells = {n_cells!r} is invalid: allowed whole numbers >= 10")
    ts = np.asarray(times_s, float)
    if ts.ndim != 1 or ts.size == 0 or not np.all(np.isfinite(ts)) or ts[0] <= 0.0 or np.any(np.diff(ts) <= 0.0):
        raise ValueError(f"times_s = {times_s!r} is invalid: allowed increasing times > 0")
    if extent_m is None:
        if yield_stress_pa > 0.0:
            extent_m = 1.5 * static_front(length_m, height_m, yield_stress_pa, density_kg_m3, g_m_s2)
        else:
            q = length_m * height_m
            nu = viscosity_pa_s / density_kg_m3
            extent_m = 1.5 * max(length_m, HUPPERT_ETA * (g_m_s2 * q**3 * ts[-1] / (3.0 * nu)) ** 0.2)
    dx = extent_m / n_cells
    edges = np.arange(n_cells) * dx
    h0 = height_m * np.clip((length_m - edges) / dx, 0.0, 1.0)  # the block's cell averages
    k = density_kg_m3 * g_m_s2 / (6.0 * viscosity_pa_s)
    ty = yield_stress_pa / (density_kg_m3 * g_m_s2)
    with jax.enable_x64(True):  # for this solve only: the process's float32 runs stay as they are
        hs, steps = _solver(RTOL)(
            jnp.asarray(h0, jnp.float64), jnp.asarray(ts, jnp.float64), dx, k, ty, ATOL * height_m,
            # the first step: a tenth of the explicit limit dx^2 / (2 D) of the block's diffusivity D = 2 k H0^3
            # (from a first step of 1e-4 t_end the step was rejected without end on one of the four slumps)
            0.1 * dx * dx / (4.0 * k * height_m**3),
        )
    hs = np.asarray(hs)
    if np.any(hs[:, -1] > 1e-6 * height_m):
        raise ValueError(f"extent_m = {extent_m!r}: the layer reached the end of the domain; allowed a larger extent")
    return edges + 0.5 * dx, hs, int(steps)


def static_front(length_m, height_m, yield_stress_pa, density_kg_m3=1000.0, g_m_s2=9.81) -> float:
    """x_inf [m], the front at rest (REFERENCE.md): L + rho g H0^2/(6 tau_y) for B >= 1/3,
    (9 rho g H0^2 L^2/(8 tau_y))^(1/3) for B <= 1/3, B = tau_y L/(rho g H0^2)."""
    rg = density_kg_m3 * g_m_s2
    if yield_stress_pa * length_m / (rg * height_m**2) >= 1.0 / 3.0:
        return length_m + rg * height_m**2 / (6.0 * yield_stress_pa)
    return (9.0 * rg * height_m**2 * length_m**2 / (8.0 * yield_stress_pa)) ** (1.0 / 3.0)


def wetted_front(x, h, floor_m: float) -> float:
    """The end of the layer [m]: the far face of the last cell thicker than ``floor_m``."""
    wet = np.nonzero(np.asarray(h) > floor_m)[0]
    dx = float(x[1] - x[0])
    return float(x[wet[-1]] + 0.5 * dx) if wet.size else 0.0


def headline_front(x, h, fraction: float = FRONT_FRACTION) -> float:
    """The front as a run's headline runout measures it (``_metrics.RunoutGauge``): where the layer
    last falls to ``fraction`` of its thickest, interpolated linearly between cell centres."""
    h = np.asarray(h, float)
    thr = fraction * float(h.max())
    i = int(np.nonzero(h >= thr)[0][-1])
    if i + 1 >= h.size or h[i] == h[i + 1]:
        return float(x[i])
    return float(x[i] + (h[i] - thr) / (h[i] - h[i + 1]) * (x[1] - x[0]))
