"""3D runs: plan-view maps (``load_plan_view``, ``plan_map``), vertical sections (``section``) and
the ``plan_view.png`` / ``sections.png`` that ``mpmjax run`` writes (``plot_3d_overview``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _metrics
from ._data import _check_field, _frame_index, _geometry, _label, field_values, load
from ._views import _make_norm


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
