"""Scenario metrics computed on the host from saved frames (numpy or jax arrays).

Definitions (also in ``docs/scenarios.md``):

``kinetic_energy``
    E_k = 1/2 sum_p rho V0_p |v_p|^2 over active particles [J; 2D: J/m].  The mass is
    rho V0_p, the same mass the P2G transfer uses (mass is conserved, V0 is not J V0).
``time_to_rest``
    With the peak E_max = max_k E_k(t_k), the time to rest is the first saved time t_k
    at or after the peak from which E_k stays at or below ``rel_threshold * E_max``
    (and below ``abs_threshold_J``, if given) up to the end of the record.  It is nan if
    the last saved frame is still above the threshold (never at rest within the run), or
    if the rest lasts less than ``min_rest_s`` before the record ends.  A record with
    E_max = 0 is at rest from its first time.
``mobilised_fraction``
    Fraction (by initial volume, or by count without ``vol0``) of the particles active
    at the end whose displacement |x - x0| exceeds ``distance_m``.
``surface_profile``
    Free-surface elevation per column: the highest active particle in each bin of the
    horizontal coordinate plus half the particle spacing [m]; nan in empty bins.
``beach_slope``
    Least-squares slope dh/dx [-] of the deposit surface h(x) over a window.  The
    default window is the wetted extent (bins with h - bed > ``min_depth_m``) with
    ``trim`` of its length removed at each end (the toe and the inflow mound).  The
    slope is negative for a surface falling in +x.  nan with fewer than 3 points.
"""

from __future__ import annotations

import math

import numpy as np


def _xp(*arrays):
    """The array module (jax.numpy or numpy) of the inputs."""
    for a in arrays:
        if type(a).__module__.startswith("jax"):
            import jax.numpy as jnp

            return jnp
    return np


def kinetic_energy(v, vol0, active, rho):
    """Kinetic energy [J; 2D: J per metre of depth].

    Args:
      v: velocities [m/s], (..., n, dim); leading frame axes allowed.
      vol0: initial particle volumes [m^3; 2D: m^2], (n,) or (..., n).
      active: bool mask (..., n); inactive particles contribute nothing.
      rho: density [kg/m^3] (scalar).
    Returns (...,) energies; works on numpy and jax arrays (jit/grad safe with jax).
    """
    xp = _xp(v, vol0, active, rho)
    v = xp.asarray(v)
    speed2 = xp.sum(v * v, axis=-1)
    m = rho * xp.asarray(vol0) * xp.asarray(active)
    return 0.5 * xp.sum(m * speed2, axis=-1)


def time_to_rest(t_s, kinetic_energy_J, *, rel_threshold: float = 0.01, abs_threshold_J=None, min_rest_s: float = 0.0):
    """Time [s] from which the kinetic energy stays below ``rel_threshold`` of its peak.

    Args:
      t_s: saved times [s], (n_frames,), increasing.
      kinetic_energy_J: kinetic energy at those times, (n_frames,).
      rel_threshold: fraction of the peak energy counted as rest, in (0, 1).
      abs_threshold_J: optional absolute bound [J]; rest also needs E <= it.
      min_rest_s: the rest must last at least this long before the record ends.
    Returns the first saved time of the final rest interval, or nan if never at rest.
    """
    t = np.asarray(t_s, float).ravel()
    e = np.asarray(kinetic_energy_J, float).ravel()
    if t.shape != e.shape or t.size == 0:
        raise ValueError(f"t_s and kinetic_energy_J need the same non-empty length; got {t.size} and {e.size}")
    if not 0.0 < rel_threshold < 1.0:
        raise ValueError(f"rel_threshold={rel_threshold}; allowed: 0 < rel_threshold < 1")
    if not np.all(np.isfinite(e)):
        return math.nan
    peak = int(np.argmax(e))
    e_max = e[peak]
    if e_max <= 0.0:
        return float(t[0])
    thr = rel_threshold * e_max
    if abs_threshold_J is not None:
        thr = min(thr, float(abs_threshold_J))
    above = e > thr
    if above[-1]:
        return math.nan
    last_above = int(np.nonzero(above)[0][-1]) if above.any() else -1
    k = max(last_above + 1, peak)
    if t[-1] - t[k] < min_rest_s:
        return math.nan
    return float(t[k])


