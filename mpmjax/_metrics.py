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

``RunoutGauge``
    The run's runout, both definitions of ``mpmjax._observables`` (docs/output.md "Runout"):
    ``front`` (headline: the free-surface front, thickness >= 10 % of the frame's thickest
    point) and ``farthest`` (the farthest particle).  In 3D the thickness is the rest volume per
    plan-view bin of one cell (``thickness_map``), its largest value across the flow in each
    column along the runout axis, and the front the last column at or above the threshold,
    interpolated linearly to where the envelope crosses it.  A runout axis along the vertical
    (the last axis) has no free-surface profile: the front is then the farthest particle.

Plan-view metrics of 3D runs (``plan_view_summary``; x is the flow axis, y lateral, z normal
to the base; bins of one cell size h on the run's x-y grid):

``thickness_map``
    Rest volume of the active particles (V0 = mass / rho) in a bin's column / bin area [m]: the
    depth of material at its rest density.  Not J V0: J drifts in long runs (0.37..7.9 in
    field-dambreak-3d at 400 s), which made J V0 thicknesses of 24 m where the surface is at 8 m.
``lobe_width``
    Widest transverse section of the deposit [m]: in each row of bins at fixed x, the distance
    between the outer edges of the outermost bins thicker than a threshold (summary.json: 10 % of
    the frame's thickest bin); mirrored about a symmetry plane (half models).
``plan_view_mean``
    Plan-view map: bin mean of log10 mu (or of |v|) over the active particles; nan in bins with
    fewer than ``PLAN_MIN_COUNT`` particles.
``channel_sections``
    Per transverse section: lateral viscosity contrast (max - min of the bin-mean log10 mu
    [decades]), speed coefficient of variation and max/min ratio; a channel is a bin at least
    ``CHANNEL_CONTRAST_DECADES`` below the stiffest bin on each side of it and at least
    ``CHANNEL_SPEED_RATIO`` times faster than both (and >= ``CHANNEL_MIN_SPEED_M_S``).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import NamedTuple

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from ._io import frame_volumes
from ._observables import FRONT_FRACTION, free_surface_front, front_stations, height_profile, runout
from ._shallow import cell_depth_map


def _xp(*arrays):
    """The array module (jax.numpy or numpy) of the inputs."""
    for a in arrays:
        if type(a).__module__.startswith("jax"):
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


# --- plan-view (x-y) metrics of 3D runs ------------------------------------------------------


def _plan_index(x, active, x_edges, y_edges):
    """Bin indices (i along x, j along y) of the active particles inside the x-y grid, and the mask
    of the particles used."""
    x = np.asarray(x, float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x: expected (n, 3) positions [m] of a 3D run; got shape {x.shape}")
    xe, ye = np.asarray(x_edges, float), np.asarray(y_edges, float)
    for name, e in (("x_edges", xe), ("y_edges", ye)):
        if e.ndim != 1 or e.size < 2 or not np.all(np.diff(e) > 0):
            raise ValueError(f"{name}: expected increasing bin edges [m] (at least 2); got {e!r}")
    a = np.asarray(active, bool) & np.all(np.isfinite(x), axis=1)
    i = np.searchsorted(xe, x[:, 0], side="right") - 1
    j = np.searchsorted(ye, x[:, 1], side="right") - 1
    use = a & (i >= 0) & (i < xe.size - 1) & (j >= 0) & (j < ye.size - 1)
    return i, j, use, (xe.size - 1, ye.size - 1)


def plan_view_mean(x, values, active, x_edges, y_edges, *, min_count: int = 1):
    """Plan-view (x-y) bin means of a per-particle quantity over the active particles.

    Args:
      x: positions [m], (n, 3).
      values: (n,) values to average (e.g. log10 of the viscosity, or the speed).
      active: bool (n,).
      x_edges, y_edges: increasing bin edges [m] along x and y.
      min_count: bins holding fewer active particles are nan.
    Returns (mean (nx, ny), count (nx, ny)); the mean is nan where count < ``min_count``.
    Particles outside the edges, inactive or with a non-finite value are left out.
    """
    v = np.asarray(values, float)
    i, j, use, shape = _plan_index(x, active, x_edges, y_edges)
    use = use & np.isfinite(v)
    s = np.zeros(shape)
    c = np.zeros(shape, dtype=np.int64)
    np.add.at(s, (i[use], j[use]), v[use])
    np.add.at(c, (i[use], j[use]), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(c >= max(int(min_count), 1), s / np.maximum(c, 1), np.nan)
    return mean, c


def thickness_map(x, volume, active, x_edges, y_edges):
    """Deposit thickness [m] per plan-view bin: the volume of the active particles in the bin's
    column divided by the bin's area (0 where empty).

    With the rest volumes ``vol0`` this is the depth of material at its rest density averaged over
    the bin: a bin fully covered by one layer of particles of spacing s (ppc^2 particles of s^3
    each on an h x h bin, s = h / ppc) has a thickness of s.
    """
    vol = np.asarray(volume, float) * np.ones(np.shape(active))
    i, j, use, shape = _plan_index(x, active, x_edges, y_edges)
    use = use & np.isfinite(vol)
    t = np.zeros(shape)
    np.add.at(t, (i[use], j[use]), vol[use])
    area = np.outer(np.diff(np.asarray(x_edges, float)), np.diff(np.asarray(y_edges, float)))
    return t / area


def lobe_width(thickness_m, y_edges, min_thickness_m: float, *, symmetry_y_m=None):
    """Lateral extent [m] of the deposit perpendicular to the flow axis (x).

    A plan-view bin is covered when its thickness exceeds ``min_thickness_m``.  The width of a
    transverse section (one row of bins at fixed x) is the distance between the outer edges of
    its outermost covered bins (gaps between them count as width).  With a symmetry plane at
    ``y = symmetry_y_m`` (a half model) the width is that of the mirrored deposit:
    2 * max |y_edge - symmetry_y_m| over the covered bins' outer edges.

    Args:
      thickness_m: (nx, ny) thickness map [m] (``thickness_map``).
      y_edges: (ny + 1,) bin edges along y [m].
      min_thickness_m: threshold [m], >= 0.
      symmetry_y_m: y of a symmetry plane of the model [m], or None.
    Returns (width [m] of the widest section (0 if nothing is covered), index of that section
    (-1 if none), per-section widths (nx,) [m]).
    """
    if not min_thickness_m >= 0:
        raise ValueError(f"min_thickness_m={min_thickness_m}; allowed: >= 0 [m]")
    th = np.asarray(thickness_m, float)
    ye = np.asarray(y_edges, float)
    if th.ndim != 2 or th.shape[1] != ye.size - 1:
        raise ValueError(f"thickness_m has shape {th.shape}; expected (nx, {ye.size - 1}) for {ye.size} y_edges")
    cov = th > min_thickness_m
    any_cov = cov.any(axis=1)
    first = np.argmax(cov, axis=1)
    last = ye.size - 2 - np.argmax(cov[:, ::-1], axis=1)
    lo, hi = ye[first], ye[last + 1]
    if symmetry_y_m is None:
        w = hi - lo
    else:
        w = 2.0 * np.maximum(np.abs(lo - symmetry_y_m), np.abs(hi - symmetry_y_m))
    w = np.where(any_cov, w, 0.0)
    if not any_cov.any():
        return 0.0, -1, w
    k = int(np.argmax(w))
    return float(w[k]), k, w


class ChannelSections(NamedTuple):
    """Per transverse section (row of plan-view bins at fixed x) of one frame; nan/False/-1 where
    the section has fewer than ``min_bins`` occupied bins."""

    viscosity_contrast_decades: np.ndarray  # (nx,) max - min of the bin-mean log10 mu across the section
    speed_cv: np.ndarray  # (nx,) std / mean of the bin-mean speed across the section [-]
    speed_ratio: np.ndarray  # (nx,) max / min of the bin-mean speed across the section [-] (inf if min is 0)
    channel: np.ndarray  # (nx,) bool: the section holds a channel (definition in ``channel_sections``)
    channel_bin: np.ndarray  # (nx,) y-bin index of the channel (-1: none)


def channel_sections(
    log10_mu,
    speed,
    *,
    contrast_decades: float = 1.0,
    speed_ratio: float = 2.0,
    min_speed_m_s: float = 0.01,
    min_bins: int = 3,
    mirror: str | None = None,
) -> ChannelSections:
    """Lateral contrast of viscosity and speed across the transverse sections of a lobe, and
    self-forming channels.

    Each row ``i`` of the plan-view maps is a transverse section (fixed x, bins along y); only
    bins where both maps are finite (occupied) count.  Per section:

    * viscosity contrast [decades] = max - min over the section of the bin-mean log10 mu
      (1 decade = a factor 10 between the stiffest and the most fluid bin);
    * speed coefficient of variation = std / mean of the bin-mean speed across the section, and
      the speed ratio max / min;
    * a **channel**: a bin c whose viscosity is at least ``contrast_decades`` below the stiffest
      bin on *each* side of it (material at least 10^contrast_decades times stiffer flanks it on
      both sides: levees), that moves at least ``speed_ratio`` times faster than both of those
      stiffest flank bins and at least ``min_speed_m_s``.  Of several candidates the most fluid
      (lowest log10 mu) is reported.

    ``mirror``: "low" or "high" if the model has a symmetry plane at the low or high y end
    of the maps (a half model): the section is mirrored about it first, so that a fluid lane on
    the plane is flanked by its mirror image.

    Args:
      log10_mu: (nx, ny) bin means of log10 viscosity [log10 Pa s]; nan where empty.
      speed: (nx, ny) bin means of |v| [m/s]; nan where empty.
    Returns ``ChannelSections``.
    """
    if not contrast_decades > 0:
        raise ValueError(f"contrast_decades={contrast_decades}; allowed: > 0")
    if not speed_ratio >= 1:
        raise ValueError(f"speed_ratio={speed_ratio}; allowed: >= 1")
    if not min_speed_m_s >= 0:
        raise ValueError(f"min_speed_m_s={min_speed_m_s}; allowed: >= 0 [m/s]")
    if mirror not in (None, "low", "high"):
        raise ValueError(f"mirror={mirror!r}; allowed: None, 'low', 'high'")
    lm, sp = np.asarray(log10_mu, float), np.asarray(speed, float)
    if lm.shape != sp.shape or lm.ndim != 2:
        raise ValueError(f"log10_mu and speed need the same (nx, ny) shape; got {lm.shape} and {sp.shape}")
    nx, ny = lm.shape
    contrast = np.full(nx, np.nan)
    cv = np.full(nx, np.nan)
    ratio = np.full(nx, np.nan)
    chan = np.zeros(nx, bool)
    cbin = np.full(nx, -1)
    for i in range(nx):
        ok = np.isfinite(lm[i]) & np.isfinite(sp[i])
        idx = np.nonzero(ok)[0]
        if idx.size < min_bins:
            continue
        m, s = lm[i, idx], sp[i, idx]
        contrast[i] = m.max() - m.min()
        mean = s.mean()
        cv[i] = s.std() / mean if mean > 0 else np.nan
        ratio[i] = s.max() / s.min() if s.min() > 0 else np.inf
        if mirror == "low":
            m, s, idx = np.r_[m[::-1], m], np.r_[s[::-1], s], np.r_[idx[::-1], idx]
        elif mirror == "high":
            m, s, idx = np.r_[m, m[::-1]], np.r_[s, s[::-1]], np.r_[idx, idx[::-1]]
        best = None
        for c in range(1, m.size - 1):
            kl = int(np.argmax(m[:c]))
            kr = c + 1 + int(np.argmax(m[c + 1 :]))
            if min(m[kl], m[kr]) - m[c] < contrast_decades:
                continue
            if s[c] < min_speed_m_s or s[c] < speed_ratio * max(s[kl], s[kr]):
                continue
            if best is None or m[c] < m[best]:
                best = c
        if best is not None:
            chan[i] = True
            cbin[i] = int(idx[best])
    return ChannelSections(contrast, cv, ratio, chan, cbin)


def plan_view_series(x, v, mu, active, volume, x_edges, y_edges, *, min_count: int = 2) -> dict:
    """Plan-view maps of every saved frame of a 3D run.

    Args:
      x: positions [m], (F, n, 3); v: velocities [m/s], (F, n, 3); mu: viscosity [Pa s], (F, n);
      active: bool (F, n); volume: particle volumes [m^3], (F, n) or (n,) (rest volumes vol0 in
        ``plan_view_summary``).
      x_edges, y_edges: bin edges [m].
      min_count: the bin means (viscosity, speed) are nan in bins with fewer active particles.
    Returns a dict of (F, nx, ny) arrays: ``log10_mu`` (bin mean of log10 mu [log10 Pa s]),
    ``speed_m_s`` (bin mean of |v|), ``thickness_m`` (``thickness_map``), ``count``.
    """
    x, v, mu = np.asarray(x), np.asarray(v), np.asarray(mu, float)
    act = np.asarray(active, bool)
    vol = np.asarray(volume, float) * np.ones(act.shape)
    out = {"log10_mu": [], "speed_m_s": [], "thickness_m": [], "count": []}
    for k in range(act.shape[0]):
        with np.errstate(divide="ignore", invalid="ignore"):
            lmu = np.where(mu[k] > 0, np.log10(np.where(mu[k] > 0, mu[k], 1.0)), np.nan)
        m, c = plan_view_mean(x[k], lmu, act[k], x_edges, y_edges, min_count=min_count)
        s, _ = plan_view_mean(x[k], np.linalg.norm(v[k], axis=-1), act[k], x_edges, y_edges, min_count=min_count)
        out["log10_mu"].append(m)
        out["speed_m_s"].append(s)
        out["thickness_m"].append(thickness_map(x[k], vol[k], act[k], x_edges, y_edges))
        out["count"].append(c)
    return {k: np.stack(a) for k, a in out.items()}


def write_plan_view(path, t_s, x_edges, y_edges, maps: dict, attrs: dict):
    """Write plan-view maps (``plan_view_series``) to an HDF5 file (through a temporary file
    and a rename): ``/t_s`` (F,), ``/x_edges_m`` (nx+1,), ``/y_edges_m`` (ny+1,) and one
    (F, nx, ny) dataset per map (float32, gzip; ``count`` int32), ``attrs`` as JSON in the
    root attribute ``attrs_json`` and the unit of each dataset in ``units_json``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    units = {"t_s": "s", "x_edges_m": "m", "y_edges_m": "m", "log10_mu": "log10(Pa s)", "speed_m_s": "m/s"}
    units.update(thickness_m="m", count="particles")
    with h5py.File(tmp, "w") as f:
        f["t_s"] = np.asarray(t_s, float)
        f["x_edges_m"] = np.asarray(x_edges, float)
        f["y_edges_m"] = np.asarray(y_edges, float)
        for name, arr in maps.items():
            dt = "i4" if name == "count" else "f4"
            f.create_dataset(name, data=np.asarray(arr).astype(dt), compression="gzip", compression_opts=4)
        f.attrs["attrs_json"] = json.dumps(attrs)
        f.attrs["units_json"] = json.dumps(units)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_plan_view(path) -> dict:
    """The maps written by ``write_plan_view`` as numpy arrays (``attrs`` parsed)."""
    p = Path(path)
    if p.is_dir():
        p = p / "plan_view.h5"
    with h5py.File(p, "r") as f:
        d = {k: f[k][()] for k in f}
        d["attrs"] = json.loads(f.attrs["attrs_json"])
    return d


# thresholds of the summary.json lobe and channel metrics (docs/output.md)
LOBE_THRESHOLD_FRACTION = 0.1  # a bin is covered when thicker than this fraction of the frame's thickest bin
CHANNEL_CONTRAST_DECADES = 1.0
CHANNEL_SPEED_RATIO = 2.0
CHANNEL_MIN_SPEED_M_S = 0.01
PLAN_MIN_COUNT = 2


def plan_view_summary(result, path=None, plan=None) -> dict:
    """Lobe width, plan-view viscosity map and channel metric of a 3D run for summary.json.

    ``result``: the dict of ``mpmjax._io.read_result`` (the scene is read from its
    ``scene_config_json``).  The plan-view grid is the run's grid in x and y (bins of one
    cell size h).  With ``path``, every frame's maps are written there (``write_plan_view``).
    ``plan``: the built scene of a depth-averaged run, whose thickness maps (and so the lobe width
    and covered area) are then the step's own depth on each cell (``_shallow.cell_depth_map``, as
    its hazard maps) instead of the rest volumes binned by particle position, which scatter by a
    third about it as the columns drift in and out of the bins (docs/depth-averaged.md, "Maps").
    Returns a JSON-ready dict (definitions in docs/output.md).
    """
    cfg = json.loads(result["attrs"]["scene_config_json"])
    if int(cfg["domain.dim"]) != 3:
        raise ValueError(f"plan_view_summary: a 3D run is needed; this one is {cfg['domain.dim']}D")
    h = float(cfg["domain.cell_size_m"])
    lo, hi = cfg["domain.lo_m"], cfg["domain.hi_m"]
    xe = lo[0] + h * np.arange(int(round((hi[0] - lo[0]) / h)) + 1)
    ye = lo[1] + h * np.arange(int(round((hi[1] - lo[1]) / h)) + 1)
    sym_y, mirror = None, None
    if cfg["boundary.y_lo"] == "symmetry":
        sym_y, mirror = float(lo[1]), "low"
    elif cfg["boundary.y_hi"] == "symmetry":
        sym_y, mirror = float(hi[1]), "high"
    fr = result["frames"]
    vol = frame_volumes(result)  # rest volumes (J drifts: thickness_map), per frame where columns split
    maps = plan_view_series(fr["x_m"], fr["v_m_s"], fr["mu_pa_s"], fr["active"], vol, xe, ye, min_count=PLAN_MIN_COUNT)
    if plan is not None:
        depth = [cell_depth_map(plan, x, v, a) for x, v, a in zip(fr["x_m"], vol, fr["active"])]
        if depth and depth[0].shape != maps["thickness_m"][0].shape:
            raise ValueError(f"plan_view_summary: the plan's cells {depth[0].shape} are not the bins "
                             f"{maps['thickness_m'][0].shape}")
        maps["thickness_m"] = np.stack(depth) if depth else maps["thickness_m"]
    t = np.asarray(fr["t_s"], float)
    xc = 0.5 * (xe[1:] + xe[:-1])

    def fin(a, nd=6):
        a = float(a)
        return round(a, nd) if math.isfinite(a) else None

    widths, w_x, contrast, cv, n_chan, chan_x = [], [], [], [], [], []
    thr = 0.0
    for k in range(t.size):
        thr = LOBE_THRESHOLD_FRACTION * float(maps["thickness_m"][k].max())
        w, i, _ = lobe_width(maps["thickness_m"][k], ye, thr, symmetry_y_m=sym_y)
        widths.append(fin(w))
        w_x.append(fin(xc[i]) if i >= 0 else None)
        cs = channel_sections(
            maps["log10_mu"][k],
            maps["speed_m_s"][k],
            contrast_decades=CHANNEL_CONTRAST_DECADES,
            speed_ratio=CHANNEL_SPEED_RATIO,
            min_speed_m_s=CHANNEL_MIN_SPEED_M_S,
            mirror=mirror,
        )
        have = np.isfinite(cs.viscosity_contrast_decades)
        contrast.append(fin(np.max(cs.viscosity_contrast_decades[have])) if have.any() else None)
        cvk = cs.speed_cv[np.isfinite(cs.speed_cv)]
        cv.append(fin(cvk.max()) if cvk.size else None)
        n_chan.append(int(cs.channel.sum()))
        chan_x.append([fin(xc[cs.channel].min()), fin(xc[cs.channel].max())] if cs.channel.any() else None)
    first = next((float(t[k]) for k in range(t.size) if n_chan[k] > 0), None)
    lm, th = maps["log10_mu"][-1], maps["thickness_m"][-1]
    cov = th > thr
    good = np.isfinite(lm)
    area = h * h
    attrs = {
        "bin_m": h,
        "min_count": PLAN_MIN_COUNT,
        "lobe_threshold_fraction": LOBE_THRESHOLD_FRACTION,
        "symmetry_y_m": sym_y,
        "scene": cfg["name"],
        "thickness": "the depth-averaged step's depth on each cell" if plan is not None
        else "rest volume of the particles in each bin over its area",
    }
    if path is not None:
        write_plan_view(path, t, xe, ye, maps, attrs)
    return {
        "lobe_width_m": widths[-1],
        "lobe_width_m_per_frame": widths,
        "lobe_width_section_x_m": w_x[-1],
        "lobe_width_threshold_m": fin(thr),
        "lobe_width_threshold_fraction": LOBE_THRESHOLD_FRACTION,
        "lobe_width_mirrored": sym_y is not None,
        "plan_view": {
            "file": None if path is None else str(getattr(path, "name", path)),
            "bin_m": h,
            "x_edges_m": [float(xe[0]), float(xe[-1]), int(xe.size - 1)],
            "y_edges_m": [float(ye[0]), float(ye[-1]), int(ye.size - 1)],
            "min_count": PLAN_MIN_COUNT,
            "final_covered_area_m2": float(cov.sum() * area),
            "final_max_thickness_m": fin(th.max()),
            "final_log10_mu_min": fin(lm[good].min()) if good.any() else None,
            "final_log10_mu_max": fin(lm[good].max()) if good.any() else None,
            "final_log10_mu_mean": fin(lm[good].mean()) if good.any() else None,
        },
        "channels": {
            "detected": first is not None,
            "first_time_s": first,
            "viscosity_contrast_decades_max": contrast,
            "speed_cv_max": cv,
            "n_channel_sections": n_chan,
            "channel_x_range_m": chan_x,
            "contrast_decades": CHANNEL_CONTRAST_DECADES,
            "speed_ratio": CHANNEL_SPEED_RATIO,
            "min_speed_m_s": CHANNEL_MIN_SPEED_M_S,
            "mirrored": mirror is not None,
        },
    }


# --- runout -----------------------------------------------------------------------------------


# cells across the final deposit's thickest point below which summary.json warns (docs/validation.md,
# "Depth resolution", GIMP ppc 3): the Bingham slump 4.5 % short at 3.9 cells across, 0.5 % at 7.5; the
# lab dam break 8.3 % short at 2.4 cells, 1.2 % at 4.7 and 0.1 % at 7.0
DEPOSIT_CELLS_NEEDED = 4


class RunoutGauge(NamedTuple):
    """How a run's runout is measured: along ``axis`` from ``origin`` [m] (module docstring).

    ``cell``: the cell size h [m] (kernel bandwidth in 2D, plan-view bin in 3D); ``spacing``: the
    initial particle spacing h / ppc [m]; ``lo`` / ``hi``: the domain's corners [m]; ``plan``: the
    scene of a depth-averaged run, whose plan-view bins take the step's own depth
    (``_shallow.cell_depth_map``: the mean of each cell's corner nodes) instead of the rest volumes
    binned by particle position, which scatter by a third at 2 x 2 columns a cell; None otherwise.
    """

    dim: int
    axis: int
    origin: float
    cell: float
    spacing: float
    lo: tuple
    hi: tuple
    fraction: float = FRONT_FRACTION
    plan: object = None

    @classmethod
    def of(cls, scene, info) -> RunoutGauge:
        """The gauge of a built run (``mpmjax.build``: its ``scene`` and ``info``)."""
        return cls(
            dim=int(scene.dim),
            axis=int(info["runout_axis"]),
            origin=float(info["runout_origin_m"]),
            cell=float(scene.h),
            spacing=float(info["particle_spacing_m"]),
            lo=tuple(float(v) for v in scene.lo),
            hi=tuple(float(v) for v in scene.hi),
            plan=scene if scene.formulation == "depth-averaged" else None,
        )

    def cells(self, x, vol0, active, along: int):
        """Thickness [m] per plan-view cell of one cell size, with ``along`` first: (n_along,
        n_across) in 3D, (n_x,) in 2D (``plan``: the step's depth; else ``thickness_map`` of the
        rest volumes, in 2D their histogram over the cells)."""
        if self.plan is not None:
            d = cell_depth_map(self.plan, x, vol0, active)
            return d if (self.dim == 2 or along == 0) else d.T
        x = np.asarray(x, float)
        vol = np.broadcast_to(np.asarray(vol0, float), np.shape(active))
        if self.dim == 2:
            (edges,) = self.plan_edges(along)
            a = np.asarray(active, bool)
            return np.histogram(x[a, along], edges, weights=vol[a])[0] / self.cell
        across = 1 - along
        xs = np.stack([x[:, along], x[:, across], x[:, 2]], axis=1)
        return thickness_map(xs, vol, active, *self.plan_edges(along, across))

    @property
    def on_profile(self) -> bool:
        """True when the runout axis is horizontal (the front is read off the free surface)."""
        return self.axis != self.dim - 1

    def farthest(self, x, active) -> float:
        """Farthest active particle + spacing/2 - origin [m]; 0 with no active particle."""
        a = np.asarray(active, bool)
        if not a.any():
            return 0.0
        return float(runout(np.asarray(x), a, self.axis, self.origin, self.spacing))

    def front(self, x, vol0, active) -> float:
        """Headline runout [m]: the free-surface front minus the origin; 0 with no active particle."""
        a = np.asarray(active, bool)
        if not a.any():
            return 0.0
        if not self.on_profile:
            return self.farthest(x, a)
        if self.dim == 2:
            x = np.asarray(x)
            vol = np.broadcast_to(np.asarray(vol0, x.dtype), a.shape)
            f = _front_2d(self.cell, self.lo[0], self.hi[0], self.fraction)
            return float(f(x, vol, a)) - self.origin
        return plan_front(x, vol0, a, self) - self.origin

    def max_thickness(self, x, vol0, active) -> float:
        """Thickest point of the deposit [m], as the front measures thickness (2D: the kernel
        profile's largest value; 3D: the thickest plan-view bin); 0 with no active particle."""
        a = np.asarray(active, bool)
        if not a.any():
            return 0.0
        if self.dim == 2:
            x = np.asarray(x)
            vol = np.broadcast_to(np.asarray(vol0, x.dtype), a.shape)
            return float(_profile_max_2d(self.cell, self.lo[0], self.hi[0])(x, vol, a))
        return float(self.cells(x, vol0, a, 0).max())

    def extent(self, x, vol0, active) -> float:
        """Length [m] of the deposit along the runout axis: the bins (of one cell) whose thickness,
        largest across the flow, is at least ``fraction`` of the thickest (the front's threshold),
        counted from the first to the last; 0 with no active particle.  The depth-averaged
        formulation's resolution measure (``deposit_cells_across`` = extent / h)."""
        a = np.asarray(active, bool)
        if not a.any():
            return 0.0
        prof = self.cells(x, vol0, a, self.axis)
        prof = prof if self.dim == 2 else prof.max(axis=1)
        on = np.nonzero(prof >= self.fraction * prof.max())[0]
        return float((on[-1] - on[0] + 1) * self.cell) if prof.max() > 0 else 0.0

    def plan_edges(self, *axes) -> list:
        """Bin edges [m] of one cell along each of ``axes`` over the domain."""
        return [self.lo[k] + self.cell * np.arange(int(round((self.hi[k] - self.lo[k]) / self.cell)) + 1) for k in axes]

    def definition(self) -> str:
        """One line for summary.json's ``runout_definition``."""
        if not self.on_profile:
            return f"runout axis {self.axis} is vertical: the farthest-particle runout ({self.farthest_definition()})"
        how = (
            f"height profile of the rest volumes, Gaussian kernel of bandwidth one cell ({self.cell:g} m)"
            if self.dim == 2
            else f"rest-volume thickness per plan-view bin of one cell ({self.cell:g} m), largest across the flow"
        )
        return (
            f"free-surface front: the farthest position along axis {self.axis} where the deposit thickness ({how}) "
            f"is at least {100 * self.fraction:g} % of the frame's thickest point, minus runout_origin_m = "
            f"{self.origin:g} m"
        )

    def farthest_definition(self) -> str:
        return (
            f"max over active particles of x[{self.axis}] + half the initial particle spacing "
            f"({self.spacing / 2:g} m), minus runout_origin_m = {self.origin:g} m"
        )


_FRONT_2D: dict = {}


def _front_2d(cell, x_lo, x_hi, fraction):
    """The jitted 2D ``free_surface_front`` for one gauge (cached: compiled once per shape)."""
    key = (cell, x_lo, x_hi, fraction)
    if key not in _FRONT_2D:
        n = front_stations(x_lo, x_hi, cell)
        _FRONT_2D[key] = jax.jit(
            lambda x, v, a: free_surface_front(x, v, a, bandwidth=cell, x_lo=x_lo, x_hi=x_hi, fraction=fraction, n_grid=n)
        )
    return _FRONT_2D[key]


_PROFILE_MAX_2D: dict = {}


def _profile_max_2d(cell, lo, hi):
    """The jitted largest value of the 2D kernel height profile (bandwidth ``cell``) over the
    stations of ``free_surface_front`` on [lo, hi] (cached)."""
    key = (cell, lo, hi)
    if key not in _PROFILE_MAX_2D:
        grid = np.linspace(lo, hi, front_stations(lo, hi, cell))
        _PROFILE_MAX_2D[key] = jax.jit(
            lambda x, v, a: jnp.max(height_profile(x, v, a, jnp.asarray(grid, x.dtype), bandwidth=cell))
        )
    return _PROFILE_MAX_2D[key]


def plan_front(x, vol0, active, gauge: RunoutGauge) -> float:
    """3D free-surface front [m] (a position along ``gauge.axis``; module docstring)."""
    along = gauge.axis
    h = gauge.cell
    edges = gauge.plan_edges(along)
    prof = gauge.cells(x, vol0, active, along).max(axis=1)
    env = np.maximum.accumulate(prof[::-1])[::-1]
    thr = gauge.fraction * prof.max()
    if not thr > 0:
        return gauge.origin
    centres = 0.5 * (edges[0][1:] + edges[0][:-1])
    k = int(np.nonzero(env >= thr)[0][-1])
    if k + 1 >= prof.size:
        return float(edges[0][-1])
    # linear between the last column at or above the threshold and the next (below it)
    a, b = env[k], env[k + 1]
    return float(centres[k] + h * (a - thr) / (a - b))
