"""Plots of a finished (or interrupted) run read back from ``result.h5``.

Every function takes ``result``: the dict returned by ``mpmjax._io.read_result``, or a path
to a ``result.h5`` file (or to the run folder holding it).  Matplotlib only; nothing here
needs a display (it works with the Agg backend, which matplotlib picks by itself on a
headless machine).  Functions that draw return the matplotlib Axes; pass ``ax=`` to draw
into a figure of your own.

* ``particles(result, frame, field)``: side view (3D: side or plan view) of one frame,
  coloured by a stored field, with a colour bar in the field's unit.
* ``profiles(result, times, data)``: free-surface or kernel height profiles at chosen times,
  with measured profiles (``calibration.data.Profile`` or ``(x_m, h_m)`` arrays) overlaid.
* ``runout_vs_time(result)``: the front position (``mpmjax.runout``) against time.
* ``animate(result, path, field)``: a GIF of the particles, one image per saved frame.
* 3D runs: ``plan_map(maps, frame, quantity)``: a binned plan-view map from ``plan_view.h5``
  (bin-mean log10 viscosity, speed, thickness); ``section(result, frame, field, along=)``:
  a side (x-z) or transverse (y-z) section; ``plot_3d_overview``: the ``plan_view.png`` and
  ``sections.png`` that ``mpmjax run`` writes.
* ``plot_result(path_png, result, summary, title)``: the ``result.png`` that ``mpmjax run``
  writes, a one-page report (``result_figure``): viscosity side views at ~1 s, ~5 s and the
  end on a robust log scale (``viscosity_norm``), λ for Coussot runs, thickness profiles at up
  to 6 times (``result_profiles``), runout against time with its final value and the wall.

Fields (``FIELDS``): ``mu`` effective viscosity [Pa·s] (log colour scale), ``lambda``
Coussot structure parameter [-], ``speed`` |v| [m/s], ``vx`` and the vertical velocity
``vz`` [m/s], ``J`` volume ratio [-], ``displacement`` |x - x(t=0)| [m].  ``lambda`` exists
only for Coussot scenes; the error for an unknown or missing field lists the allowed ones.
"""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from . import _metrics
from ._build import terrain_of
from ._hazard import MAPS
from ._io import read_result
from ._observables import height_profile
from ._release import region_polygon

__all__ = [
    "FIELDS",
    "animate",
    "field_values",
    "load",
    "load_plan_view",
    "particles",
    "plan_map",
    "plot_3d_overview",
    "plot_result",
    "profile_at",
    "result_figure",
    "result_profiles",
    "profiles",
    "runout",
    "runout_vs_time",
    "section",
    "viscosity_norm",
]

# name -> (label, unit, log colour scale)
FIELDS = {
    "mu": ("effective viscosity μ", "Pa·s", True),
    "lambda": ("structure parameter λ", "-", False),
    "speed": ("speed |v|", "m/s", False),
    "vx": ("horizontal velocity v_x", "m/s", False),
    "vz": ("vertical velocity", "m/s", False),
    "J": ("volume ratio J", "-", False),
    "displacement": ("displacement |x − x0|", "m", False),
}


def load(result) -> dict:
    """``result`` as the dict of ``read_result``: a dict is returned as is, a path to
    ``result.h5`` or to a run folder containing it is read."""
    if isinstance(result, dict):
        if not {"attrs", "frames"} <= set(result):
            raise ValueError("result: expected the dict of mpmjax._io.read_result (keys 'attrs', 'frames', ...)")
        return result
    p = Path(result)
    if p.is_dir():
        p = p / "result.h5"
    if not p.exists():
        raise FileNotFoundError(f"result: {p} does not exist (expected a result.h5 written by `mpmjax run`)")
    return read_result(p)


def _cfg(res) -> dict:
    return json.loads(res["attrs"]["scene_config_json"])


def _geometry(res) -> dict:
    """Cell size, particle spacing, runout axis and origin [m] of the run (as ``build`` defines them)."""
    cfg = _cfg(res)
    h = float(cfg["domain.cell_size_m"])
    axis = int(cfg["output.runout_axis"])
    origin = cfg["output.runout_origin_m"]
    if "runout_origin_m" in res["attrs"]:  # the origin build() derived (files from before it: derived here)
        origin = float(res["attrs"]["runout_origin_m"])
    if origin is None or (isinstance(origin, float) and math.isnan(origin)):
        starts = [b["lo_m"][axis] for b in cfg["bodies"]]
        if cfg.get("inflow.point_m") is not None:
            starts.append(cfg["inflow.point_m"][axis])
        origin = min(starts)
    return {
        "h": h,
        "spacing": h / int(cfg["numerics.ppc"]),
        "axis": axis,
        "origin": float(origin),
        "lo": list(cfg["domain.lo_m"]),
        "hi": list(cfg["domain.hi_m"]),
        "dim": int(cfg["domain.dim"]),
        "name": cfg["name"],
    }


def _allowed(res) -> list[str]:
    fr = res["frames"]
    return [k for k in FIELDS if k != "lambda" or "lambda" in fr]


def _check_field(res, field: str):
    allowed = _allowed(res)
    if field not in allowed:
        extra = " (lambda is stored for Coussot scenes only)" if field == "lambda" else ""
        raise ValueError(f"field = {field!r} is not available{extra}; allowed: {', '.join(allowed)}")


def _frame_index(res, frame: int) -> int:
    n = res["frames"]["t_s"].shape[0]
    if not isinstance(frame, (int, np.integer)) or isinstance(frame, bool):
        raise ValueError(f"frame = {frame!r}: expected an integer frame index in -{n}..{n - 1}")
    if not -n <= int(frame) < n:
        raise ValueError(f"frame = {frame}: this result has {n} frames; allowed range -{n}..{n - 1}")
    return int(frame) % n


def field_values(result, frame: int, field: str) -> np.ndarray:
    """Values of ``field`` (see ``FIELDS``) for every particle of frame ``frame``, (n,), SI units."""
    res = load(result)
    _check_field(res, field)
    k = _frame_index(res, frame)
    fr = res["frames"]
    if field == "mu":
        return np.asarray(fr["mu_pa_s"][k], float)
    if field == "lambda":
        return np.asarray(fr["lambda"][k], float)
    if field == "J":
        return np.asarray(fr["J"][k], float)
    v = np.asarray(fr["v_m_s"][k], float)
    if field == "speed":
        return np.linalg.norm(v, axis=-1)
    if field == "vx":
        return v[:, 0]
    if field == "vz":
        return v[:, -1]
    return np.linalg.norm(np.asarray(fr["x_m"][k], float) - np.asarray(fr["x_m"][0], float), axis=-1)