def mobilised_fraction(x0, x, active, distance_m: float, vol0=None) -> float:
    """Fraction of active particles displaced by more than ``distance_m`` [m].

    Args:
      x0: initial (or release) positions [m], (n, dim).
      x: positions [m], (n, dim).
      active: bool (n,): particles counted (active at the time of ``x``).
      distance_m: displacement threshold [m], > 0.
      vol0: optional volumes (n,) to weight by; count fraction otherwise.
    Returns a float in [0, 1]; nan with no active particle.
    """
    if not distance_m > 0:
        raise ValueError(f"distance_m={distance_m}; allowed: > 0")
    x0, x = np.asarray(x0, float), np.asarray(x, float)
    a = np.asarray(active, bool)
    w = np.ones(a.shape) if vol0 is None else np.asarray(vol0, float) * np.ones(a.shape)
    w = np.where(a, w, 0.0)
    tot = w.sum()
    if tot <= 0:
        return math.nan
    moved = np.linalg.norm(x - x0, axis=-1) > distance_m
    return float(np.sum(w * moved) / tot)


def surface_profile(x, active, x_edges, spacing_m: float, *, axis: int = 0):
    """Free-surface elevation [m] per bin of ``x[:, axis]`` (highest particle + spacing/2).

    Args:
      x: positions [m], (n, dim); the last axis is vertical.
      active: bool (n,).
      x_edges: bin edges [m] along ``axis``, (n_bins + 1,), increasing.
      spacing_m: initial particle spacing [m] (the block's top is its top particle plus half).
    Returns (centres (n_bins,), elevation (n_bins,)) with nan in empty bins.
    """
    x = np.asarray(x, float)
    a = np.asarray(active, bool)
    edges = np.asarray(x_edges, float)
    xc = 0.5 * (edges[1:] + edges[:-1])
    top = np.full(xc.shape, -np.inf)
    xa = x[a]
    k = np.searchsorted(edges, xa[:, axis], side="right") - 1
    ok = (k >= 0) & (k < xc.size)
    np.maximum.at(top, k[ok], xa[ok, -1])
    top = np.where(np.isfinite(top), top + 0.5 * spacing_m, np.nan)
    return xc, top


def beach_slope(x_grid, h, *, window=None, bed=0.0, min_depth_m: float = 0.0, trim: float = 0.1) -> float:
    """Least-squares slope dh/dx [-] of a deposit surface.

    Args:
      x_grid: horizontal positions [m], (n,).
      h: surface elevation [m], (n,); nan where there is no material.
      window: optional (x_lo, x_hi) [m]; points with x_lo <= x <= x_hi are used.
      bed: bed elevation [m], scalar or (n,); used for the default window.
      min_depth_m: default window: points with h - bed > min_depth_m are wetted.
      trim: default window: this fraction of the wetted extent is dropped at each end.
    Returns the slope (negative when the surface falls in +x), nan with < 3 points.
    """
    if not 0.0 <= trim < 0.5:
        raise ValueError(f"trim={trim}; allowed: 0 <= trim < 0.5")
    xg = np.asarray(x_grid, float).ravel()
    hh = np.asarray(h, float).ravel()
    if xg.shape != hh.shape:
        raise ValueError(f"x_grid and h need the same length; got {xg.size} and {hh.size}")
    good = np.isfinite(hh)
    if window is None:
        wet = good & (np.where(good, hh, -np.inf) - np.asarray(bed, float) > min_depth_m)
        if wet.sum() < 3:
            return math.nan
        x_lo, x_hi = xg[wet].min(), xg[wet].max()
        cut = trim * (x_hi - x_lo)
        sel = wet & (xg >= x_lo + cut) & (xg <= x_hi - cut)
    else:
        x_lo, x_hi = window
        sel = good & (xg >= x_lo) & (xg <= x_hi)
    if sel.sum() < 3:
        return math.nan
    slope, _ = np.polyfit(xg[sel], hh[sel], 1)
    return float(slope)
