"""Hazard maps: maximum flow depth, maximum speed, maximum depth x speed and arrival time over the
whole run, and the final deposit thickness, on the plan-view grid (3D) or along the profile (2D).

Grid (``HazardGrid``): bins of one cell h over the domain's plan, [lo + i h, lo + (i + 1) h) on each
horizontal axis, the bins of the 3D runout front and deposit thickness (``_metrics.RunoutGauge``).
Per bin, from the active particles whose plan position falls in it:

* flow depth d = sum of rest volumes V0 / bin area [m] (the depth of material at its rest density
  averaged over the bin; the vertical thickness, also on a slope), as ``_metrics.thickness_map``;
* speed u = |sum V0 v| / sum V0 [m/s]: the magnitude of the volume-averaged (depth-averaged) velocity
  vector, all components;
* a bin is *wet* when d >= ``output.hazard_depth_m``; speed and depth x speed count only in wet bins
  (a lone particle flying ahead would otherwise set the maximum speed);
* arrival time: the first sampled time [s] at which the bin is wet (-1 / no data: never).

Accumulation (``make_hazard_advance``): inside the forward driver's compiled frame, after every
``output.hazard_every_steps``-th step (default: every step), the bins of the state are taken and the
running maxima and arrival times updated, an extra carry of the scan next to the state.  So the maps
see the whole run, not only the saved frames, and a scene that does not ask for hazard maps runs the
unchanged advance and pays nothing.  The carry is outside the differentiable path (``simulate``,
used by calibration, never carries it).  Its cost per step is a scatter-add of 1 + dim numbers per particle
onto the bins plus elementwise maxima over the bins (measured: docs/scenarios.md, field-breach-3d).
A pipe pour with hazard maps steps its whole buffer each frame (the staged prefixes are not used).

Output (``write_hazard``): one raster per map in map coordinates (scene + ``terrain.map_origin_m``),
north up, pixel = bin, as GeoTIFF (rasterio) when the scene has a CRS, else as ESRI ASCII grids
(``output.hazard_format``); in 2D, ``hazard_profile.csv``.  ``summary.json`` ``hazard`` lists the
files, the transform and the maps' largest values.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _shallow
from ._dem import NODATA, write_raster
from ._received import check
from ._scene import Params, Scene, State
from ._shard import AXIS
from ._simulate import Pacer, chunkable, run_chunked
from ._slab import make_slab_advance
from ._step import make_step

MAPS = {  # file stem: (unit, meaning)
    "max_depth_m": ("m", "maximum flow depth over the run"),
    "max_speed_m_s": ("m/s", "maximum depth-averaged speed over the run, in wet bins"),
    "max_depth_speed_m2_s": ("m^2/s", "maximum of depth x speed over the run, in wet bins"),
    "arrival_time_s": ("s", "first time the flow depth reaches the wet threshold (no data: never)"),
    "deposit_thickness_m": ("m", "final deposit thickness (rest volumes per bin area) at the end of the run"),
}


class HazardGrid(NamedTuple):
    """Static plan-view grid: ``lo`` (dim-1,) [m] of the first bin's lower edge, ``cell`` [m],
    ``shape`` bins per horizontal axis, ``threshold`` wet depth [m], ``every`` steps between samples;
    ``plan``: the scene of a depth-averaged run, whose bins take the step's own nodal depth and
    momentum (``_shallow.cell_depth_speed``), or None (bins of particle positions)."""

    lo: tuple
    cell: float
    shape: tuple
    threshold: float
    every: int
    plan: Scene | None = None

    @classmethod
    def of(cls, scene: Scene, cfg: dict) -> HazardGrid:
        k = scene.dim - 1
        shape = tuple(int(round((scene.hi[a] - scene.lo[a]) / scene.h)) for a in range(k))
        return cls(
            tuple(float(a) for a in scene.lo[:k]),
            float(scene.h),
            shape,
            float(cfg["output.hazard_depth_m"]),
            int(cfg["output.hazard_every_steps"]),
            scene if scene.formulation == "depth-averaged" else None,
        )

    @property
    def n_bins(self) -> int:
        return int(np.prod(self.shape))


class HazardMaps(NamedTuple):
    """The running maps (flat over the bins, C order of ``HazardGrid.shape``) and the step count."""

    max_depth: jnp.ndarray
    max_speed: jnp.ndarray
    max_depth_speed: jnp.ndarray
    arrival: jnp.ndarray  # -1 until the bin is first wet
    steps: jnp.ndarray  # steps taken since the start (int32 scalar)


def init_maps(grid: HazardGrid, dtype) -> HazardMaps:
    z = jnp.zeros((grid.n_bins,), dtype)
    return HazardMaps(z, z, z, jnp.full((grid.n_bins,), -1.0, dtype), jnp.zeros((), jnp.int32))


def bins(state: State, grid: HazardGrid, total=None):
    """Flow depth [m] and depth-averaged speed [m/s] per bin (flat) of a state (module docstring).

    ``total``: sums the per-bin volume and momentum over the devices that hold the particles
    (``psum`` on slabs, ``make_hazard_advance``); default: the state holds them all.  A depth-averaged
    run (``grid.plan``) takes the step's nodal depth and momentum instead (``_shallow.cell_depth_speed``;
    it runs on one device)."""
    if grid.plan is not None:
        return _shallow.cell_depth_speed(grid.plan, state, grid.lo, grid.shape)
    k = len(grid.shape)
    x, dt = state.x, state.x.dtype
    idx = jnp.floor((x[:, :k] - jnp.asarray(grid.lo, dt)[None, :]) / grid.cell).astype(jnp.int32)
    inside = state.active & jnp.all((idx >= 0) & (idx < jnp.asarray(grid.shape)[None, :]), axis=1)
    flat = idx[:, 0] if k == 1 else idx[:, 0] * grid.shape[1] + idx[:, 1]
    flat = jnp.where(inside, flat, grid.n_bins)  # dropped by the scatter
    vol = jnp.where(inside, state.vol0, 0.0)
    vsum = jnp.zeros((grid.n_bins,), dt).at[flat].add(vol, mode="drop")
    mom = jnp.zeros((grid.n_bins, x.shape[1]), dt).at[flat].add(vol[:, None] * state.v, mode="drop")
    if total is not None:
        vsum, mom = total((vsum, mom))
    depth = vsum / grid.cell**k
    speed = jnp.sqrt(jnp.sum(mom * mom, axis=1)) / jnp.where(vsum > 0, vsum, 1.0)
    return depth, speed


def update(maps: HazardMaps, state: State, grid: HazardGrid, total=None) -> HazardMaps:
    """The maps after one more sample of ``state`` (time ``state.t``); ``total`` as ``bins``."""
    depth, speed = bins(state, grid, total)
    wet = depth >= grid.threshold
    return maps._replace(
        max_depth=jnp.maximum(maps.max_depth, depth),
        max_speed=jnp.maximum(maps.max_speed, jnp.where(wet, speed, 0.0)),
        max_depth_speed=jnp.maximum(maps.max_depth_speed, jnp.where(wet, depth * speed, 0.0)),
        arrival=jnp.where((maps.arrival < 0) & wet, state.t, maps.arrival),
    )


def make_hazard_advance(scene: Scene, grid: HazardGrid):
    """Jitted ``advance(state, maps, params) -> (state, maps)`` over one frame: the scene's step,
    and after every ``grid.every``-th step (counted from the start of the run) a map update.
    On slabs (``numerics.decomposition = "slab"``) the update runs inside the slab advance, each
    device binning its own particles and the bin sums added over devices, so the particles are
    dealt out once per frame (and rebalanced as usual), not once per step."""

    def sample(m: HazardMaps, s: State, total=None) -> HazardMaps:
        m = m._replace(steps=m.steps + 1)
        if grid.every == 1:
            return update(m, s, grid, total)
        return jax.lax.cond(m.steps % grid.every == 0, lambda: update(m, s, grid, total), lambda: m)

    if scene.devices > 1 and scene.decomposition == "slab":
        psum = functools.partial(jax.lax.psum, axis_name=AXIS)
        slab_advance = make_slab_advance(
            scene, make_step(scene, AXIS), scene.steps_per_frame, observe=lambda m, s: sample(m, s, psum)
        )

        def advance(state: State, maps: HazardMaps, params: Params):
            return slab_advance(state, params, maps)

        return jax.jit(advance)

    step = make_step(scene)

    def advance(state: State, maps: HazardMaps, params: Params, n):
        # ``n`` steps (an int32, one program for any n): the driver steps a frame in chunks
        # (``_simulate.run_chunked``); the maps count the steps themselves, so any chunking samples alike
        def body(i, carry):
            s, m = carry
            s = step(s, params)
            return s, sample(m, s)

        return jax.lax.fori_loop(0, n, body, (state, maps))

    return jax.jit(advance)


class HazardAdvance:
    """The driver's frame advance with hazard maps: ``advance(i, state, params) -> state`` as
    ``_simulate.StagedAdvance`` (always the whole buffer), keeping the maps in ``self.maps``
    (updated once the frame is computed)."""

    def __init__(self, scene: Scene, state: State, params: Params, grid: HazardGrid, pacer=None, between=check):
        self.scene, self.grid = scene, grid
        self.maps = init_maps(grid, state.x.dtype)
        self.schedule = (scene.n_particles,) * scene.n_frames
        self.fallbacks = 0
        self.chunked = chunkable(scene)
        self.pacer, self.between = pacer or Pacer(), between
        args = (state, self.maps, params) + ((np.int32(1),) if self.chunked else ())
        self._program = make_hazard_advance(scene, grid).lower(*args).compile()

    def sizes(self, first_frame: int = 0) -> list[int]:
        return [self.scene.n_particles]

    def program(self, n: int):
        return self._program

    def __call__(self, i: int, state: State, params: Params) -> State:
        """Frame ``i``: in chunks of steps where the scene is chunkable (``_simulate.StagedAdvance``)."""
        if not self.chunked:
            new, self.maps = self._program(state, self.maps, params)
            return new
        prog = self._program
        spf = self.scene.steps_per_frame
        new, self.maps = run_chunked(
            lambda c, k: prog(c[0], c[1], params, k), (state, self.maps), spf, self.pacer, self.between
        )
        return new

    def to_json(self) -> dict:
        """The maps as lists (for the checkpoint's metadata)."""
        return {k: np.asarray(a).tolist() for k, a in self.maps._asdict().items()}

    def restore(self, saved: dict) -> None:
        dt = self.maps.max_depth.dtype
        self.maps = HazardMaps(
            **{k: jnp.asarray(np.asarray(saved[k]), jnp.int32 if k == "steps" else dt) for k in HazardMaps._fields}
        )


def final_maps(maps: HazardMaps, state: State, grid: HazardGrid) -> dict[str, np.ndarray]:
    """The five maps as numpy arrays of ``grid.shape`` (arrival NaN where never wet)."""
    depth, _ = bins(state._replace(vol0=jnp.broadcast_to(state.vol0, state.active.shape)), grid)
    out = {
        "max_depth_m": maps.max_depth,
        "max_speed_m_s": maps.max_speed,
        "max_depth_speed_m2_s": maps.max_depth_speed,
        "arrival_time_s": jnp.where(maps.arrival < 0, jnp.nan, maps.arrival),
        "deposit_thickness_m": depth,
    }
    return {k: np.asarray(a, float).reshape(grid.shape) for k, a in out.items()}


def raster_format(cfg: dict) -> str:
    fmt = cfg["output.hazard_format"]
    if fmt == "auto":
        return "geotiff" if cfg["terrain.crs"] else "ascii"
    return fmt


def write_hazard(out: Path, cfg: dict, grid: HazardGrid, maps: dict[str, np.ndarray]) -> dict:
    """Write the hazard maps of a finished run to ``out``; returns summary.json's ``hazard``."""
    origin = cfg["terrain.map_origin_m"] or [0.0] * len(grid.shape)
    files = []
    summary = {
        "every_steps": grid.every,
        "wet_depth_m": grid.threshold,
        "cell_m": grid.cell,
        "maps": {k: {"unit": u, "meaning": m} for k, (u, m) in MAPS.items()},
        "definition": (
            f"plan-view bins of one cell ({grid.cell:g} m) over the domain; depth = rest volume / bin area, speed = "
            "|volume-averaged velocity|; maxima and arrival sampled inside the time loop after every "
            f"{grid.every} step(s), not only at saved frames; speeds only where depth >= {grid.threshold:g} m"
        ),
    }
    if len(grid.shape) == 1:
        x0 = grid.lo[0] + origin[0]
        xc = x0 + (np.arange(grid.shape[0]) + 0.5) * grid.cell
        cols = np.column_stack([xc] + [maps[k] for k in MAPS])
        path = Path(out) / "hazard_profile.csv"
        head = (
            f"hazard maps along the profile (mpmjax; docs/output.md): bins of {grid.cell:g} m, x_m = bin centre in map "
            f"coordinates (scene + {origin[0]:g} m); arrival nan: never wet\nx_m," + ",".join(MAPS)
        )
        np.savetxt(path, cols, delimiter=",", header=head, fmt="%.7g")
        files.append(path.name)
    else:
        fmt = raster_format(cfg)
        crs = cfg["terrain.crs"] or None
        left = grid.lo[0] + origin[0]
        top = grid.lo[1] + grid.shape[1] * grid.cell + origin[1]
        for k in MAPS:
            img = maps[k].T[::-1, :]  # (ny, nx), row 0 north
            p = write_raster(Path(out) / f"hazard_{k}", img, left, top, grid.cell, crs, fmt)
            files.append(p.name)
        summary.update(
            format=fmt,
            transform=[grid.cell, 0.0, left, 0.0, -grid.cell, top],
            transform_definition="GDAL affine (a, b, c, d, e, f): map x = c + a col, map y = f + e row, pixel corners",
            nodata=NODATA,
            width=grid.shape[0],
            height=grid.shape[1],
        )
    area = grid.cell ** len(grid.shape)
    wet = maps["max_depth_m"] >= grid.threshold
    arr = maps["arrival_time_s"]
    summary.update(
        files=files,
        max_flow_depth_m=float(maps["max_depth_m"].max()),
        max_speed_m_s=float(maps["max_speed_m_s"].max()),
        max_depth_speed_m2_s=float(maps["max_depth_speed_m2_s"].max()),
        inundated_area_m2=float(wet.sum() * area),
        last_arrival_s=float(np.nanmax(arr)) if np.isfinite(arr).any() else None,
        deposit_volume_m3=float(maps["deposit_thickness_m"].sum() * area),
        area_unit="m^2" if len(grid.shape) == 2 else "m (2D: length along the profile)",
    )
    if not math.isfinite(summary["max_speed_m_s"]):
        summary["max_speed_m_s"] = None
    return summary