def _label(res, field: str) -> str:
    name, unit, _ = FIELDS[field]
    if field == "vz":
        name = f"vertical velocity v_{'y' if res['frames']['x_m'].shape[-1] == 2 else 'z'}"
    return f"{name} [{unit}]"


def _make_norm(field: str, values):
    # matplotlib only when a plot is made (optional heavy import)
    from matplotlib.colors import LogNorm, Normalize

    vals = np.asarray(values, float)
    vals = vals[np.isfinite(vals)]
    if FIELDS[field][2]:
        vals = vals[vals > 0]
        lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (1.0, 10.0)
        return LogNorm(vmin=lo, vmax=max(hi, lo * 1.001))
    lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)
    if hi <= lo:
        hi = lo + (abs(lo) * 1e-3 or 1e-12)
    return Normalize(vmin=lo, vmax=hi)


def _axes_of(res, view: str) -> tuple[int, int, str, str]:
    dim = res["frames"]["x_m"].shape[-1]
    if view == "side":
        return 0, dim - 1, "x [m]", ("y" if dim == 2 else "z") + " [m]"
    if view == "plan":
        if dim != 3:
            raise ValueError(f"view = 'plan' needs a 3D result; this one is {dim}D (allowed: 'side')")
        return 0, 1, "x [m]", "y [m]"
    raise ValueError(f"view = {view!r}; allowed: 'side', 'plan' (3D only)")


def particles(result, frame: int = -1, field: str = "mu", ax=None, *, view: str = "side", size=None, norm=None):
    """Scatter plot of the active particles of one frame coloured by ``field``.

    Args:
      result: ``read_result`` dict or path to ``result.h5`` / its folder.
      frame: frame index (0 = initial state, -1 = last).
      field: one of ``FIELDS`` (``mu`` uses a logarithmic colour scale).
      ax: matplotlib Axes to draw on (a new figure otherwise).
      view: ``side`` (x against the vertical axis) or, in 3D, ``plan`` (x against y).
      size: marker size [points^2] (default: from the particle count).
      norm: a matplotlib colour ``Normalize`` (default: the frame's range).
    Returns the Axes; its first collection is the scatter (one point per active particle,
    colour values = the stored field) and ``ax.figure`` holds the colour bar.
    """
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    res = load(result)
    _check_field(res, field)
    k = _frame_index(res, frame)
    a, b, xl, yl = _axes_of(res, view)
    act = res["frames"]["active"][k].astype(bool)
    x = res["frames"]["x_m"][k][act]
    c = field_values(res, k, field)[act]
    new = ax is None
    if new:
        _, ax = plt.subplots(figsize=(9, 3.2))
    norm = _make_norm(field, c) if norm is None else norm
    s = size if size is not None else float(np.clip(4000.0 / max(len(c), 1), 0.5, 20.0))
    sc = ax.scatter(x[:, a], x[:, b], c=c, s=s, cmap="viridis", norm=norm, linewidths=0)
    ax.figure.colorbar(sc, ax=ax, label=_label(res, field))
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    g = _geometry(res)
    ax.set_title(f"{g['name']}: t = {res['frames']['t_s'][k]:.3g} s, {int(act.sum())} active particles", fontsize=9)
    if new:
        ax.figure.tight_layout()
    return ax


def _pick_times(res, times):
    t = np.asarray(res["frames"]["t_s"], float)
    out = []
    tol = 0.5 * (t[-1] - t[0]) / max(len(t) - 1, 1) + 1e-9
    for ts in times:
        ts = float(ts)
        if not (t[0] - tol <= ts <= t[-1] + tol):
            raise ValueError(f"time {ts:g} s is outside the saved frames; allowed range {t[0]:g}..{t[-1]:g} s")
        out.append(int(np.argmin(np.abs(t - ts))))
    return out


def _data_list(data):
    """Measured data -> list of (label, t_s or None, x_m, h_m, sigma_m or None)."""
    if data is None:
        return []
    if hasattr(data, "x_m") or (isinstance(data, tuple) and len(data) == 2 and np.ndim(data[0]) == 1):
        data = [data]
    out = []
    for i, d in enumerate(data):
        if hasattr(d, "x_m") and hasattr(d, "h_m"):
            lab = "measured" + ("" if d.t_s is None else f" t = {d.t_s:g} s")
            out.append((lab, d.t_s, np.asarray(d.x_m, float), np.asarray(d.h_m, float), d.sigma_m))
            continue
        try:
            xd, hd = (np.asarray(a, float) for a in d)
        except (TypeError, ValueError):
            raise ValueError(
                f"data[{i}]: expected a calibration.data.Profile or an (x_m, h_m) pair of 1-D arrays [m]"
            ) from None
        if xd.ndim != 1 or xd.shape != hd.shape:
            raise ValueError(f"data[{i}]: x_m has shape {xd.shape} and h_m {hd.shape}; expected equal 1-D arrays [m]")
        out.append((f"measured {i}", None, xd, hd, None))
    return out


def profile_at(result, frame: int, *, method: str = "surface", x_m=None, bandwidth_m=None):
    """Height profile of one frame along the runout axis: (x [m], h [m]).

    ``method="surface"``: ``mpmjax._metrics.surface_profile`` (highest active particle plus
    half a particle spacing per cell-wide bin; nan where empty), an elevation [m].
    ``method="kernel"`` (2D): ``mpmjax.height_profile`` at ``x_m``
    (default: 201 stations over the domain) with bandwidth ``bandwidth_m`` (default one
    cell), the depth-integrated thickness that ``mpmjax calibrate`` fits, using rest volumes.
    """
    res = load(result)
    k = _frame_index(res, frame)
    g = _geometry(res)
    fr = res["frames"]
    x, act = np.asarray(fr["x_m"][k], float), fr["active"][k].astype(bool)
    ax_ = g["axis"]
    if method == "surface":
        if x_m is None:
            edges = np.arange(g["lo"][ax_], g["hi"][ax_] + 0.5 * g["h"], g["h"])
        else:
            xs = np.asarray(x_m, float)
            mid = 0.5 * (xs[1:] + xs[:-1])
            edges = np.concatenate([[xs[0] - (mid[0] - xs[0])], mid, [xs[-1] + (xs[-1] - mid[-1])]])
        if not act.any():
            xc = 0.5 * (edges[1:] + edges[:-1])
            return xc, np.full(xc.shape, np.nan)
        return _metrics.surface_profile(x, act, edges, g["spacing"], axis=ax_)
    if method == "kernel":
        if g["dim"] != 2:
            raise ValueError(f"method = 'kernel' is for 2D results; this one is {g['dim']}D (allowed: 'surface')")

        xs = np.linspace(g["lo"][ax_], g["hi"][ax_], 201) if x_m is None else np.asarray(x_m, float)
        bw = g["h"] if bandwidth_m is None else float(bandwidth_m)
        if not bw > 0:
            raise ValueError(f"bandwidth_m = {bandwidth_m}; allowed: > 0 [m]")
        hp = height_profile(
            jnp.asarray(x), jnp.asarray(res["particles"]["vol0_m3"]), jnp.asarray(act), jnp.asarray(xs), bandwidth=bw
        )
        return xs, np.asarray(hp, float)
    raise ValueError(f"method = {method!r}; allowed: 'surface', 'kernel'")


