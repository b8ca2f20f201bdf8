"""``plot_hazard_maps``: the one page of hazard maps (``hazard_maps.png``) of a run with
output.hazard_maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._build import terrain_of
from .._hazard import MAPS
from .._release import region_polygon


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
