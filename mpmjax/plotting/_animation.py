"""``animate``: a GIF of the particles of a result, one image per saved frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._data import _check_field, _frame_index, _geometry, _label, field_values, load
from ._views import _axes_of, _make_norm


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