def profiles(result, times=None, data=None, ax=None, *, method: str = "surface", bandwidth_m=None):
    """Height profiles at ``times`` [s] (nearest saved frames) with measured ``data`` overlaid.

    Args:
      result: ``read_result`` dict or path.
      times: times [s]; default: the measured profiles' times if they have any, else the last frame.
      data: a ``calibration.data.Profile``, a list of them (``calibration.data.load_profiles``),
        or ``(x_m, h_m)`` array pairs [m]; drawn as markers (error bars where sigma is known).
      method: ``surface`` (free-surface elevation) or ``kernel`` (depth-integrated thickness,
        as calibrated); see ``profile_at``.
    Returns the Axes (one line per time, labelled with the frame's actual time).
    """
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    res = load(result)
    meas = _data_list(data)
    if times is None:
        mt = [t for _, t, *_ in meas if t is not None]
        times = sorted(set(mt)) if mt else [float(res["frames"]["t_s"][-1])]
    times = np.atleast_1d(np.asarray(times, float))
    ks = _pick_times(res, times)
    new = ax is None
    if new:
        _, ax = plt.subplots(figsize=(8, 3.4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    t = res["frames"]["t_s"]
    for i, k in enumerate(ks):
        xc, hc = profile_at(res, k, method=method, bandwidth_m=bandwidth_m)
        ax.plot(xc, hc, "-", color=colors[i % len(colors)], label=f"model t = {t[k]:.3g} s")
    colour_of_frame = {k: colors[i % len(colors)] for i, k in reversed(list(enumerate(ks)))}
    for j, (lab, tm, xd, hd, sd) in enumerate(meas):
        # a measurement takes the colour of the model line at its time (final profile: the last frame)
        kd = _pick_times(res, [tm])[0] if tm is not None else len(t) - 1
        c = colour_of_frame.get(kd, colors[(len(ks) + j) % len(colors)])
        if sd is not None:
            ax.errorbar(xd, hd, yerr=sd, fmt="o", ms=3, color=c, label=lab)
        else:
            ax.plot(xd, hd, "o", ms=3, color=c, label=lab)
    g = _geometry(res)
    axname = "xyz"[g["axis"]]
    ax.set_xlabel(f"{axname} [m]")
    ax.set_ylabel("surface elevation [m]" if method == "surface" else "height h [m]")
    ax.set_title(f"{g['name']}: {'free-surface' if method == 'surface' else 'kernel height'} profiles", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    if new:
        ax.figure.tight_layout()
    return ax


def _gauge(res) -> _metrics.RunoutGauge:
    g = _geometry(res)
    return _metrics.RunoutGauge(
        dim=g["dim"], axis=g["axis"], origin=g["origin"], cell=g["h"], spacing=g["spacing"], lo=tuple(g["lo"]),
        hi=tuple(g["hi"]),
    )


def runout(result, *, farthest: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(times [s], runout [m]) of every saved frame, as summary.json defines it (docs/output.md
    "Runout"): the free-surface front, or with ``farthest`` the farthest particle (0 where no
    material is active yet)."""
    res = load(result)
    gauge = _gauge(res)
    fr = res["frames"]
    act = fr["active"].astype(bool)
    vol0 = np.asarray(res["particles"]["vol0_m3"], np.float32)
    if farthest:
        front = [gauge.farthest(x, a) for x, a in zip(fr["x_m"], act)]
    else:
        front = [gauge.front(x, vol0, a) for x, a in zip(fr["x_m"], act)]
    return np.asarray(fr["t_s"], float), np.asarray(front, float)


def runout_vs_time(result, ax=None, **plot_kw):
    """Front position (runout [m], see ``runout``) against time [s]; returns the Axes."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    res = load(result)
    t, front = runout(res)
    new = ax is None
    if new:
        _, ax = plt.subplots(figsize=(6, 3.4))
    kw = {"marker": "o", "ms": 3, **plot_kw}
    ax.plot(t, front, **kw)
    g = _geometry(res)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("runout [m]")
    ax.set_title(f"{g['name']}: front along {'xyz'[g['axis']]} from {g['origin']:g} m", fontsize=9)
    ax.grid(alpha=0.3)
    if new:
        ax.figure.tight_layout()
    return ax


def animate(
    result,
    path,
    field: str = "mu",
    *,
    frames=None,
    fps: float = 5.0,
    view: str = "side",
    dpi: int = 80,
    max_frames: int | None = None,
    progress=None,
):
    """Write a GIF (matplotlib ``PillowWriter``) of the particles coloured by ``field``, one
    image per saved frame (or per index in ``frames``), on fixed axes and one colour scale.
    ``max_frames``: at most this many images, evenly spaced over the frames, the first and the
    last included.  ``progress(i, n)``, if given, is called as image i of n is drawn.
    Returns the path (written to a temporary name and renamed, so an interrupted call leaves
    no partial GIF)."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation, PillowWriter

    res = load(result)
    _check_field(res, field)
    path = Path(path)
    if path.suffix.lower() != ".gif":
        raise ValueError(f"path = {str(path)!r}: expected a .gif file name")
    if not fps > 0:
        raise ValueError(f"fps = {fps}; allowed: > 0")
    n = res["frames"]["t_s"].shape[0]
    ks = list(range(n)) if frames is None else [_frame_index(res, int(k)) for k in frames]
    if not ks:
        raise ValueError("frames: empty; give at least one frame index")
    if max_frames is not None:
        if int(max_frames) < 1:
            raise ValueError(f"max_frames = {max_frames}; allowed: >= 1")
        if len(ks) > max_frames:
            ks = [ks[i] for i in sorted({int(round(j)) for j in np.linspace(0, len(ks) - 1, int(max_frames))})]
    a, b, xl, yl = _axes_of(res, view)
    act_all = res["frames"]["active"][ks].astype(bool)
    vals = np.concatenate([field_values(res, k, field)[act_all[i]] for i, k in enumerate(ks)])
    norm = _make_norm(field, vals)
    pts = res["frames"]["x_m"][ks][act_all]
    if pts.size == 0:
        lo_a, hi_a, lo_b, hi_b = 0.0, 1.0, 0.0, 1.0
    else:
        lo_a, hi_a = float(pts[:, a].min()), float(pts[:, a].max())
        lo_b, hi_b = float(pts[:, b].min()), float(pts[:, b].max())
    pad_a, pad_b = 0.03 * (hi_a - lo_a) + 1e-6, 0.08 * (hi_b - lo_b) + 1e-6
    fig, ax = plt.subplots(figsize=(8, 3.2))
    t = res["frames"]["t_s"]
    name = _geometry(res)["name"]

    # one scatter artist, updated in place per image (cheaper than redrawing the axes)
    sc = ax.scatter(np.zeros(0), np.zeros(0), c=np.zeros(0), s=3, cmap="viridis", norm=norm, lw=0)
    ax.set_xlim(lo_a - pad_a, hi_a + pad_a)
    ax.set_ylim(lo_b - pad_b, hi_b + pad_b)
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    title = ax.set_title("", fontsize=9)

    def draw(i):
        k = ks[i]
        act = act_all[i]
        x = res["frames"]["x_m"][k][act]
        sc.set_offsets(np.stack([x[:, a], x[:, b]], axis=-1))
        sc.set_array(field_values(res, k, field)[act])
        title.set_text(f"{name}: t = {t[k]:.3g} s")
        return (sc, title)

    # matplotlib only when a plot is made (optional heavy import)
    from matplotlib.cm import ScalarMappable

    fig.colorbar(ScalarMappable(norm=norm, cmap="viridis"), ax=ax, label=_label(res, field))
    anim = FuncAnimation(fig, draw, frames=len(ks), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.gif")
    try:
        anim.save(tmp, writer=PillowWriter(fps=fps), dpi=dpi, progress_callback=progress)
        tmp.replace(path)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()
    return path


# --- 3D runs: plan-view maps and sections ---------------------------------------------------

PLAN_QUANTITIES = {
    "log10_mu": "bin mean of log10 μ [log10 Pa·s]",
    "speed_m_s": "bin mean speed |v| [m/s]",
    "thickness_m": "thickness [m]",
    "count": "particles per bin",
}


def load_plan_view(maps) -> dict:
    """The plan-view maps of a 3D run: a dict of ``mpmjax._metrics.read_plan_view`` is returned
    as is; a path to ``plan_view.h5`` (or to the run folder holding it) is read."""
    if isinstance(maps, dict):
        return maps
    p = Path(maps)
    if (p / "plan_view.h5").exists() if p.is_dir() else p.exists():
        return _metrics.read_plan_view(p)
    raise FileNotFoundError(f"maps: {p} is not a plan_view.h5 (written by `mpmjax run` for 3D scenes)")


def plan_map(maps, frame: int = -1, quantity: str = "log10_mu", ax=None, *, norm=None):
    """Plan view (x against y) of a binned map of one frame: ``log10_mu`` (default),
    ``speed_m_s``, ``thickness_m`` or ``count``; empty bins are left white.

    Args:
      maps: ``plan_view.h5`` path, run folder or the dict of ``read_plan_view``.
      frame: frame index (-1 = last).
    Returns the Axes (its first collection is the ``pcolormesh``)."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    d = load_plan_view(maps)
    if quantity not in PLAN_QUANTITIES:
        raise ValueError(f"quantity = {quantity!r}; allowed: {', '.join(PLAN_QUANTITIES)}")
    n = d["t_s"].shape[0]
    if not -n <= int(frame) < n:
        raise ValueError(f"frame = {frame}: the maps have {n} frames; allowed range -{n}..{n - 1}")
    k = int(frame) % n
    z = np.asarray(d[quantity][k], float)
    if quantity in ("thickness_m", "count"):
        z = np.where(z > 0, z, np.nan)
    new = ax is None
    if new:
        _, ax = plt.subplots(figsize=(8, 3.2))
    xe, ye = d["x_edges_m"], d["y_edges_m"]
    pm = ax.pcolormesh(xe, ye, z.T, cmap="viridis", norm=norm, shading="flat")
    ax.figure.colorbar(pm, ax=ax, label=PLAN_QUANTITIES[quantity])
    occ = np.nonzero(np.isfinite(z))
    if occ[0].size:
        pad = 2 * (xe[1] - xe[0])
        ax.set_xlim(xe[occ[0].min()] - pad, xe[occ[0].max() + 1] + pad)
        ax.set_ylim(ye[occ[1].min()] - pad, ye[occ[1].max() + 1] + pad)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    bin_m = d["attrs"].get("bin_m", xe[1] - xe[0])
    ax.set_title(f"t = {d['t_s'][k]:.3g} s, plan view, {bin_m:g} m bins", fontsize=9)
    if new:
        ax.figure.tight_layout()
    return ax


def section(result, frame: int = -1, field: str = "mu", ax=None, *, along: str = "x", at_m=None, half_width_m=None):
    """Vertical section of a 3D run: the active particles within ``half_width_m`` of a plane,
    coloured by ``field``.  ``along="x"``: a side section (x against z) through y = ``at_m``
    (default: the y of the material's centre); ``along="y"``: a transverse section (y against z)
    at x = ``at_m`` (default: the centre).  ``half_width_m`` defaults to one cell size.
    Returns the Axes."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    res = load(result)
    _check_field(res, field)
    if res["frames"]["x_m"].shape[-1] != 3:
        raise ValueError("section: needs a 3D result (2D results are sections already: use particles())")
    if along not in ("x", "y"):
        raise ValueError(f"along = {along!r}; allowed: 'x' (side section), 'y' (transverse section)")
    k = _frame_index(res, frame)
    g = _geometry(res)
    act = res["frames"]["active"][k].astype(bool)
    x = res["frames"]["x_m"][k]
    cut = 1 if along == "x" else 0
    hw = g["h"] if half_width_m is None else float(half_width_m)
    if not hw > 0:
        raise ValueError(f"half_width_m = {half_width_m}; allowed: > 0 [m]")
    if at_m is None:
        at_m = float(np.median(x[act, cut])) if act.any() else 0.5 * (g["lo"][cut] + g["hi"][cut])
    sel = act & (np.abs(x[:, cut] - at_m) <= hw)
    c = field_values(res, k, field)[sel]
    new = ax is None
    if new:
        _, ax = plt.subplots(figsize=(9, 3.0))
    a = 0 if along == "x" else 1
    norm = _make_norm(field, c)
    sc = ax.scatter(x[sel, a], x[sel, 2], c=c, s=float(np.clip(3000.0 / max(len(c), 1), 1.0, 20.0)), norm=norm, lw=0)
    ax.figure.colorbar(sc, ax=ax, label=_label(res, field))
    ax.set_xlabel(f"{'xy'[a]} [m]")
    ax.set_ylabel("z [m] (normal to the base)")
    kind = "side section" if along == "x" else "transverse section"
    ax.set_title(
        f"{g['name']}: t = {res['frames']['t_s'][k]:.3g} s, {kind} at {'yx'[a]} = {at_m:.3g} ± {hw:g} m "
        "(vertical scale exaggerated)",
        fontsize=9,
    )
    if new:
        ax.figure.tight_layout()
    return ax


def plot_3d_overview(result, maps, summary: dict, out_dir) -> list[Path]:
    """The pictures ``mpmjax run`` writes for a 3D run into ``out_dir``:

    * ``plan_view.png``: plan-view maps of the bin-mean log10 viscosity at half time and at the
      end of the run, and the final thickness; lobe width and the channel metric (largest
      lateral viscosity contrast) against time.
    * ``sections.png``: the final frame's side section along the flow axis through the
      material's centre and the transverse section at the widest point of the lobe, coloured
      by viscosity, and the side section coloured by the structure parameter λ (Coussot scenes).
    Returns the paths written."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    res = load(result)
    d = load_plan_view(maps)
    out_dir = Path(out_dir)
    t = np.asarray(d["t_s"], float)
    n = t.size
    picks = sorted({n // 2, n - 1})
    lm = d["log10_mu"][picks]
    fin = lm[np.isfinite(lm)]
    norm = Normalize(*(float(fin.min()), float(fin.max()) + 1e-9)) if fin.size else None
    fig, axes = plt.subplots(len(picks) + 2, 1, figsize=(9, 2.6 * (len(picks) + 2)))
    occ = np.nonzero(np.any(d["count"][picks] > 0, axis=0))
    for ax, k in zip(axes, picks):
        plan_map(d, k, "log10_mu", ax, norm=norm)
    plan_map(d, -1, "thickness_m", axes[len(picks)])
    if occ[0].size:  # one extent for every map: the bins occupied at any of the times shown
        xe, ye = d["x_edges_m"], d["y_edges_m"]
        pad = 2 * (xe[1] - xe[0])
        for ax in axes[: len(picks) + 1]:
            ax.set_xlim(xe[occ[0].min()] - pad, xe[occ[0].max() + 1] + pad)
            ax.set_ylim(ye[occ[1].min()] - pad, ye[occ[1].max() + 1] + pad)
    axes[len(picks)].set_title(f"t = {t[-1]:.3g} s: thickness (rest volume of the column / bin area)", fontsize=9)
    axl = axes[-1]
    w = [np.nan if a is None else a for a in summary.get("lobe_width_m_per_frame", [])]
    axl.plot(t[: len(w)], w, "-o", ms=3, color="C0")
    axl.set_xlabel("time [s]")
    axl.set_ylabel("lobe width [m]", color="C0")
    axl.grid(alpha=0.3)
    ch = summary.get("channels", {})
    c = [np.nan if a is None else a for a in ch.get("viscosity_contrast_decades_max", [])]
    if c:
        axc = axl.twinx()
        axc.plot(t[: len(c)], c, "-s", ms=3, color="C1")
        axc.axhline(ch.get("contrast_decades", 1.0), color="C1", ls=":", lw=1)
        axc.set_ylabel("max lateral μ contrast [decades]", color="C1")
    axl.set_title(
        f"lobe width (thickness > {summary.get('lobe_width_threshold_m', float('nan')):.3g} m) and lateral "
        f"viscosity contrast; channels: {'yes' if ch.get('detected') else 'no'}",
        fontsize=9,
    )
    fig.tight_layout()
    p1 = out_dir / "plan_view.png"
    fig.savefig(p1, dpi=80)
    plt.close(fig)

    lam = "lambda" in res["frames"]
    fig, axes = plt.subplots(2 + lam, 1, figsize=(9, 2.8 * (2 + lam)))
    section(res, -1, "mu", axes[0], along="x")
    section(res, -1, "mu", axes[1], along="y", at_m=summary.get("lobe_width_section_x_m"))
    if lam:
        section(res, -1, "lambda", axes[2], along="x")
    fig.tight_layout()
    p2 = out_dir / "sections.png"
    fig.savefig(p2, dpi=80)
    plt.close(fig)
    return [p1, p2]


def viscosity_norm(mu, *, lower_percentile: float = 2.0, min_decades: float = 1.0):
    """A logarithmic colour scale for viscosities ``mu`` [Pa·s] that keeps contrast when most
    material sits at the law's cap μ_max: ``(LogNorm, note)``.

    The top is the largest value.  The bottom is the ``lower_percentile`` percentile of log10 μ
    of the particles *below* the top (those within 0.01 decade of it are "at the top"), so a
    handful of outliers far below (a fast front, one particle in free fall) does not squeeze the
    flowing material into one colour, and a deposit 95 % at μ_max still spreads its flowing 5 %
    over the whole colour map; the range spans at least ``min_decades`` decades (so a frame
    entirely at μ_max shows one decade).  Values below the bottom take the lowest colour
    (the colour bar's arrow).  ``note`` says how the range was chosen, for the colour bar."""
    # matplotlib only when a plot is made (optional heavy import)
    from matplotlib.colors import LogNorm

    v = np.asarray(mu, float).ravel()
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return LogNorm(vmin=1.0, vmax=10.0), "no active material"
    lv = np.log10(v)
    hi = float(lv.max())
    top = lv >= hi - 0.01
    below = lv[~top]
    lo = float(np.percentile(below, lower_percentile)) if below.size else hi
    lo = max(lo, float(lv.min()))
    lo = min(lo, hi - min_decades)
    clipped = float(np.mean(lv < lo - 1e-9))
    note = f"{100 * top.mean():.0f} % at the top"
    if clipped > 0:
        note += f", {100 * clipped:.1g} % below the range (darkest colour)"
    return LogNorm(vmin=10.0**lo, vmax=10.0**hi), note


def _profile_frames(n: int, k_max: int = 6, runout=None) -> list[int]:
    """Up to ``k_max`` frame indices of ``n`` frames, the first and last included: evenly spaced,
    or, given the ``runout`` per frame [m], the first frames whose runout has covered 25, 50, 75
    and 90 % of its whole advance (a flow that stops early would otherwise show the same final
    profile several times)."""
    if runout is not None and len(runout) == n and n > 2:
        r = np.asarray(runout, float)
        adv = r - r[0]
        if np.all(np.isfinite(adv)) and adv[-1] > 0:
            ks = {0, n - 1}
            for f in (0.25, 0.5, 0.75, 0.9)[: max(k_max - 2, 0)]:
                ks.add(int(np.argmax(adv >= f * adv[-1])))
            return sorted(ks)
    return sorted({int(round(j)) for j in np.linspace(0, n - 1, min(n, k_max))})


def _kernel_profile_wide(res, k: int, x_m: np.ndarray, bandwidth: float, chunk: int = 2_000_000) -> np.ndarray:
    """``mpmjax.height_profile`` of frame ``k`` (rest volumes, 2D) at ``x_m``, summed over blocks of
    particles so that the stations x particles kernel matrix stays below ``chunk`` entries."""
    fr = res["frames"]
    x = np.asarray(fr["x_m"][k], float)
    act = np.asarray(fr["active"][k]).astype(bool)
    vol = np.asarray(res["particles"]["vol0_m3"], float)
    idx = np.nonzero(act)[0]
    out = np.zeros(len(x_m))
    step = max(1, chunk // max(len(x_m), 1))
    for s in range(0, len(idx), step):
        j = idx[s : s + step]
        out += np.asarray(
            height_profile(
                jnp.asarray(x[j]), jnp.asarray(vol[j]), jnp.ones(len(j), bool), jnp.asarray(x_m), bandwidth=bandwidth
            ),
            float,
        )
    return out


def result_profiles(result, frames=None, runout=None):
    """The thickness profiles that ``result.png`` draws: ``(x [m], [(frame, t [s], h [m]), ...])``.

    2D: the kernel height profile of the rest volumes, bandwidth one cell h (``mpmjax.height_profile``,
    the thickness the runout is read from), along x on stations 3 per cell from 4 h before the
    domain to 4 h beyond it (the kernel spreads material up to a few h past a wall: on these
    stations each curve integrates to the released area).  3D: the rest-volume thickness of the
    plan-view bins of one cell (``mpmjax._metrics.thickness_map``), its largest value across the
    flow, per bin along the runout axis (x if the runout axis is vertical): the thickness the 3D
    runout is read from.  ``frames``: default the first and last frame and those where the
    ``runout`` per frame [m] (e.g. summary.json's ``runout_m``) has covered 25, 50, 75 and 90 % of
    its advance; without ``runout``, 6 frames evenly spaced."""
    res = load(result)
    g = _geometry(res)
    t = np.asarray(res["frames"]["t_s"], float)
    ks = _profile_frames(len(t), runout=runout) if frames is None else [_frame_index(res, int(k)) for k in frames]
    h = g["h"]
    if g["dim"] == 2:
        lo, hi = g["lo"][0] - 4 * h, g["hi"][0] + 4 * h
        xs = np.linspace(lo, hi, int(math.ceil(3 * (hi - lo) / h)) + 1)
        return xs, [(k, float(t[k]), _kernel_profile_wide(res, k, xs, h)) for k in ks]
    ax_ = g["axis"] if g["axis"] in (0, 1) else 0
    edges = [g["lo"][a] + h * np.arange(int(round((g["hi"][a] - g["lo"][a]) / h)) + 1) for a in (0, 1)]
    xc = 0.5 * (edges[ax_][1:] + edges[ax_][:-1])
    vol = np.asarray(res["particles"]["vol0_m3"], float)
    out = []
    for k in ks:
        act = np.asarray(res["frames"]["active"][k]).astype(bool)
        tm = _metrics.thickness_map(np.asarray(res["frames"]["x_m"][k], float), vol, act, edges[0], edges[1])
        out.append((k, float(t[k]), tm.max(axis=1 - ax_)))
    return xc, out


def result_figure(result, summary: dict, title: str | None = None, snapshot_times=(1.0, 5.0)):
    """The one-page report of a run that ``mpmjax run`` saves as ``result.png``; returns the Figure.

    * side views (x against the vertical axis; 3D: all particles projected) at ~1 s, ~5 s (as in
      thesis Figs. 34-42) and the end, coloured by viscosity on one log scale chosen by
      ``viscosity_norm`` (contrast even when most material sits at μ_max; the colour bar says how);
    * Coussot runs (a ``lambda`` frame dataset): the last frame coloured by λ, on its own panel;
    * thickness profiles [m] at up to 6 saved times coloured by time (``result_profiles``);
    * runout against time (free-surface front and farthest particle) with the final value and,
      when the front nears it, the domain wall; the title says the final runout, where the wall
      is and whether it capped the runout.
    Axes carry labels for tests and scripts (``ax.get_label()``): ``side``, ``lambda``, ``profiles``,
    ``runout``."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    res = load(result)
    frames = res["frames"]
    g = _geometry(res)
    title = g["name"] if title is None else title
    t = np.asarray(frames["t_s"], float)
    picks = sorted({int(np.argmin(np.abs(t - ts))) for ts in snapshot_times if ts < t[-1]} | {len(t) - 1})
    dim = frames["x_m"].shape[-1]
    vert = dim - 1
    vname = "y" if vert == 1 else "z"
    act_all = frames["active"][picks].astype(bool)
    norm, note = viscosity_norm(np.asarray(frames["mu_pa_s"][picks], float)[act_all])
    xs = frames["x_m"][picks][act_all]
    if xs.size:
        x0, xmax = float(xs[:, 0].min()), float(xs[:, 0].max())
        z0, zmax = float(xs[:, vert].min()), float(xs[:, vert].max())
    else:
        x0, xmax, z0, zmax = g["lo"][0], g["hi"][0], g["lo"][vert], g["hi"][vert]
    xlim = (x0 - 0.02 * max(abs(xmax), 1e-9), xmax + 0.05 * max(abs(xmax), 1e-9))
    ylim = (z0 - 0.05 * max(abs(zmax), 1e-9), zmax + 0.15 * max(abs(zmax), 1e-9))
    lam = "lambda" in frames
    n_side = len(picks) + lam
    warnings = list(summary.get("warnings") or [])
    wrows = 0.18 * (len(warnings) + 1) if warnings else 0.0
    fig = plt.figure(figsize=(11, 1.9 * n_side + 3.6 + wrows), layout="constrained")
    gs = fig.add_gridspec(
        n_side + 1 + bool(warnings), 2, height_ratios=[1.0] * n_side + [1.9] + ([wrows / 1.9] if warnings else []),
        width_ratios=[1.35, 1.0],
    )
    size = float(np.clip(4000.0 / max(int(act_all[-1].sum()), 1), 0.5, 12.0))
    side_axes = []
    for r, k in enumerate(picks):
        ax = fig.add_subplot(gs[r, :])
        ax.set_label("side")
        act = frames["active"][k].astype(bool)
        x = frames["x_m"][k][act]
        ax.scatter(x[:, 0], x[:, vert], c=frames["mu_pa_s"][k][act], s=size, cmap="viridis", norm=norm, lw=0)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_ylabel(f"{vname} [m]")
        ax.set_title(
            f"t = {t[k]:.3g} s: viscosity{' (all particles projected on x-z)' if dim == 3 else ''}",
            fontsize=9,
            loc="left",
        )
        side_axes.append(ax)
    cb = fig.colorbar(
        ScalarMappable(norm=norm, cmap="viridis"), ax=side_axes, extend="min" if "below" in note else "neither",
        aspect=30,
    )
    cb.set_label(f"μ [Pa·s], log scale\n({note})", fontsize=8)
    if lam:
        k = len(t) - 1
        ax = fig.add_subplot(gs[len(picks), :])
        ax.set_label("lambda")
        act = frames["active"][k].astype(bool)
        x = frames["x_m"][k][act]
        lv = np.asarray(frames["lambda"][k], float)[act]
        lv_f = lv[np.isfinite(lv)]
        lnorm = Normalize(0.0, max(float(lv_f.max()) if lv_f.size else 1.0, 1e-6))
        sc = ax.scatter(x[:, 0], x[:, vert], c=lv, s=size, cmap="magma", norm=lnorm, lw=0)
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_ylabel(f"{vname} [m]")
        ax.set_title(f"t = {t[k]:.3g} s: structure parameter λ (0 = fully broken down)", fontsize=9, loc="left")
        fig.colorbar(sc, ax=ax, aspect=10).set_label("λ [-]", fontsize=8)
        side_axes.append(ax)
    side_axes[-1].set_xlabel("x [m]")

    # thickness profiles, coloured by time
    axp = fig.add_subplot(gs[n_side, 0])
    axp.set_label("profiles")
    xp, profs = result_profiles(res, runout=summary.get("runout_m"))
    cmap = plt.get_cmap("plasma")  # in time order: dark (first) to orange (last)
    reach = 0.0
    for i, (k, tk, hp) in enumerate(profs):
        axp.plot(xp, hp, drawstyle="default" if dim == 2 else "steps-mid", lw=1.2,
                 color=cmap(0.85 * i / max(len(profs) - 1, 1)), label=f"t = {tk:.3g} s")
        big = np.nonzero(hp > 0.01 * max(float(hp.max()), 1e-30))[0]
        if big.size:
            reach = max(reach, float(xp[big[-1]]))
    for w in (g["lo"][0 if dim == 2 else (g["axis"] if g["axis"] in (0, 1) else 0)],
              g["hi"][0 if dim == 2 else (g["axis"] if g["axis"] in (0, 1) else 0)]):
        axp.axvline(w, color="0.5", lw=0.8, ls=":")
    axp.set_xlim(xp[0], min(float(xp[-1]), reach + 0.1 * max(reach - float(xp[0]), 1e-9)) if reach > xp[0] else xp[-1])
    axp.set_ylim(bottom=0.0)
    pax = "x" if dim == 2 else "xyz"[g["axis"] if g["axis"] in (0, 1) else 0]
    axp.set_xlabel(f"{pax} [m]")
    axp.set_ylabel("thickness [m]")
    how = (f"kernel height profile, bandwidth h = {g['h']:g} m" if dim == 2
           else f"plan-view bins of {g['h']:g} m, largest across the flow")
    axp.set_title(f"thickness ({how}; dotted: domain walls)", fontsize=8, loc="left")
    axp.grid(alpha=0.3)
    axp.legend(fontsize=7, loc="upper right", title="time (colour)", title_fontsize=7)

    # runout against time
    axr = fig.add_subplot(gs[n_side, 1])
    axr.set_label("runout")
    ts, front = summary["times_s"], summary["runout_m"]
    axr.plot(ts, front, "-o", ms=3, label="free-surface front (headline)")
    if "runout_farthest_particle_m" in summary:
        axr.plot(ts, summary["runout_farthest_particle_m"], "--", lw=1, label="farthest particle")
    final = summary["final_runout_m"]
    axr.axhline(final, color="C0", lw=0.8, ls="-.", alpha=0.7)
    axr.annotate(f"final {final:.3f} m", (ts[-1], final), xytext=(-4, -6), textcoords="offset points",
                 ha="right", va="top", fontsize=8, color="C0")
    wall = summary.get("runout_wall_m")
    reach_r = max(list(front) + list(summary.get("runout_farthest_particle_m", [])))
    if wall is not None and reach_r > 0.7 * wall:  # drawn where it matters; far away it would flatten the curve
        axr.axhline(wall, color="k", lw=1, ls=":", label="domain wall")
    capped = " (CAPPED by the domain wall: a lower bound)" if summary.get("runout_capped_by_wall") else ""
    wall_note = f"; domain wall at {wall:.3g} m" if wall is not None else ""
    axr.set_title(f"final runout {final:.3f} m{capped}{wall_note}", fontsize=8, loc="left")
    axr.legend(fontsize=7, loc="lower right")
    axr.set_xlabel("time [s]")
    axr.set_ylabel("runout [m]")
    axr.ticklabel_format(axis="y", useOffset=False)
    axr.grid(True, alpha=0.3)

    facts = [f"{dim}D"]
    for key, fmt in (("n_particles", "{} particles"), ("cell_size_m", "h = {:g} m"), ("dt_s", "dt = {:.3g} s"),
                     ("t_end_s", "t_end = {:g} s")):
        if summary.get(key) is not None:
            facts.append(fmt.format(summary[key]))
    fig.suptitle(f"{title}: " + ", ".join(facts), fontsize=10)
    if warnings:
        axw = fig.add_subplot(gs[n_side + 1, :])
        axw.set_label("warnings")
        axw.axis("off")
        lines = [f"{len(warnings)} warning(s), in full in summary.json 'warnings':"]
        lines += [textwrap.shorten("• " + w, 180, placeholder=" …") for w in warnings]
        axw.text(0.0, 1.0, "\n".join(lines), fontsize=7, va="top", ha="left", color="#a00000", transform=axw.transAxes)
    return fig


def plot_result(path_png, result, summary: dict, title: str | None = None, snapshot_times=(1.0, 5.0)):
    """Save ``result_figure`` (the one-page report of a run: viscosity side views, λ for Coussot,
    thickness profiles, runout against time) as ``path_png``; ``result``: the ``read_result`` dict
    or a path to ``result.h5`` / its folder.  Returns the path."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = result_figure(result, summary, title, snapshot_times)
    try:
        fig.savefig(path_png, dpi=100)
    finally:
        plt.close(fig)
    return Path(path_png)


def plot_hazard_maps(path_png, cfg: dict, grid, maps: dict, summary: dict | None = None):
    """One page of hazard maps (``mpmjax._hazard``; docs/output.md) in map coordinates.

    3D: six panels on the terrain's hillshade (matplotlib's ``LightSource``; flat grey without a
    terrain): maximum flow depth, maximum speed, maximum depth x speed, arrival time, final deposit
    thickness, and the terrain's elevation with the breach release region.  Bins below the wet depth
    are transparent.  2D: the five quantities against x along the profile.

    cfg: the validated scene; grid: ``_hazard.HazardGrid``; maps: ``_hazard.final_maps``.
    Returns the path written."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LightSource

    origin = np.asarray(cfg["terrain.map_origin_m"] or [0.0] * len(grid.shape), float)
    names = list(MAPS)
    title = f"{cfg['name']}: hazard maps (wet depth >= {grid.threshold:g} m, sampled every {grid.every} step(s))"
    if len(grid.shape) == 1:
        x = origin[0] + grid.lo[0] + (np.arange(grid.shape[0]) + 0.5) * grid.cell
        fig, axes = plt.subplots(len(names), 1, figsize=(9, 1.8 * len(names)), sharex=True)
        for ax, k in zip(axes, names):
            ax.plot(x, maps[k], "-", lw=1.2)
            ax.set_ylabel(f"{k}\n[{MAPS[k][0]}]", fontsize=8)
            ax.grid(alpha=0.3)
        axes[-1].set_xlabel("x along the profile [m]")
        axes[0].set_title(title, fontsize=9)
    else:
        nx, ny = grid.shape
        xe = origin[0] + grid.lo[0] + grid.cell * np.array([0, nx])
        ye = origin[1] + grid.lo[1] + grid.cell * np.array([0, ny])
        extent = (xe[0], xe[1], ye[0], ye[1])
        ter = None
        if cfg["terrain.type"] != "none":
            t = terrain_of(cfg)
            xc = grid.lo[0] + (np.arange(nx) + 0.5) * grid.cell
            yc = grid.lo[1] + (np.arange(ny) + 0.5) * grid.cell
            gx, gy = np.meshgrid(xc, yc, indexing="ij")
            ter = t.height(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(nx, ny).T[::-1, :]
        shade = (
            LightSource(azdeg=315, altdeg=45).hillshade(ter, vert_exag=2.0, dx=grid.cell, dy=grid.cell)
            if ter is not None
            else np.full((ny, nx), 0.8)
        )
        aspect = (ye[1] - ye[0]) / (xe[1] - xe[0])
        fig, axes = plt.subplots(3, 2, figsize=(12, max(4.0, 3 * 3.2 * aspect * 2 + 1.5)))
        wet = (maps["max_depth_m"] >= grid.threshold).T[::-1, :]
        for ax, k in zip(axes.flat, names + ["terrain"]):
            ax.imshow(shade, cmap="gray", extent=extent, vmin=0, vmax=1, origin="upper")
            if k == "terrain":
                if ter is not None:
                    im = ax.imshow(ter, cmap="terrain", alpha=0.45, extent=extent, origin="upper")
                    fig.colorbar(im, ax=ax, shrink=0.8, label="elevation [m]")
                if cfg["release.region_map_m"] is not None:
                    poly = region_polygon(cfg["release.region_map_m"], None, 3)
                    ring = np.vstack([poly, poly[:1]])
                    ax.plot(ring[:, 0], ring[:, 1], "-", color="C3", lw=1.5, label="release region")
                    ax.legend(fontsize=7, loc="upper right")
                ax.set_title("terrain and release region", fontsize=9)
            else:
                img = maps[k].T[::-1, :]
                show = wet if k != "deposit_thickness_m" else (img >= grid.threshold)
                data = np.ma.masked_where(~show | ~np.isfinite(img), img)
                cmap = "viridis" if k == "arrival_time_s" else "magma_r"
                im = ax.imshow(data, cmap=cmap, extent=extent, origin="upper")
                fig.colorbar(im, ax=ax, shrink=0.8, label=f"[{MAPS[k][0]}]")
                top = np.nanmax(img) if np.isfinite(img).any() else float("nan")
                ax.set_title(f"{k}: max {top:.3g} {MAPS[k][0]}", fontsize=9)
            ax.set_xlim(*xe)
            ax.set_ylim(*ye)
            ax.tick_params(labelsize=7)
            ax.ticklabel_format(useOffset=False, style="plain")
        for ax in axes[-1]:
            ax.set_xlabel("map x (east) [m]", fontsize=8)
        for ax in axes[:, 0]:
            ax.set_ylabel("map y (north) [m]", fontsize=8)
        epsg = (summary or {}).get("map", {}).get("epsg") if summary else None
        fig.suptitle(title + (f"; EPSG:{epsg}" if epsg else ""), fontsize=10)
    fig.tight_layout()
    try:
        fig.savefig(path_png, dpi=90)
    finally:
        plt.close(fig)
    return Path(path_png)
