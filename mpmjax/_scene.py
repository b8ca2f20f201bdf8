"""Static (hashable) scene configuration and the time-varying simulation state.

``Scene`` is a frozen dataclass: it is static under ``jit`` (changing it
recompiles), exactly like jax-cfd's ``Grid``.  ``State`` is a NamedTuple of
arrays (a pytree).  Material parameters are a separate traced pytree
(``Params``), so ``grad``/``vmap`` reach them.

Conventions: SI units; the last axis is vertical (y in 2D, z in 3D); 2D is plane
strain, and 2D masses and volumes are per metre of depth (kg/m, m^2).
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from . import _shapes

WALL_KINDS = ("noslip", "slip", "symmetry")
FACE_KINDS = WALL_KINDS + ("periodic", "open")


@dataclasses.dataclass(frozen=True)
class Wall:
    """A planar boundary: nodes with (x - point).normal <= 0 get the condition ``kind``.

    kind: ``noslip`` (v = 0), ``slip`` (no penetration: the normal velocity into the
    wall is removed, separation allowed) or ``symmetry`` (normal velocity zero).
    The normal points into the fluid.  slip_length [m]: a ``noslip`` box face with
    slip_length b > 0 takes the Navier partial-slip law instead (``_boundary.navier_slip``).
    """

    point: tuple[float, ...]
    normal: tuple[float, ...]
    kind: str
    slip_length: float = 0.0


@dataclasses.dataclass(frozen=True)
class Gate:
    """Aging gate: a particle ages only once (x - point).normal > 0 has held (sticky)."""

    point: tuple[float, ...]
    normal: tuple[float, ...]


@dataclasses.dataclass(frozen=True)
class Terrain:
    """A height-map boundary z = z_b(x[, y]) sampled on a regular grid (bilinear between samples).

    Grid nodes with z <= z_b(node) get the condition ``kind`` with the local normal
    n = (-grad z_b, 1)/|.| (pointing into the fluid): ``noslip`` (v = 0), ``slip`` (the
    inward normal velocity is removed) or ``coulomb`` (as slip, and the tangential speed is
    reduced by ``friction`` times the removed normal speed, to zero at most: Coulomb
    friction with coefficient ``friction``, the usual MPM contact form).  Particles below
    the surface are lifted onto it.  ``voellmy`` (depth-averaged formulation only): Coulomb
    friction plus Voellmy's turbulent drag in the basal shear, both coefficients traced
    (``Params.basal``, ``_shallow``); ``friction`` here is the full model's static coefficient.

    origin: first sample position (x0[, y0]) [m]; spacing: sample spacing per horizontal
    axis [m]; heights: z_b samples [m], nested tuples in (x[, y]) order.
    """

    origin: tuple[float, ...]
    spacing: tuple[float, ...]
    heights: tuple
    kind: str
    friction: float = 0.0

    def height(self, xy, xp=np):
        """z_b [m] at horizontal positions ``xy`` (n, dim - 1); clamped outside the map."""
        z = xp.asarray(np.asarray(self.heights, float), dtype=xy.dtype)
        idx, frac = [], []
        for a in range(xy.shape[1]):
            u = (xy[:, a] - self.origin[a]) / self.spacing[a]
            u = xp.clip(u, 0.0, z.shape[a] - 1.0)
            i = xp.clip(xp.floor(u), 0, max(z.shape[a] - 2, 0)).astype(np.int32)
            idx.append(i)
            frac.append(u - i)
        if len(idx) == 1:
            i, f = idx[0], frac[0]
            j = xp.minimum(i + 1, z.shape[0] - 1)
            return z[i] * (1 - f) + z[j] * f
        (i, fi), (k, fk) = (idx[0], frac[0]), (idx[1], frac[1])
        i1, k1 = xp.minimum(i + 1, z.shape[0] - 1), xp.minimum(k + 1, z.shape[1] - 1)
        return (z[i, k] * (1 - fi) + z[i1, k] * fi) * (1 - fk) + (z[i, k1] * (1 - fi) + z[i1, k1] * fi) * fk

    def normal(self, xy, xp=np):
        """Unit normal (n, dim) of the surface at ``xy`` (central differences of ``height``)."""
        comps = []
        for a in range(xy.shape[1]):
            e = np.zeros(xy.shape[1])
            e[a] = 0.5 * self.spacing[a]
            e = xp.asarray(e, dtype=xy.dtype)  # a float64 numpy offset would promote float32 positions under x64
            d = (self.height(xy + e[None, :], xp) - self.height(xy - e[None, :], xp)) / self.spacing[a]
            comps.append(-d)
        comps.append(xp.ones_like(comps[0]))
        n = xp.stack(comps, axis=-1)
        return n / xp.linalg.norm(n, axis=-1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class Inflow:
    """Pipe inflow: a fixed pool of particles, released in layers by a time schedule.

    The pool is the last ``n_layers * n_per_layer`` particles of the buffer; particle
    ``first + k * n_per_layer + j`` is layer k, position j in the cross-section.  Layer k
    starts to leave the pipe at t_k = t_start + k * layer_dt and is switched on in the
    step whose interval [t, t + dt) holds t_k, with its centre at
    point + offsets[j] - direction (thickness/2 + speed (t_k - t)) and velocity
    speed * direction, so consecutive layers are ``thickness`` apart and layer k has fully
    left the pipe at t_k + layer_dt.  Each layer carries Q * layer_dt, the whole pool
    Q (t_stop - t_start).  Until released a pool particle is inactive (zero mass).

    point: centre of the pipe exit [m]; direction: unit vector of the flow;
    speed: Q / A [m/s]; offsets: positions in the cross-section relative to ``point`` [m];
    thickness: layer thickness speed * layer_dt [m]; half_width: half the pipe width
    (2D) or the pipe radius (3D) [m]; pipe_length: length of the pipe end behind the exit
    whose grid nodes are driven at the pipe velocity [m] (see ``_boundary.pipe_nodes``).
    """

    point: tuple[float, ...]
    direction: tuple[float, ...]
    speed: float
    first: int
    n_layers: int
    n_per_layer: int
    layer_dt: float
    t_start: float
    thickness: float
    offsets: tuple[tuple[float, ...], ...]
    half_width: float = 0.0
    pipe_length: float = 0.0

    @property
    def t_stop(self) -> float:
        return self.t_start + self.n_layers * self.layer_dt


@dataclasses.dataclass(frozen=True)
class Scene:
    """Everything static about a run.  Hashable; changing a field recompiles.

    Attributes:
      dim: 2 (plane strain) or 3.
      h: cell size [m].
      lo, hi: physical domain box [m] (walls sit on these faces).
      periodic: per axis, whether the axis is periodic.
      grid_origin: position of node 0 [m] (``lo`` minus the ghost layer).
      grid_shape: number of nodes per axis.
      walls: planar boundaries (faces and inclined planes).
      shape: shape function (see ``_shapes``); lp_cells: GIMP half-width in cells.
      transfer: ``apic`` or ``flip`` (FLIP/PIC blend ``flip_blend``).
      rheology: a model instance from ``_rheology`` (static description).
      shear_measure: ``standard`` (sqrt(2 d':d')) or ``thesis`` (d':d'/4).
      force: ``gradient`` (the stress as a nodal force through grad w) or ``mls`` (the
        stress impulse in APIC's affine momentum, C as the velocity gradient; ``_transfer``).
      viscous_update: ``maxwell`` (exponential Maxwell relaxation, stable for any mu)
        or ``explicit`` (sigma' = 2 mu d', needs dt < rho h^2/(2 d mu)).
      maxwell_G: Maxwell shear modulus [Pa] (numerical regularisation).
      maxwell_rotation: ``jaumann`` or ``lag`` (what the Maxwell update turns with the spin;
        ``_constitutive.deviatoric_update``).
      dt: fixed time step [s]; steps_per_frame, n_frames: the nested scan lengths.
      n_particles: buffer capacity.
      gate: optional aging gate.
      inflow: optional pipe inflow (``Inflow``; its pool is part of the particle buffer).
      terrain: optional height-map boundary (``Terrain``).
      dtype: ``float32`` or ``float64``.
      grid_density_cap: 0 (off) or the tolerance of the grid volume check: J <= (1 + cap) / phi,
        phi the grid-measured packing fraction at the particle (``_transfer.packing_fraction``).
      volume_averaging: ``none`` or ``jbar``: the volume increment of each step averaged through
        the grid (F-bar / J-bar against volumetric locking; ``_transfer`` docstring).
      devices: number of devices one run's particles are split over (``_shard``); 1: no sharding.
      decomposition: with ``devices`` > 1, ``replicated`` (every device holds the whole grid,
        ``_shard``) or ``slab`` (the grid cut into slabs along x, halos exchanged, ``_slab``).
      slab_capacity: with ``slab``, particle slots per device relative to an even share.
      pressure: ``explicit`` (the Tait EOS of each particle's J) or ``incompressible`` (one pressure
        per grid cell solved each step; ``_pressure``).
      void_closure: with ``incompressible``, ``off``, ``position`` (voids closed by moving the
        particles) or ``velocity`` (the deep cells' packing error corrected both ways in the pressure
        solve itself); ``_pressure``, step 4.
      stress_quadrature: ``particles`` (the internal force summed at the particles) or ``corrected`` (the
        stress's smooth part integrated exactly on the grid cells, the particles' sum only the remainder;
        ``_quadrature``; experimental).
      wall_yield: ``cell`` or ``wall`` (where the row of particles on a no-slip box face tests its
        yield stress; ``_wall_yield``).
      cell_shear: ``uniform`` or ``series`` (how a cell's particles share its shear across the bed;
        ``_cell_shear``).
      formulation: ``full`` (the MPM of this module's conventions, in ``dim`` dimensions) or
        ``depth-averaged`` (particles are columns on the plan of the first dim - 1 axes: ``_shallow``).
      bed_curvature: depth-averaged only: ``centrifugal`` (the bed's curvature u.K.u in the columns'
        bed-normal gravity) or ``none`` (``_shallow``, step 2).
      split_levels, split_min_volume: depth-averaged only: columns sparser than the grid are split
        (``_split``) down to ``split_min_volume`` (a column's volume: m^3 in 3D, m^2 per metre in 2D);
        0 levels: off.
      depth_layers: depth-averaged only: layers across a column's depth that carry the law's internal
        variables (1: one value per column; ``_basal.layered``).
      internal_friction_deg: depth-averaged only: the internal friction angle of a granular column, which scales
        its hydrostatic pressure by Savage & Hutter's earth-pressure coefficient (``_earth_pressure``); None: k = 1.
    """

    dim: int
    h: float
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    periodic: tuple[bool, ...]
    grid_origin: tuple[float, ...]
    grid_shape: tuple[int, ...]
    walls: tuple[Wall, ...]
    shape: str
    lp_cells: float
    transfer: str
    flip_blend: float
    rheology: Any
    shear_measure: str
    viscous_update: str
    maxwell_G: float
    dt: float
    steps_per_frame: int
    n_frames: int
    n_particles: int
    gate: Gate | None = None
    dtype: str = "float32"
    inflow: Inflow | None = None
    terrain: Terrain | None = None
    grid_density_cap: float = 0.0
    volume_averaging: str = "none"
    devices: int = 1
    decomposition: str = "replicated"
    slab_capacity: float = 1.5
    force: str = "gradient"
    pressure: str = "explicit"
    void_closure: str = "off"
    stress_quadrature: str = "particles"
    maxwell_rotation: str = "lag"
    formulation: str = "full"
    wall_yield: str = "wall"
    cell_shear: str = "uniform"
    bed_curvature: str = "centrifugal"
    split_levels: int = 0
    depth_layers: int = 1
    internal_friction_deg: float | None = None
    split_min_volume: float = 0.0

    @property
    def n_nodes(self) -> int:
        return int(np.prod(self.grid_shape))

    @property
    def t_end(self) -> float:
        return self.dt * self.steps_per_frame * self.n_frames

    @property
    def n_steps(self) -> int:
        return self.steps_per_frame * self.n_frames

    def node_positions(self) -> np.ndarray:
        """Node coordinates [m], shape (n_nodes, dim), in the flat (C) order of the grid."""
        axes = [self.grid_origin[d] + self.h * np.arange(self.grid_shape[d]) for d in range(self.dim)]
        mesh = np.meshgrid(*axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=-1)

    def replace(self, **kw) -> Scene:
        return dataclasses.replace(self, **kw)


def box_wall_nodes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the node indices (as floats) of the box faces that are walls: (lo, hi), each
    of shape (dim,), -inf / +inf where the face is no wall (open, periodic).

    A box wall is a wall (kind noslip, slip or symmetry) on a face of the domain box: normal
    along an axis and point on ``lo`` or ``hi``.  The boundary-modified B-splines
    (``_shapes.BOUNDARY_MODIFIED``) are modified at these faces only; extra planes
    (``boundary.planes``) and terrain keep the plain B-spline.  The box faces lie on nodes
    (the domain is a whole number of cells)."""
    lo = np.full(scene.dim, -np.inf)
    hi = np.full(scene.dim, np.inf)
    for wall in scene.walls:
        nrm = np.asarray(wall.normal, float)
        a = int(np.argmax(np.abs(nrm)))
        if np.count_nonzero(nrm) != 1 or scene.periodic[a]:
            continue
        node = (wall.point[a] - scene.grid_origin[a]) / scene.h
        if nrm[a] > 0 and abs(wall.point[a] - scene.lo[a]) <= 1e-9 * scene.h:
            lo[a] = float(np.round(node))
        elif nrm[a] < 0 and abs(wall.point[a] - scene.hi[a]) <= 1e-9 * scene.h:
            hi[a] = float(np.round(node))
    return lo, hi


def ghost_cells(shape: str) -> int:
    """Ghost layer outside each non-periodic face: the stencil of a particle up to one
    cell behind a wall must still fit in the grid."""
    return int(np.ceil(_shapes.SUPPORT[shape])) + 1


class Basal(NamedTuple):
    """Traced basal friction of the depth-averaged formulation on a ``coulomb`` or ``voellmy``
    terrain (``_shallow``): the Coulomb coefficient [-] (``terrain.friction``) and Voellmy's
    turbulence coefficient xi [m/s^2] (``terrain.turbulence_m_s2``; inf on a ``coulomb`` terrain)."""

    friction: jnp.ndarray
    turbulence: jnp.ndarray


class Params(NamedTuple):
    """Traced parameters: the rheology's NamedTuple, the gravity vector [m/s^2] and, for a depth-averaged
    scene on a ``coulomb`` or ``voellmy`` terrain, its ``Basal`` friction (None otherwise), so that
    ``jax.grad``, ``vmap`` and a fit can take the friction too."""

    material: Any
    gravity: jnp.ndarray
    basal: Any = None


class State(NamedTuple):
    """Particle state (arrays of leading dimension n_particles unless stated).

    x: positions [m] (n, dim); v: velocities [m/s] (n, dim);
    C: APIC affine velocity matrix [1/s] (n, dim, dim);
    tau: deviatoric (extra) stress [Pa] (n, dim, dim);
    J: volume ratio det F [-] (n,); vol0: initial volume [m^3, 2D: m^2] (n,);
    mu: effective viscosity of the last step [Pa s] (n,);
    internal: rheology internal variables, e.g. {"lam": (n,)} for Coussot;
    active: bool (n,): inactive particles carry no mass;
    gate: bool (n,): has passed the aging gate;
    t: time [s] (scalar); n_lost: particles lost so far (scalar int);
    p: with ``numerics.pressure = "incompressible"``, the last step's pressure per grid
    cell [Pa], shape (1, *grid_shape) (the leading 1 keeps it apart from the particle arrays), the
    next solve's start; None otherwise (``_pressure``).
    """

    x: jnp.ndarray
    v: jnp.ndarray
    C: jnp.ndarray
    tau: jnp.ndarray
    J: jnp.ndarray
    vol0: jnp.ndarray
    mu: jnp.ndarray
    internal: dict
    active: jnp.ndarray
    gate: jnp.ndarray
    t: jnp.ndarray
    n_lost: jnp.ndarray
    p: jnp.ndarray | None = None


def next_time(t, dt):
    """The time after the step that starts at ``t``: (round(t / dt) + 1) dt [s].

    The clock is the step count times dt, not a running sum: adding a float32 dt 270 times
    to reach 0.5 s at dt = 1/540 s lands 15 ulp (9e-7 s) off, and the error grows with the
    step count, so frame times, release windows and restarts would drift.  Every step starts
    at a multiple of dt (runs start at 0, checkpoints store such a time), so the rounding
    recovers the step count exactly.
    """
    return (jnp.round(t / dt) + 1.0) * dt


def _fresh_material(scene: Scene, params: Params, n: int, dt):
    """The rheology's initial internal fields (e.g. lambda = lambda0) and the viscosity at rest
    of ``n`` fresh particles, in the dtype ``dt``."""
    internal = scene.rheology.init_internal(params.material, n)
    internal = {k: jnp.asarray(a, dt) for k, a in internal.items()}
    mu0 = scene.rheology.viscosity(params.material, jnp.zeros((n,), dt), internal, 0.0, False)[0]
    if scene.depth_layers > 1:  # the same value in every layer across the depth (``_basal.layered``)
        internal = {k: jnp.broadcast_to(a[:, None], (n, scene.depth_layers)) for k, a in internal.items()}
    return internal, mu0


def restate(state: State, scene: Scene, params: Params) -> State:
    """``state`` with the rheology's internal fields and the viscosity rebuilt from ``params``
    as ``init_state`` makes them, so that parameters that enter only through the initial
    state (lambda0) are traced.  Everything else (positions, active mask, inflow pool) is kept."""
    n = state.x.shape[0]
    dt = state.x.dtype
    internal, mu0 = _fresh_material(scene, params, n, dt)
    return state._replace(internal=internal, mu=jnp.asarray(mu0, dt))


def init_state(scene: Scene, params: Params, x, vol0, v=None, active=None) -> State:
    """A state at rest (J = 1, zero stress) from particle positions and volumes."""
    dt = jnp.dtype(scene.dtype)
    x = jnp.asarray(x, dt)
    n, dim = x.shape
    if n != scene.n_particles or dim != scene.dim:
        raise ValueError(f"positions have shape {x.shape}; the scene expects ({scene.n_particles}, {scene.dim})")
    v = jnp.zeros_like(x) if v is None else jnp.asarray(v, dt)
    active = jnp.ones((n,), bool) if active is None else jnp.asarray(active, bool)
    internal, mu0 = _fresh_material(scene, params, n, dt)
    return State(
        x=x,
        v=v,
        C=jnp.zeros((n, dim, dim), dt),
        tau=jnp.zeros((n, dim, dim), dt),
        J=jnp.ones((n,), dt),
        vol0=jnp.asarray(vol0, dt) * jnp.ones((n,), dt),
        mu=jnp.asarray(mu0, dt),
        internal=internal,
        active=active,
        gate=jnp.zeros((n,), bool) if scene.gate is not None else jnp.ones((n,), bool),
        t=jnp.zeros((), dt),
        n_lost=jnp.zeros((), jnp.int32),
        p=None if scene.pressure == "explicit" else jnp.zeros((1,) + tuple(scene.grid_shape), dt),
    )
