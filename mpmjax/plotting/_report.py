"""The one-page report of a run, ``result.png`` (``result_figure``, ``plot_result``): its viscosity
colour scale (``viscosity_norm``) and thickness profiles (``result_profiles``)."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .. import _metrics
from .._io import frame_volumes
from .._observables import height_profile
from ._data import _frame_index, _geometry, load


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
    vol = frame_volumes(res)[k]
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
    vols = frame_volumes(res)
    out = []
    for k in ks:
        act = np.asarray(res["frames"]["active"][k]).astype(bool)
        tm = _metrics.thickness_map(np.asarray(res["frames"]["x_m"][k], float), vols[k], act, edges[0], edges[1])
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

    res = load(result)
    frames = res["frames"]
    g = _geometry(res)
    title = g["name"] if title is None else title
    t = np.asarray(frames["t_s"], float)
    picks = sorted({int(np.argmin(np.abs(t - ts))) for ts in snapshot_times if ts < t[-1]} | {len(t) - 1})
    dim = frames["x_m"].shape[-1]
    lam = "lambda" in frames
    n_side = len(picks) + lam
    warnings = list(summary.get("warnings") or [])
    wrows = 0.18 * (len(warnings) + 1) if warnings else 0.0
    fig = plt.figure(figsize=(11, 1.9 * n_side + 3.6 + wrows), layout="constrained")
    gs = fig.add_gridspec(
        n_side + 1 + bool(warnings), 2, height_ratios=[1.0] * n_side + [1.9] + ([wrows / 1.9] if warnings else []),
        width_ratios=[1.35, 1.0],
    )
    _side_views(fig, gs, res, g, picks)
    _thickness_panel(fig.add_subplot(gs[n_side, 0]), res, g, summary)
    _runout_panel(fig.add_subplot(gs[n_side, 1]), summary)

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


def _side_views(fig, gs, res, g: dict, picks: list[int]) -> None:
    """``result_figure``'s side views at the frames ``picks`` on one viscosity scale (grid rows 0..),
    and for Coussot runs the last frame coloured by λ in the row after them."""
    # matplotlib only when a plot is made (optional heavy import)
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    frames = res["frames"]
    t = np.asarray(frames["t_s"], float)
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


def _thickness_panel(axp, res, g: dict, summary: dict) -> None:
    """``result_figure``'s thickness profiles (``result_profiles``), coloured by time, on ``axp``."""
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib.pyplot as plt

    dim = res["frames"]["x_m"].shape[-1]
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


def _runout_panel(axr, summary: dict) -> None:
    """``result_figure``'s runout against time (free-surface front and farthest particle) with the
    final value and, where the front nears it, the domain wall, on ``axr``."""
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
