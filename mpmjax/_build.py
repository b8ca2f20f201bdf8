"""Building a run: validated scene dict -> ``Setup`` (static scene, traced parameters,
initial state, derived facts).

* ``make_params``: the material parameters (read through the law's ``Param``
  declarations) and the gravity vector;
* ``make_rheology``: the law instance with its static options;
* ``seed_bodies``: regular particle seeding of the material blocks (their union);
* ``time_step_limits``: the wave-speed and viscous limits of the fixed time step;
* ``memory_estimate``: the memory a run will need, from the validated scene alone;
* ``build``: grid, walls, gate, terrain and pipe-inflow pool, the time step and the scan
  lengths, and the initial state.

Units: SI throughout; the last axis is vertical.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import _basal, _bodies, _constitutive, _dem, _release, _rheology, _shallow, _shapes, _split
from ._boundary import inflow_layout
from ._scene import WALL_KINDS, Basal, Gate, Inflow, Params, Scene, Terrain, Wall, ghost_cells, init_state
from ._schema import SceneError
from ._shard import use_devices
from ._slab import check as slab_check


def make_params(cfg: dict, dim: int | None = None, dtype="float32") -> Params:
    """Traced parameters from a validated scene dict."""
    dim = cfg["domain.dim"] if dim is None else dim
    dt = jnp.dtype(dtype)

    def a(key):
        # an optional parameter the scene left out (the bulk modulus where the step does not use it)
        return jnp.asarray(_rheology.UNUSED if cfg[key] is None else cfg[key], dt)

    law = _rheology.MODELS[cfg["material.model"]]
    mat = law.params_type(**{p.name: a(p.key) for p in law.params})
    g = cfg["gravity.g_m_s2"]
    th = math.radians(cfg["gravity.slope_deg"])
    ph = math.radians(cfg["gravity.transverse_slope_deg"])
    if dim == 2:
        gv = [g * math.sin(th), -g * math.cos(th)]
    else:
        gv = [g * math.sin(th), g * math.sin(ph), -g * math.cos(th) * math.cos(ph)]
    basal = None
    if cfg["model.formulation"] == "depth-averaged" and cfg["terrain.type"] in ("coulomb", "voellmy"):
        xi = cfg["terrain.turbulence_m_s2"] if cfg["terrain.type"] == "voellmy" else math.inf
        basal = Basal(friction=a("terrain.friction"), turbulence=jnp.asarray(xi, dt))
    return Params(material=mat, gravity=jnp.asarray(gv, dt), basal=basal)


def make_rheology(cfg: dict):
    """The law instance of ``material.model`` with its static options from the scene."""
    law = _rheology.MODELS[cfg["material.model"]]
    return law(**{o.name: cfg[o.key] for o in law.options})


def layers_of(cfg: dict) -> int:
    """The layers across a column's depth that carry the law's internal variables (``_basal.layered``): the
    scene's ``numerics.depth_layers`` in the depth-averaged formulation for a law with internal variables and no
    yield stress (the layered closure has no yield part), else 1."""
    law = _rheology.MODELS[cfg["material.model"]]
    layered = cfg["model.formulation"] == "depth-averaged" and law.internals and not _basal.has_yield(law)
    return int(cfg["numerics.depth_layers"]) if layered else 1


def bodies_below_terrain(cfg: dict, terrain, meshes: list) -> list[str]:
    """Bodies that start below the terrain surface (``terrain.type`` != none; ``meshes``: each
    body's particles, ``seed_bodies(per_body=...)``).

    A body wholly below it is a ``SceneError`` naming the body, its top and the surface height
    over it: the step lifts every particle below the surface onto it, so such a body would
    silently become a film on the surface, nothing like the body given (issue 35: it ran without
    a word).  A body partly below it is a warning (returned, for ``start_warnings``): a box on a
    sloped bed dips a corner into the slope, and lifting those few particles is the documented
    contact; the warning gives the share lifted, since the body's shape and the material's volume
    where it is lifted differ from the input."""
    if terrain is None:
        return []
    warnings = []
    for i, mesh in enumerate(meshes):
        if not len(mesh):
            continue
        surface = terrain.height(mesh[:, :-1])
        below = mesh[:, -1] < surface
        lo, hi = _bodies.bounds(cfg["bodies"][i], mesh.shape[1])
        what = f"bodies[{i}] ({_bodies.kind(cfg['bodies'][i])}, from {lo.tolist()} to {hi.tolist()} m)"
        vertical = "xyz"[mesh.shape[1] - 1]
        if below.all():
            raise SceneError(
                f"{what} lies wholly below the terrain surface: its highest particle is at {vertical} = "
                f"{float(mesh[:, -1].max()):.4g} m, where the surface under the body is at {vertical} = "
                f"{float(surface.min()):.4g} to {float(surface.max()):.4g} m (terrain.*); allowed: a body above the "
                f"surface: raise bodies[{i}] to rest on it, or lower the terrain"
            )
        if below.any():
            warnings.append(
                f"{what} starts {100 * below.mean():.3g} % below the terrain surface ({int(below.sum())} of "
                f"{len(mesh)} particles, down to {float((surface - mesh[:, -1])[below].max()):.3g} m under it): "
                "they are lifted onto the surface at the first step, so the body's shape and volume there differ from "
                f"the input; raise bodies[{i}] to rest on the surface (it rises to {vertical} = "
                f"{float(surface.max()):.4g} m under the body)"
            )
    return warnings


def seed_bodies(cfg: dict, per_body: list | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regular particle seeding: ``ppc`` per axis per cell.  Returns x (n, dim) [m],
    vol0 (n,) [m^dim] and v (n, dim) [m/s].

    A box is filled on its own lattice, every particle holding the box's volume / its
    particle count.  A shaped body (cylinder, cone, polygon: ``_bodies``) gets the points of the
    domain's particle lattice inside it, each holding the lattice volume (h / ppc)^dim, so its
    seeded volume differs from the exact one by the cells its surface cuts (``_bodies``).
    Overlapping bodies are seeded as their union: a particle of a later body that lies inside
    (or on the surface of) an earlier body is dropped, so overlapping material is not seeded
    twice (two boxes overlapping by half used to hold 4/3 of their union's mass); where bodies
    overlap, the earlier body's particles (and velocity) are kept.  ``per_body``: a list that gets
    each body's particle positions (after that removal)."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    dx = h / ppc
    xs, vols, vs = [np.zeros((0, dim))], [np.zeros(0)], [np.zeros((0, dim))]
    earlier: list[dict] = []
    for b in cfg["bodies"]:
        if _bodies.kind(b) == "box":
            lo, hi = np.asarray(b["lo_m"], float), np.asarray(b["hi_m"], float)
            counts = np.maximum(np.round((hi - lo) / dx).astype(int), 1)
            axes = [lo[d] + (np.arange(counts[d]) + 0.5) * (hi[d] - lo[d]) / counts[d] for d in range(dim)]
            mesh = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)
            vol = np.prod(hi - lo) / len(mesh)  # each box's particles fill it exactly
        else:
            mesh = _bodies.lattice(cfg, b)
            vol = dx**dim  # the lattice volume (_bodies: boundary cells)
            if not len(mesh):
                lo, hi = _bodies.bounds(b, dim)
                raise SceneError(
                    f"bodies[{len(earlier)}] ({b['type']}, spanning [{lo.tolist()}, {hi.tolist()}] m) holds no point "
                    f"of the particle lattice (spacing domain.cell_size_m / numerics.ppc = {dx:g} m): nothing to seed; "
                    "allowed: a body at least a particle spacing across, or a smaller domain.cell_size_m"
                )
        keep = np.ones(len(mesh), bool)
        for e in earlier:
            keep &= ~_bodies.contains(e, mesh)
        earlier.append(b)
        mesh = mesh[keep]
        if per_body is not None:
            per_body.append(mesh)
        xs.append(mesh)
        vols.append(np.full(len(mesh), vol))
        vs.append(np.broadcast_to(np.asarray(b.get("velocity_m_s", [0.0] * dim), float), mesh.shape))
    return np.concatenate(xs), np.concatenate(vols), np.concatenate(vs)


def terrain_of(cfg: dict) -> Terrain | None:
    """The height-map boundary of a validated scene (``terrain.type`` != none), else None."""
    if cfg["terrain.type"] == "none":
        return None
    dim = cfg["domain.dim"]
    hs = np.asarray(cfg["terrain.heights_m"], float)
    return Terrain(
        origin=tuple(map(float, cfg["terrain.origin_m"])),
        spacing=(float(cfg["terrain.spacing_m"]),) * (dim - 1),
        heights=tuple(map(tuple, hs)) if hs.ndim == 2 else tuple(map(float, hs)),
        kind=cfg["terrain.type"],
        friction=float(cfg["terrain.friction"]),
    )


def _add_release(cfg: dict, terrain, x, vol0, v):
    """The bodies' particles followed by the breach release's (``_release``), filled down to the
    terrain (the domain floor without one); an empty release is an error."""
    floor = float(cfg["domain.lo_m"][-1])
    height = terrain.height if terrain is not None else (lambda xy: np.full(len(xy), floor))
    xr, vr, info = _release.seed_release(cfg, height, cfg["bodies"])
    if not len(xr):
        raise SceneError(
            f"release.pond_level_m = {cfg['release.pond_level_m']} is invalid: it lies below the terrain everywhere "
            f"in release.region_map_m = {cfg['release.region_map_m']}, or no particle column (spacing "
            f"{cfg['domain.cell_size_m'] / cfg['numerics.ppc']:g} m) has its centre in the region: nothing to release; "
            "allowed: a pond level above the terrain somewhere in a region at least a particle spacing wide"
        )
    info["back_m"] = (xr.min(axis=0) - 0.5 * cfg["domain.cell_size_m"] / cfg["numerics.ppc"]).tolist()
    return (
        np.concatenate([x, xr]),
        np.concatenate([vol0, vr]),
        np.concatenate([v, np.zeros_like(xr)]),
        info,
    )


@dataclasses.dataclass
class Setup:
    """A built run: static scene, traced parameters, initial state and derived facts."""

    cfg: dict
    scene: Scene
    params: Params
    state: Any
    info: dict


def _fall_height(cfg: dict, params: Params, x: np.ndarray) -> float:
    """Largest drop along gravity [m] available to the material: from its highest point to the
    lowest point of the domain box (with a terrain: the lowest terrain sample, which the
    material cannot pass).  Measured along the (possibly tilted) gravity vector, so a block
    released above the floor, or a slope tilted by ``gravity.slope_deg``, counts its whole
    fall.  (It used to be the material's own height span, which let a 1 m drop run at an
    impact speed 2.4x the bound and blow up, and field runs exceed their bound by 1.7x.)"""
    g = np.asarray(params.gravity, float)
    gn = float(np.linalg.norm(g))
    if x.size == 0 or gn == 0.0:
        return 0.0
    up = -g / gn
    dim = x.shape[1]
    if cfg["terrain.type"] != "none":
        hs = np.asarray(cfg["terrain.heights_m"], float)
        axes = [cfg["terrain.origin_m"][a] + cfg["terrain.spacing_m"] * np.arange(hs.shape[a]) for a in range(dim - 1)]
        grid = np.meshgrid(*axes, indexing="ij")
        low = np.stack([*(a.ravel() for a in grid), hs.ravel()], axis=1)
    else:
        lo, hi = cfg["domain.lo_m"], cfg["domain.hi_m"]
        low = np.array(list(itertools.product(*zip(lo, hi))), float)
    return max(0.0, float(np.max(x @ up) - np.min(low @ up)))


def time_step_limits(cfg: dict, params: Params, x: np.ndarray, v: np.ndarray, rheology) -> dict:
    """Wave-speed and viscous limits [s] and the inputs they came from.

    dt_wave = cfl h / (c + |v|), c = sqrt((kappa + 4/3 G)/rho) with the Maxwell modulus G
    (G = 0 for the explicit update); |v| = velocity_scale_m_s, or sqrt(2 g H) plus the
    largest initial speed, H the fall height along gravity from the highest material point
    to the lowest point the material can reach (``_fall_height``): a frictionless energy bound.
    dt_visc = viscous_safety rho h^2 / (2 d mu_max), mu_max the largest viscosity the law
    can reach; it binds only the explicit update.
    With the pressure solved on the grid (numerics.pressure = incompressible) the sound speed
    leaves c: c = sqrt(4/3 G / rho), and G = 0 in numerics.maxwell_shear_modulus_pa means
    G = max(rho |v|^2, ``_constitutive.MAXWELL_YIELD_FACTOR`` tau_y) instead of kappa (tau_y the law's
    yield stress, if any).
    """
    mat = params.material
    rho, kappa = float(mat.rho), float(mat.kappa)
    h, dim = cfg["domain.cell_size_m"], cfg["domain.dim"]
    maxwell = cfg["numerics.viscous_update"] == "maxwell"
    implicit = cfg["numerics.pressure"] != "explicit"
    G = (cfg["numerics.maxwell_shear_modulus_pa"] or kappa) if maxwell else 0.0
    # numpy float64 arithmetic: extreme (validated) inputs give inf / 0 / nan instead of
    # raising; build() rejects a limit that is not a positive finite number.
    f64 = np.float64
    with np.errstate(all="ignore"):
        c = float(np.sqrt((f64(kappa) + f64(4.0 / 3.0) * f64(G)) / f64(rho)))
        vscale = cfg["numerics.velocity_scale_m_s"]
        if vscale == 0.0:
            # + half a particle spacing: the top of the material, not its top particle centre
            H = _fall_height(cfg, params, x) + 0.5 * h / cfg["numerics.ppc"]
            vscale = float(
                np.sqrt(f64(2.0) * f64(cfg["gravity.g_m_s2"]) * f64(H))
                + np.max(np.linalg.norm(np.asarray(v, float), axis=1), initial=0.0)
            )
        if implicit:
            # the pressure solved on the grid: only the Maxwell shear waves are explicit, and G = 0 means
            # G = rho |v|^2, so that they are no faster than the flow and the step follows the flow speed (and at
            # least a multiple of the yield stress: _constitutive.MAXWELL_YIELD_FACTOR)
            if maxwell and not cfg["numerics.maxwell_shear_modulus_pa"]:
                tau_y = float(rheology.yield_stress(mat))
                G = float(max(f64(rho) * f64(vscale) ** 2, f64(_constitutive.MAXWELL_YIELD_FACTOR) * f64(tau_y)))
            c = float(np.sqrt(f64(4.0 / 3.0) * f64(G) / f64(rho)))
        dt_wave = float(f64(cfg["numerics.cfl"]) * f64(h) / (f64(c) + f64(vscale)))
        mu_max = float(rheology.max_viscosity(mat))
        dt_visc = float(
            f64(cfg["numerics.viscous_safety"]) * f64(rho) * f64(h) * f64(h) / (f64(2.0 * dim) * f64(mu_max))
        )
    limit = dt_wave if maxwell else min(dt_wave, dt_visc)
    return {
        "dt_wave_s": dt_wave,
        "dt_viscous_s": dt_visc,
        "dt_limit_s": limit,
        "wave_speed_m_s": c,
        "velocity_scale_m_s": vscale,
        "maxwell_G_pa": G,
        "mu_max_pa_s": mu_max,
    }


_MAX_STEPS_PER_FRAME = 2**31 - 1  # scan length of one frame


def _dt_inputs(cfg: dict, lim: dict) -> str:
    keys = [
        "numerics.dt_s",
        "domain.cell_size_m",
        "numerics.cfl",
        "material.density_kg_m3",
        "material.bulk_modulus_pa",
        "numerics.maxwell_shear_modulus_pa",
        "numerics.velocity_scale_m_s",
        "gravity.g_m_s2",
    ]
    text = ", ".join(f"{k} = {cfg[k]!r}" for k in keys)
    text += f", bodies velocity_m_s (velocity scale {lim['velocity_scale_m_s']!r} m/s)"
    if cfg["numerics.viscous_update"] == "explicit":
        law = _rheology.MODELS[cfg["material.model"]]
        key_of = {p.name: p.key for p in law.params}
        visc = [key_of[name] for name in law.max_viscosity_params]
        text += (
            f", numerics.viscous_safety = {cfg['numerics.viscous_safety']!r}, "
            + ", ".join(f"{k} = {cfg[k]!r}" for k in visc)
            + f" (material.model = {cfg['material.model']!r}: mu_max = {lim['mu_max_pa_s']!r} Pa s)"
        )
    return text


def _grid_shape(cfg: dict) -> tuple[int, ...]:
    """Grid nodes per axis: the cells of the domain plus the ghost layers outside each
    non-periodic face (periodic axes wrap: one node per cell)."""
    dim, h = cfg["domain.dim"], cfg["domain.cell_size_m"]
    lo, hi = np.asarray(cfg["domain.lo_m"]), np.asarray(cfg["domain.hi_m"])
    ng = ghost_cells(cfg["numerics.shape"])
    ncell = np.round((hi - lo) / h).astype(int)
    periodic = [cfg[f"boundary.{'xyz'[a]}_lo"] == "periodic" for a in range(dim)]
    return tuple(int(ncell[a] if periodic[a] else ncell[a] + 2 * ng + 1) for a in range(dim))


def memory_estimate(cfg: dict) -> dict:
    """Memory [bytes] a run of a validated scene needs, estimated before anything is built
    (so that a run that cannot fit is refused in a second instead of failing after compiling).

    Deliberately generous (it may overestimate 2-3x, never by orders of magnitude):

    * ``device_bytes``, where the step runs: 4 copies of the particle state (the state in and
      out of a frame, the last good frame kept for the health check, XLA buffers), the
      per-particle stencil temporaries of the transfers (for each of the stencil^dim nodes: weight,
      gradient, node index and the scattered mass and momentum, twice), and 4 copies of the
      grid fields (mass, momentum, velocity, old velocity, force); with ``numerics.devices`` = N > 1
      the grid once per device (the replicated grid, and slabs, whose windows span about the whole
      grid: ``_slab``), and with slabs the particle state and temporaries for
      ``numerics.slab_capacity`` times the particles (the devices' slots, empty ones included);
    * ``host_bytes``: the saved frames that ``run_scene`` reads back at the end for the
      summary metrics and pictures ((n_frames + 1) x particles x the stored float32 fields),
      plus, on the CPU backend, ``device_bytes``.

    Particles: the sum of the bodies' lattice counts (an upper bound: overlaps are seeded once)
    plus a pipe inflow's pool, plus a breach release's geometric volume / (h / ppc)^dim.  With the
    depth-averaged formulation the particles are columns (a box's plan lattice count, the release's
    wet columns) and the grid is the plan's, so neither is counted over the vertical."""
    dim = cfg["domain.dim"]
    shallow = cfg["model.formulation"] == "depth-averaged"
    k = dim - 1 if shallow else dim  # the axes the particles and the grid span
    item = 8 if cfg["numerics.dtype"] == "float64" else 4
    dx = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
    n = 0.0
    for b in cfg["bodies"]:
        if _bodies.kind(b) == "box":
            counts = np.maximum(np.round((np.asarray(b["hi_m"]) - np.asarray(b["lo_m"])) / dx), 1.0)
            n += float(np.prod(counts[:k]))
        else:
            n += _bodies.lattice_count_bound(cfg, b)
    if cfg["inflow.point_m"] is not None:
        n += float(inflow_layout(cfg, dim)[2])
    if cfg["release.region_map_m"] is not None:  # about one particle per dx^dim of pond (one per column: shallow)
        ter = terrain_of(cfg)
        floor = float(cfg["domain.lo_m"][-1])
        height = ter.height if ter is not None else (lambda xy: np.full(len(xy), floor))
        n += _release.wet_columns(cfg, height) if shallow else _release.geometric_volume(cfg, height) / dx**dim
    if shallow and cfg["numerics.split_levels"] > 0:  # the spare slots of column splitting (_split)
        n *= 1.0 + float(cfg["numerics.split_pool"])
    nodes = float(np.prod(np.asarray(_grid_shape(cfg), float)[:k]))
    # internal variables per particle: one value each, or one per layer across a column's depth
    n_internal = len(_rheology.MODELS[cfg["material.model"]].internals) * layers_of(cfg)
    state_per_particle = (2 * dim + 2 * dim * dim + 3 + n_internal) * item + 2  # x v C tau J vol0 mu internal; bools
    stencil = _shapes.STENCIL[cfg["numerics.shape"]] ** dim
    step_per_particle = 2 * stencil * (2 * dim + 3) * item
    n_dev = int(cfg["numerics.devices"])
    slab = n_dev > 1 and cfg["numerics.decomposition"] == "slab"
    slots = min(float(cfg["numerics.slab_capacity"]), n_dev) if slab else 1.0  # _slab.geometry's capacity
    particles = slots * n * (4 * state_per_particle + step_per_particle)
    grid = n_dev * 4 * nodes * (3 * dim + 2) * item
    frames = (cfg["time.n_frames"] + 1) * n * ((2 * dim + 3 + n_internal) * 4 + 1)
    return {
        "particles": n,
        "grid_nodes": nodes,
        "particle_bytes": particles,
        "grid_bytes": grid,
        "frames_bytes": frames,
        "device_bytes": particles + grid,
        "host_bytes": frames,
        "dtype": cfg["numerics.dtype"],
    }


def build(cfg: dict) -> Setup:
    """Validated scene dict -> ``Setup`` (scene, params, initial state, info).

    A ``float64`` scene switches on ``jax_enable_x64`` (without it JAX would silently
    truncate every array to float32).  A scene with ``numerics.devices`` > 1 needs that many
    devices in the process (``_shard.use_devices``; the run driver makes them on a CPU).
    """
    use_devices(int(cfg["numerics.devices"]), make=False)
    dim, h = cfg["domain.dim"], cfg["domain.cell_size_m"]
    dtype = cfg["numerics.dtype"]
    if dtype == "float64" and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    params = make_params(cfg, dim, dtype)
    rheology = make_rheology(cfg)
    depth_layers = layers_of(cfg)
    meshes: list = []
    x, vol0, v = seed_bodies(cfg, meshes)
    terrain = terrain_of(cfg)
    buried = bodies_below_terrain(cfg, terrain, meshes)  # SceneError for a body wholly below the surface
    release = None
    if cfg["release.region_map_m"] is not None:
        x, vol0, v, release = _add_release(cfg, terrain, x, vol0, v)
    n_bodies = len(x)
    inflow = None
    if cfg["inflow.point_m"] is not None:
        offs, area, _, n_layers, layer_dt, u, d = inflow_layout(cfg, dim)
        n_per = len(offs)
        thickness = u * layer_dt
        exit_ = np.asarray(cfg["inflow.point_m"], float)
        inflow = Inflow(
            point=tuple(map(float, exit_)),
            direction=tuple(map(float, d)),
            speed=float(u),
            first=int(n_bodies),
            n_layers=int(n_layers),
            n_per_layer=int(n_per),
            layer_dt=float(layer_dt),
            t_start=float(cfg["inflow.t_start_s"]),
            thickness=float(thickness),
            offsets=tuple(tuple(map(float, o)) for o in offs),
            half_width=0.5 * float(cfg["inflow.width_m"]),
            pipe_length=2.0 * float(h),
        )
        # parked (inactive) at the exit, one layer thickness behind it
        park = np.tile(exit_[None, :] + offs - 0.5 * thickness * d[None, :], (n_layers, 1))
        x = np.concatenate([x, park])
        vol0 = np.concatenate([vol0, np.full(len(park), area * thickness / n_per)])
        v_pool = np.broadcast_to(u * d, park.shape)
        v = np.concatenate([v, v_pool])
    shallow = cfg["model.formulation"] == "depth-averaged"
    split_min = 0.0
    if shallow:  # columns on the plan (_shallow): one particle per seeded column
        x, vol0, v = _shallow.columns(x, vol0, v)
        n_bodies = len(x)
        if cfg["numerics.split_levels"] > 0 and n_bodies:  # spare slots for split columns (_split): inactive, volume 0
            k = dim - 1
            split_min = _split.min_volume(vol0, k, int(cfg["numerics.split_levels"]))
            n_pool = int(math.ceil(float(cfg["numerics.split_pool"]) * n_bodies))
            x = np.concatenate([x, np.repeat(x[:1], n_pool, axis=0)])
            vol0 = np.concatenate([vol0, np.zeros(n_pool)])
            v = np.concatenate([v, np.zeros((n_pool, v.shape[1]))])
    if cfg["numerics.force"] == "mls" and (
        cfg["numerics.transfer"] != "apic" or cfg["numerics.shape"] not in ("quadratic", "cubic")
    ):
        raise SceneError(
            f'numerics.force = "mls" is invalid with numerics.transfer = {cfg["numerics.transfer"]!r} and '
            f'numerics.shape = {cfg["numerics.shape"]!r}: allowed with transfer = "apic" and shape = "quadratic" '
            f'or "cubic" (MLS needs APIC\'s affine matrix and a constant inertia D = h^2/4 or h^2/3), or use '
            f'numerics.force = "gradient"'
        )
    if shallow:
        bed_pts = x.copy()
        bed_pts[:, -1] = terrain.height(x[:, :-1]) if terrain is not None else float(cfg["domain.lo_m"][-1])
        fall = _fall_height(cfg, params, bed_pts) if len(x) else 0.0
        lim = _shallow.time_step_limits(cfg, params, x, vol0, v, fall, rheology)
    else:
        lim = time_step_limits(cfg, params, x, v, rheology)
    t_end, n_frames = cfg["time.t_end_s"], cfg["time.n_frames"]
    dt_req = cfg["numerics.dt_s"]
    if not (math.isfinite(lim["dt_limit_s"]) and lim["dt_limit_s"] > 0.0):
        raise SceneError(
            f"the stable time step is {lim['dt_limit_s']!r} s (wave-speed limit {lim['dt_wave_s']!r} s, viscous limit "
            f"{lim['dt_viscous_s']!r} s), not a positive finite number; allowed: inputs that give one: "
            f"{_dt_inputs(cfg, lim)}"
        )
    if dt_req > 0.0:
        if dt_req > lim["dt_limit_s"] * (1 + 1e-9):
            raise SceneError(
                f"numerics.dt_s = {dt_req} is invalid: allowed range: <= {lim['dt_limit_s']:.4g} s "
                f"(wave-speed limit {lim['dt_wave_s']:.4g} s, viscous limit {lim['dt_viscous_s']:.4g} s)"
            )
        dt_target = dt_req
    else:
        dt_target = lim["dt_limit_s"]
    with np.errstate(all="ignore"):
        spf_f = float(np.float64(t_end) / np.float64(n_frames) / np.float64(dt_target))
    if not math.isfinite(spf_f) or spf_f > _MAX_STEPS_PER_FRAME:
        raise SceneError(
            f"time.t_end_s = {t_end} with time.n_frames = {n_frames} needs {spf_f:.4g} steps per frame of "
            f"dt = {dt_target:.4g} s; allowed: at most {_MAX_STEPS_PER_FRAME} steps per frame (shorten time.t_end_s, "
            f"raise time.n_frames, or change the inputs of the time step: {_dt_inputs(cfg, lim)})"
        )
    spf = max(1, math.ceil(spf_f - 1e-9))
    dt = t_end / (n_frames * spf)
    lo, hi = np.asarray(cfg["domain.lo_m"]), np.asarray(cfg["domain.hi_m"])
    faces = [(cfg[f"boundary.{'xyz'[a]}_lo"], cfg[f"boundary.{'xyz'[a]}_hi"]) for a in range(dim)]
    periodic = tuple(f[0] == "periodic" for f in faces)
    ng = ghost_cells(cfg["numerics.shape"])
    origin = tuple(float(lo[a] - (0 if periodic[a] else ng * h)) for a in range(dim))
    shape = _grid_shape(cfg)
    walls = []
    for a in range(dim):
        for side, kind in zip((0, 1), faces[a]):
            if kind in WALL_KINDS:
                nrm = [0.0] * dim
                nrm[a] = 1.0 if side == 0 else -1.0
                pt = [0.0] * dim
                pt[a] = float(lo[a] if side == 0 else hi[a])
                b = float(cfg["boundary.slip_length_m"]) if kind == "noslip" else 0.0
                walls.append(Wall(tuple(pt), tuple(nrm), kind, b))
    for p in cfg["boundary.planes"]:
        walls.append(Wall(tuple(map(float, p["point_m"])), tuple(map(float, p["normal"])), p.get("type", "noslip")))
    gate = None
    if cfg["gate.point_m"] is not None:
        gate = Gate(tuple(cfg["gate.point_m"]), tuple(cfg["gate.normal"]))
    elif inflow is not None and cfg["inflow.aging_gate"]:
        gate = Gate(inflow.point, inflow.direction)
    scene = Scene(
        dim=dim,
        h=float(h),
        lo=tuple(map(float, lo)),
        hi=tuple(map(float, hi)),
        periodic=periodic,
        grid_origin=origin,
        grid_shape=shape,
        walls=tuple(walls),
        shape=cfg["numerics.shape"],
        lp_cells=0.5 / cfg["numerics.ppc"],
        grid_density_cap=float(cfg["numerics.grid_density_cap"]),
        volume_averaging=cfg["numerics.volume_averaging"],
        devices=int(cfg["numerics.devices"]),
        decomposition=cfg["numerics.decomposition"],
        slab_capacity=float(cfg["numerics.slab_capacity"]),
        transfer=cfg["numerics.transfer"],
        force=cfg["numerics.force"],
        pressure=cfg["numerics.pressure"],
        void_closure=cfg["numerics.void_closure"],
        stress_quadrature=cfg["numerics.stress_quadrature"],
        maxwell_rotation=cfg["numerics.maxwell_rotation"],
        wall_yield=cfg["numerics.wall_yield"],
        cell_shear=cfg["numerics.cell_shear"],
        formulation=cfg["model.formulation"],
        bed_curvature=cfg["model.bed_curvature"],
        split_levels=int(cfg["numerics.split_levels"]) if shallow else 0,
        depth_layers=depth_layers,
        internal_friction_deg=cfg["model.internal_friction_deg"],
        split_min_volume=float(split_min),
        flip_blend=cfg["numerics.flip_blend"],
        rheology=rheology,
        shear_measure=cfg["material.shear_measure"],
        viscous_update=cfg["numerics.viscous_update"],
        maxwell_G=float(lim["maxwell_G_pa"]) if lim["maxwell_G_pa"] else float(params.material.kappa),
        dt=float(dt),
        steps_per_frame=int(spf),
        n_frames=int(n_frames),
        n_particles=int(len(x)),
        gate=gate,
        dtype=dtype,
        inflow=inflow,
        terrain=terrain,
    )
    slab_check(scene)
    active = np.arange(len(x)) < n_bodies
    state = init_state(scene, params, x, vol0, np.where(active[:, None], v, 0.0), active=active)
    if inflow is not None and gate is not None and cfg["gate.point_m"] is None:
        # the exit gate holds only the pipe material back: initial bodies age from t = 0
        state = state._replace(gate=jnp.asarray(active))
    axis = cfg["output.runout_axis"]
    origin_r = cfg["output.runout_origin_m"]
    if math.isnan(origin_r):
        starts = [_bodies.start(cfg, b, axis) for b in cfg["bodies"]]
        if release is not None and release["particles"]:
            starts.append(release["back_m"][axis])
        if inflow is not None:
            starts.append(inflow.point[axis])
        origin_r = float(min(starts))
    info = dict(
        lim,
        dt_s=float(dt),
        n_steps=scene.n_steps,
        runout_axis=axis,
        runout_origin_m=origin_r,
        particle_spacing_m=h / cfg["numerics.ppc"],
    )
    if scene.split_levels > 0:
        info["split_pool"] = int(len(x) - n_bodies)
    if buried:
        info["bodies_below_terrain"] = buried
    if release is not None:
        info["release"] = {k: a for k, a in release.items() if k != "back_m"}
    map_ = _dem.map_info(cfg)
    if map_ is not None:
        info["map"] = map_
    if inflow is not None:
        info.update(
            inflow_pool_particles=int(len(x) - n_bodies),
            inflow_speed_m_s=inflow.speed,
            inflow_layer_dt_s=inflow.layer_dt,
            inflow_volume_m3=float(np.sum(vol0[n_bodies:])),
            inflow_t_stop_s=inflow.t_stop,
        )
    return Setup(cfg=cfg, scene=scene, params=params, state=state, info=info)


# --- warnings at run start (issue 17 item 5) -------------------------------------------------

BODY_CELLS_MIN = 4  # a body thinner than this many cells along an axis is under-resolved
DT_FORCED_RATIO = 10.0  # warn when the frame interval forces dt this far below the stable step
STEPS_WARN = 1_000_000  # warn when a run needs more steps than this
# conservative time-loop rates [particle-steps/s] for the run-time estimates of the warnings: about
# half of what the 2-core CPU VM measured (docs/performance.md: 2D 1-2.9 M, 3D 0.12-0.6 M)
EST_RATE = {2: 1.0e6, 3: 1.0e5}
EST_STEP_S = 2e-4  # and at least this per step (small runs: the per-step overhead, ~2000 steps/s)
# the particles' pressure (numerics.pressure = "explicit") locks a yield-stress or thixotropic material as its
# hydrostatic strain rho g H / kappa falls: warn below this.  Measured (docs/validation.md, "Incompressible
# limit"): dambreak-lab 1.282 / 1.175 / 0.647 m at 24 / 2.4 / 0.24 %; bingham-dambreak (h = 1 cm) 1.240 / 1.184 /
# 0.732 m at 5 / 0.5 / 0.05 %, and 1.315 m with the grid pressure.  The Newtonian Cruchaga columns move by at most
# 0.9 % over κ / 10 to κ x 10 (free-surface front at 0.2 s, h = 5 mm): a purely viscous material is not warned
LOCKING_STRAIN = 0.05


def estimate_run_time_s(n_particles: int, n_steps: int, dim: int) -> float:
    """A conservative estimate [s] of the time loop of a run on a CPU: n_steps x max(n_particles /
    EST_RATE[dim], EST_STEP_S).  A GPU is 1-2 orders of magnitude faster (docs/performance.md)."""
    return float(n_steps) * max(float(n_particles) / EST_RATE.get(dim, EST_RATE[3]), EST_STEP_S)


def _duration(s: float) -> str:
    if s < 10:
        return f"{s:.2g} s"
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"


def start_warnings(setup: Setup) -> list[str]:
    """Warnings about a built run, printed before its time loop and kept in summary.json's
    ``warnings`` (docs/output.md).  Each names the scene key, its value and what to change:

    * a body fewer than ``BODY_CELLS_MIN`` cells thick along an axis (an axis it spans whole
      on a periodic domain does not count, nor the vertical of the depth-averaged formulation, whose
      columns carry the depth: no cell resolves it);
    * ``time.n_frames`` forcing the time step more than ``DT_FORCED_RATIO`` x below the step
      the run would otherwise take (the stable step, or ``numerics.dt_s``): the frame interval
      t_end / n_frames must be a whole number of steps, so a frame interval shorter than the
      step makes each frame one step of exactly that interval;
    * a run of more than ``STEPS_WARN`` steps, naming what sets the step (the bulk modulus for a
      wave-speed limit), with the estimated run time (``estimate_run_time_s``);
    * a body that starts partly below the terrain surface (``bodies_below_terrain``; wholly
      below is an error);
    * a non-Newtonian material under the particles' pressure whose hydrostatic strain rho g H / kappa
      is below ``LOCKING_STRAIN`` (H its depth along gravity at the start): there the runout depends on
      material.bulk_modulus_pa (volumetric locking), which the grid pressure removes."""
    cfg, sc, info = setup.cfg, setup.scene, setup.info
    h, dim = sc.h, sc.dim
    out = list(info.get("bodies_below_terrain", []))  # bodies partly below the terrain (bodies_below_terrain)
    for i, b in enumerate(cfg["bodies"]):
        box = _bodies.kind(b) == "box"
        lo, hi = _bodies.bounds(b, dim)
        if not box:  # a shaped body cut by a symmetry face
            lo, hi = np.maximum(lo, sc.lo), np.minimum(hi, sc.hi)
        thin = []
        for a in range(dim - 1 if sc.formulation == "depth-averaged" else dim):
            cells = (hi[a] - lo[a]) / h
            whole_periodic = sc.periodic[a] and hi[a] - lo[a] >= sc.hi[a] - sc.lo[a] - 1e-9 * h
            if cells < BODY_CELLS_MIN - 1e-9 and not whole_periodic:
                thin.append(a)
        if thin:
            sizes = "; ".join(
                f"{hi[a] - lo[a]:.4g} m = {(hi[a] - lo[a]) / h:.3g} cells along {'xyz'[a]} "
                + (
                    f"(bodies[{i}].lo_m[{a}] = {lo[a]:g}, hi_m[{a}] = {hi[a]:g})"
                    if box
                    else f"(from {lo[a]:g} m to {hi[a]:g} m)"
                )
                for a in thin
            )
            least = min(hi[a] - lo[a] for a in thin)
            out.append(
                f"bodies[{i}] is fewer than {BODY_CELLS_MIN} cells of domain.cell_size_m = {h:g} m thick: {sizes}; "
                f"a body so thin is under-resolved (its runout and profile depend on the grid): set "
                f"domain.cell_size_m <= {least / BODY_CELLS_MIN:.3g} m, or make the body thicker"
            )
    locking = _locking_warning(setup)
    if locking:
        out.append(locking)
    dt_req = float(cfg["numerics.dt_s"])
    dt_target = dt_req if dt_req > 0 else float(info["dt_limit_s"])
    what = f"numerics.dt_s = {dt_req:g} s" if dt_req > 0 else f"the stable time step {dt_target:.3g} s"
    t_end, n_frames = float(cfg["time.t_end_s"]), int(cfg["time.n_frames"])
    n_used = sc.n_particles  # (a pipe inflow's pool is stepped only once released: an upper bound)
    est = estimate_run_time_s(n_used, sc.n_steps, dim)
    if dt_target / sc.dt > DT_FORCED_RATIO:
        frames_ok = max(1, int(math.floor(t_end / dt_target)))
        est_ok = estimate_run_time_s(n_used, math.ceil(t_end / dt_target), dim)
        out.append(
            f"time.n_frames = {n_frames} forces dt = {sc.dt:.3g} s, {dt_target / sc.dt:.3g}x below {what}: a frame "
            f"every {t_end / n_frames:.3g} s (time.t_end_s = {t_end:g} s) must be a whole number of steps, so every "
            f"step is a frame; {sc.n_steps} steps, estimated run time {_duration(est)} on a CPU (about "
            f"{_duration(est_ok)} at the stable step): set time.n_frames <= {frames_ok} (a frame at most every dt: "
            "the step is then within 2x of the limit)"
        )
    if sc.n_steps > STEPS_WARN:
        wave = cfg["numerics.viscous_update"] == "maxwell" or info["dt_wave_s"] <= info["dt_viscous_s"]
        if dt_req > 0:
            cause = f"numerics.dt_s = {dt_req:g} s sets the step"
            fix = "raise numerics.dt_s (up to the stable limit), "
        elif dt_target / sc.dt > DT_FORCED_RATIO:
            cause, fix = "time.n_frames sets the step (above)", ""
        elif wave and cfg["numerics.pressure"] != "explicit":
            cause = (
                f"the flow speed v = {float(info['velocity_scale_m_s']):.3g} m/s and the Maxwell shear waves "
                f"(G = {float(info['maxwell_G_pa']):.4g} Pa, c = {float(info['wave_speed_m_s']):.3g} m/s) set the step "
                f"(dt = numerics.cfl h / (c + v) = {info['dt_wave_s']:.3g} s, h = domain.cell_size_m = {h:g} m)"
            )
            fix = ""
        elif wave:
            rho = float(cfg["material.density_kg_m3"])
            kappa = float(cfg["material.bulk_modulus_pa"])
            v = float(info["velocity_scale_m_s"])
            c = float(info["wave_speed_m_s"])
            cause = (
                f"material.bulk_modulus_pa = {kappa:.4g} Pa sets the step through the wave speed c = {c:.3g} m/s "
                f"(wave-speed limit dt = numerics.cfl h / (c + v) = {info['dt_wave_s']:.3g} s, v = {v:.3g} m/s, "
                f"h = domain.cell_size_m = {h:g} m)"
            )
            k_soft = rho * (10.0 * v) ** 2  # Mach 0.1 at the velocity scale (docs/scenarios.md)
            # the grid pressure, where the scene may take it (validation refuses it with these options)
            grid_ok = (
                sc.formulation != "depth-averaged"
                and cfg["numerics.volume_averaging"] == "none"
                and not cfg["numerics.grid_density_cap"]
                and not (sc.decomposition == "slab" and sc.devices > 1)
            )
            fix = (
                'set numerics.pressure = "incompressible" (the step then follows the flow speed; kappa does not '
                "enter), "
                if grid_ok
                else ""
            )
            if k_soft < kappa and v > 0 and c > 10.0 * v:
                depth = _locking_depth(setup)
                g_mag = float(np.linalg.norm(np.asarray(setup.params.gravity, float)))
                locks = depth is not None and rho * g_mag * depth / k_soft < LOCKING_STRAIN  # at Mach 0.1
                fix += (
                    f"lower material.bulk_modulus_pa towards rho (10 v)^2 = {k_soft:.3g} Pa (Mach 0.1 at the velocity "
                    f"scale v = {v:.3g} m/s, weakly compressible; docs/scenarios.md"
                    + ("; this material locks there, see the warning on its hydrostatic strain), " if locks else "), ")
                )
        else:
            cause = (
                f"the viscous limit dt = {info['dt_viscous_s']:.3g} s sets the step (mu_max = "
                f"{info['mu_max_pa_s']:.4g} Pa s, explicit viscous update)"
            )
            fix = 'set numerics.viscous_update = "maxwell" (no viscous limit), lower the law\'s maximum viscosity, '
        out.append(
            f"the run needs {sc.n_steps} steps of dt = {sc.dt:.3g} s to time.t_end_s = {t_end:g} s (more than "
            f"{STEPS_WARN:,}): {cause}; estimated run time {_duration(est)} on a CPU ({sc.n_particles} particles): "
            f"{fix}raise domain.cell_size_m, or shorten time.t_end_s"
        )
    return out


def _locking_depth(setup: Setup) -> float | None:
    """H [m] of the ``LOCKING_STRAIN`` warning, or None where it does not apply.  H is the deepest column of the
    material along gravity: its particles binned by their position across gravity (bins of one cell), each bin's
    extent along gravity plus one particle spacing (a long body on a slope tilted by gravity.slope_deg is as deep
    as its thickness, not its length times the slope).  None for the grid pressure, the depth-averaged formulation,
    J-bar (the explicit step's own anti-locking option, with its overshoot: docs/validation.md), a purely viscous
    law (Newtonian, or a yield-stress law at tau_y = 0), no gravity, and a scene with no material at the start (a
    pipe inflow: its deposit's depth is not known before the run)."""
    cfg, sc = setup.cfg, setup.scene
    if sc.pressure != "explicit" or sc.formulation == "depth-averaged" or cfg["numerics.volume_averaging"] != "none":
        return None
    if not (float(sc.rheology.yield_stress(setup.params.material)) > 0.0 or sc.rheology.internals):
        return None
    g = np.asarray(setup.params.gravity, float)
    gn = float(np.linalg.norm(g))
    act = np.asarray(setup.state.active)
    if gn == 0.0 or not act.any():
        return None
    x = np.asarray(setup.state.x, float)[act]
    down = g / gn
    along = x @ -down
    across = x - np.outer(x @ down, down)  # positions in the plane normal to gravity
    _, col = np.unique(np.floor(across / sc.h).astype(np.int64), axis=0, return_inverse=True)
    col = col.reshape(-1)
    top = np.full(col.max() + 1, -np.inf)
    low = np.full(col.max() + 1, np.inf)
    np.maximum.at(top, col, along)
    np.minimum.at(low, col, along)
    return float(np.max(top - low)) + sc.h / cfg["numerics.ppc"]  # particle centres + half a spacing each end


def _locking_warning(setup: Setup) -> str | None:
    """The ``LOCKING_STRAIN`` warning of ``start_warnings``, or None (``_locking_depth``)."""
    depth = _locking_depth(setup)
    if depth is None:
        return None
    mat = setup.params.material
    rho, kappa = float(mat.rho), float(mat.kappa)
    rho_g_h = rho * float(np.linalg.norm(np.asarray(setup.params.gravity, float))) * depth
    strain = rho_g_h / kappa
    if strain >= LOCKING_STRAIN:
        return None
    return (
        f"material.bulk_modulus_pa = {kappa:.4g} Pa with numerics.pressure = \"explicit\": the material's "
        f"hydrostatic strain rho g H / kappa is {100 * strain:.2g} % (H = {depth:.4g} m, its depth along gravity), "
        f"below {100 * LOCKING_STRAIN:g} %, where the particles' pressure locks a yield-stress or thixotropic material "
        "and the runout depends on kappa (dambreak-lab: 1.282 m at 24 %, 0.647 m at 0.24 %; docs/validation.md, "
        '"Incompressible limit"): set numerics.pressure = "incompressible" (the pressure solved on the grid; kappa '
        f"does not enter), or lower material.bulk_modulus_pa to {rho_g_h / LOCKING_STRAIN:.3g} Pa or less "
        "(weakly compressible)"
    )
