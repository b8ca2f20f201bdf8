"""Views of a result: particles of one frame (``particles``), height profiles with measured data
(``profiles``), runout against time (``runout_vs_time``), and the colour scales they share."""

from __future__ import annotations

import numpy as np

from ._data import (
    FIELDS,
    _check_field,
    _data_list,
    _frame_index,
    _geometry,
    _label,
    _pick_times,
    field_values,
    load,
    profile_at,
    runout,
)


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
