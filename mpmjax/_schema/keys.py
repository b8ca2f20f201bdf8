"""The ``Key`` spec of one scene key, ``SceneError``, and the fixed keys (every section but
``material``, whose keys the rheology laws declare: ``table`` puts them together)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from .. import _cell_shear, _constitutive, _quadrature, _shapes
from .._scene import FACE_KINDS


class SceneError(ValueError):
    """Invalid scene input; the message names the key, the value and the allowed range."""


@dataclasses.dataclass(frozen=True)
class Key:
    type: Any  # float, int, str, bool, "vec" (list of floats of length dim), "table-list"
    default: Any
    unit: str
    doc: str
    lo: float | None = None  # inclusive lower bound
    lo_open: bool = False  # True: value must be > lo
    hi: float | None = None
    choices: tuple | None = None
    only_3d: bool = False  # meaningful in 3D scenes only: setting it in a 2D scene is an error


_REQ = object()  # marker: required

_HEAD: dict[str, Key] = {
    "name": Key(str, "unnamed", "-", "Scene name, written to the outputs."),
    "description": Key(str, "", "-", "Free text describing the scene and its source."),
    "model.formulation": Key(
        str,
        "full",
        "-",
        "Which equations the particles follow. full: the MPM continuum in domain.dim dimensions (the thesis's "
        "model). depth-averaged: shallow flow on the plan of the first domain.dim - 1 axes (a profile along x in 2D, "
        "the map in 3D): each particle is a column of the material carrying its volume, depth-averaged velocity and "
        "the law's internal variables; depth from the particles' volume on the plan grid, hydrostatic pressure, "
        "basal shear from the law through a depth-averaged closure (docs/depth-averaged.md). For field scenes the "
        "grid cannot resolve in depth. Not with boundary.planes, periodic faces, a pipe inflow, an aging gate, "
        "numerics.devices > 1, boundary-modified shapes, or the full model's volume and pressure options.",
        choices=("full", "depth-averaged"),
    ),
    "model.bed_curvature": Key(
        str,
        "centrifugal",
        "-",
        "Depth-averaged formulation only: the bed's curvature in the columns' bed-normal gravity. centrifugal: "
        "g_n + u.K.u (K the terrain's Hessian, u the plan velocity; a column following a concave bed presses "
        "harder on it, a convex one lighter, never below zero), in the bed-slope force, the hydrostatic pressure "
        "and the Coulomb / Voellmy normal stress, as Savage-Hutter type models on curved beds do; none: gravity "
        "alone (the form before 2026-12-05). No effect on a plane bed.",
        choices=("centrifugal", "none"),
    ),
    "model.internal_friction_deg": Key(
        float,
        None,
        "deg",
        "Depth-averaged formulation on a coulomb or voellmy terrain only: the internal friction angle phi of a "
        "granular (Mohr-Coulomb) material, which scales the columns' hydrostatic pressure by Savage & Hutter's "
        "earth-pressure coefficient (1989): k_act/pass = 2 / cos^2(phi) (1 -/+ sqrt(1 - cos^2(phi) / "
        "cos^2(delta))) - 1, tan(delta) = terrain.friction, active where a column extends, passive where it is "
        "compressed (isotropic in the plan). At least the bed's friction angle. Unset: k = 1, a fluid's "
        "hydrostatic pressure (tailings, muds). The wave speed and so the time step take Rankine's passive "
        "(1 + sin phi) / (1 - sin phi). docs/earth-pressure.md.",
        lo=0.0,
        lo_open=True,
        hi=60.0,
    ),
    "domain.dim": Key(int, 2, "-", "Dimension: 2 (plane strain, per metre of depth) or 3.", choices=(2, 3)),
    "domain.lo_m": Key("vec", _REQ, "m", "Lower corner of the domain box (walls lie on its faces)."),
    "domain.hi_m": Key("vec", _REQ, "m", "Upper corner of the domain box."),
    "domain.cell_size_m": Key(float, _REQ, "m", "Grid cell size h.", lo=0.0, lo_open=True),
    "boundary.x_lo": Key(str, "slip", "-", "Condition on the x-min face.", choices=FACE_KINDS),
    "boundary.x_hi": Key(str, "slip", "-", "Condition on the x-max face.", choices=FACE_KINDS),
    "boundary.y_lo": Key(str, "noslip", "-", "Condition on the y-min face.", choices=FACE_KINDS),
    "boundary.y_hi": Key(str, "slip", "-", "Condition on the y-max face.", choices=FACE_KINDS),
    "boundary.z_lo": Key(str, "noslip", "-", "Condition on the z-min face (3D).", choices=FACE_KINDS, only_3d=True),
    "boundary.z_hi": Key(str, "slip", "-", "Condition on the z-max face (3D).", choices=FACE_KINDS, only_3d=True),
    "boundary.slip_length_m": Key(
        float,
        0.0,
        "m",
        "Navier slip length b on the noslip faces of the domain box (not on extra planes or terrain): "
        "0 is no slip (v = 0 at the wall); b > 0 lets the material slide along the wall at u_wall = b du/dn, "
        "the gradient taken over the first cell (docs/validation.md, 'Depth resolution', has what it "
        "measured; experimental: it changes the bed's physics, no-slip is the thesis's condition).",
        lo=0.0,
        hi=1e3,
    ),
    "boundary.planes": Key(
        "table-list",
        [],
        "-",
        "Extra planar walls, e.g. an inclined base: a list of tables with point_m (vec, m), "
        "normal (vec, pointing into the fluid) and type (noslip, slip, symmetry).",
    ),
    "numerics.shape": Key(
        str,
        "gimp",
        "-",
        "Shape function (gimp: the thesis's choice; see docs/validation.md for the measured accuracy of each). "
        "quadratic_bm / cubic_bm: B-splines modified at the box walls (noslip, slip, symmetry faces) so that they "
        "interpolate there and have no ghost nodes; extra planes and terrain are not modified.",
        choices=tuple(_shapes.STENCIL),
    ),
    "numerics.transfer": Key(
        str, "apic", "-", "Particle-grid transfer: APIC or a FLIP/PIC blend.", choices=("apic", "flip")
    ),
    "numerics.force": Key(
        str,
        "gradient",
        "-",
        "How the stress reaches the grid. gradient: as a nodal force f_i = -sum V sigma grad w_ip (any shape "
        "function). mls: EXPERIMENTAL, MLS-MPM (Hu et al. 2018): the impulse -dt V sigma D^-1 folded into APIC's "
        "affine momentum and C used as the velocity gradient; 0.64x the step's CPU in docs/performance.md's "
        "ablation; needs transfer = apic and shape = quadratic or cubic; not validated against the records.",
        choices=("gradient", "mls"),
    ),
    "numerics.flip_blend": Key(
        float, 0.95, "-", "FLIP fraction of the FLIP/PIC blend (transfer = flip).", lo=0.0, hi=1.0
    ),
    "numerics.ppc": Key(
        int,
        3,
        "-",
        "Particles per cell per axis for seeded bodies. 3 (the default) is the cheapest count at which a yield-stress "
        "deposit stays packed as its J says; at 2 it packs up to 14 % denser and stops short (the lab dam break: "
        "1.19 m against 1.28 m at h = 1 cm), at 1 it stops 10-30 % short (docs/validation.md, convergence benchmark; "
        "benchmarks/accuracy/ppc_probe.md).",
        lo=1,
        hi=8,
    ),
    "numerics.cfl": Key(
        float, 0.4, "-", "Safety factor f of the wave-speed limit dt = f h / (c + |v|).", lo=0.0, lo_open=True, hi=1.0
    ),
    "numerics.viscous_safety": Key(
        float,
        0.5,
        "-",
        "Safety factor of the viscous limit dt = f rho h^2/(2 d mu_max) (explicit update only).",
        lo=0.0,
        lo_open=True,
        hi=1.0,
    ),
    "numerics.viscous_update": Key(
        str,
        "maxwell",
        "-",
        "Deviatoric stress update: exponential Maxwell (stable for any mu) or explicit.",
        choices=("maxwell", "explicit"),
    ),
    "numerics.maxwell_rotation": Key(
        str,
        "lag",
        "-",
        "What the Maxwell update turns with the material's spin W. lag: only the stored stress's departure from the "
        "viscous stress 2 mu d' (steady shear exact; a rigid plug turns as with jaumann). jaumann (the default "
        "until 2026-12-03): the whole stored stress (objective, but in steady shear it gives mu gamma_dot / "
        "(1 + Wi^2), Wi = tau/G: Poiseuille 2.7 % fast at the incompressible default G; docs/incompressible.md).",
        choices=("jaumann", "lag"),
    ),
    "numerics.maxwell_shear_modulus_pa": Key(
        float,
        0.0,
        "Pa",
        "Maxwell regularisation modulus G; 0 means G = bulk modulus, or with numerics.pressure = incompressible "
        f"G = max(rho v^2, {_constitutive.MAXWELL_YIELD_FACTOR:g} tau_y), v the velocity scale of the time step (the "
        "shear waves no faster than the flow) and tau_y the law's yield stress (so that material held at its yield "
        f"stress strains at most {100 / _constitutive.MAXWELL_YIELD_FACTOR:g} % elastically). A deposit at its yield "
        "limit deforms by about 2-3 tau_y/G of its size (a block that must stand moves +10 % at 20 tau_y, +3.4 % at "
        "100, +0.6 % at 400: validate's slump-held-B0.5-a1); a larger G costs steps as sqrt(G).",
        lo=0.0,
    ),
    "numerics.velocity_scale_m_s": Key(
        float,
        0.0,
        "m/s",
        "Speed |v| in the wave-speed limit; 0 means sqrt(2 g H) + max initial speed, "
        "H the height span of the material.",
        lo=0.0,
    ),
    "numerics.split_levels": Key(
        int,
        3,
        "-",
        "Depth-averaged formulation only: column splitting. A column whose depth on the grid is below its volume "
        "over the plan cell (its neighbours more than a cell away: a stretching tip) is split into 2^k columns "
        "(k the plan's axes) of equal volume at its footprint's quarter points, so that the grid resolves the thin "
        "tip of a flow and of its deposit (an arrested deposit whose tip columns spread apart keeps creeping "
        "otherwise, and its sensitivities are wrong); at most this many halvings per plan axis below the median "
        "seeded column. 0: off. The default 3 since 2026-12-07 with numerics.split_pool 3 (1 and 1 before, 0 "
        "before 2026-12-06): at 2 columns a cell mpmjax validate's da-huppert reads -5.5 % with 1 and 1 (the pool "
        "spent in the first 0.5 s) and -1.7 % with 3 and 3, and dambreak-lab as columns stops at 1.196 m with 1 "
        "and 1, 1.347 m (its resolved runout) with 3 and 3. The full model ignores the default and refuses any "
        "other value but 0. docs/depth-averaged.md, Column splitting.",
        lo=0,
        hi=12,
    ),
    "numerics.depth_layers": Key(
        int,
        16,
        "-",
        "Depth-averaged formulation only: layers across each column's depth that carry the law's internal "
        "variables (Coussot's structure lambda). K > 1: K layers graded towards the bed, each sheared at its own "
        "rate under the shallow layer's linear stress, the basal shear from their viscosities in series (Hewitt & "
        "Balmforth's thixotropic lubrication, layered): a band that breaks down at the bed under an aging plug. 1: "
        "one value per column, advanced at the Newtonian profile's bed rate 3 U / h, which cannot hold that band: "
        "mpmjax validate's coussot-film-da (a 5 cm lab layer from rest against the same layer solved across its "
        "depth) reads +75 % at twice the flow curve's minimum stress and +348 % at 1.5 times it with 1, -0.02 % "
        "and -3.2 % with 16 (8: -19 % at 1.5; 32: -0.3 %). The default 16 since 2026-12-07 (1 before); it costs "
        "1.1-1.25x the loop of the field scenes and moves their fronts by about -1 %. A no-op for laws without "
        "internal variables or with a yield stress; the full model ignores the default and refuses any value but "
        "1. docs/depth-layers.md.",
        lo=1,
        hi=256,
    ),
    "numerics.split_pool": Key(
        float,
        3.0,
        "-",
        "With numerics.split_levels > 0: spare column slots for the children, as a multiple of the seeded columns "
        "(each costs a step like a column, used or not, in fits and sweeps; mpmjax run steps only those in use; "
        "when they run out, splitting stops and the run says so). "
        "The default 3 since 2026-12-07 (1 before): the stretching current of mpmjax validate's da-huppert spent a "
        "pool of 1 in its first 0.5 s, and dambreak-lab as columns uses 2.7 (163 of 180 slots) to resolve its "
        "tip; a fit of a run that splits nothing still pays for them (coussot-film-da's loop 1.9-2.6x). "
        "field-breach-da pins 1 for its 5-minute budget.",
        lo=0.0,
        lo_open=True,
        hi=64.0,
    ),
    "numerics.dt_s": Key(
        float,
        0.0,
        "s",
        "Fixed time step; 0 means from the stability limits. A value above the limit is an error.",
        lo=0.0,
    ),
    "numerics.grid_density_cap": Key(
        float,
        0.0,
        "-",
        "Grid volume check (off by default): a particle's J is capped at (1 + cap) / phi, phi "
        "the packing of reference volume measured on the grid (nodal mass / (rho h^d), wall-corrected) at the "
        "particle. It keeps deposits at the volume their J says: thin pipe-fed deposits, and yield-stress deposits "
        "at low ppc, whose overpacking makes their runout depend on ppc (Bingham slump at 16 cells, cap 0.05: "
        "ppc 2 / 3 within 0.2 % of the exact front, against -2.4 / -0.5 % without). It lengthens dambreak-lab "
        "(1.37 m instead of 1.19 m at h = 0.01 m); see benchmarks/accuracy/ppc_probe.md and docs/scenarios.md, "
        "overpacking.",
        lo=0.0,
        hi=1.0,
    ),
    "numerics.volume_averaging": Key(
        str,
        "none",
        "-",
        "Volumetric anti-locking (off by default): jbar replaces each particle's volume change per step by its "
        "mass-weighted average through the grid (F-bar / J-bar, Zhao, Jiang & Choo 2023), so a stiff (nearly "
        "incompressible) material flows instead of locking; it also calms J in a deposit's bottom row, not the "
        "J noise above it. About 30 % more per step. Experimental: at fine grids it runs too far (water column "
        "+55 % at h = 2.5 mm, Bingham slump +7 % at 32 cells; docs/validation.md, convergence benchmark).",
        choices=("none", "jbar"),
    ),
    "numerics.pressure": Key(
        str,
        "incompressible",
        "-",
        "Where the pressure comes from. incompressible (the default since 2026-12-08): one pressure per grid cell "
        "solved every step so that the flow keeps its volume (fractional step, conjugate gradients; kappa is not "
        "used); the time step then follows the flow speed and the Maxwell shear waves (docs/incompressible.md). "
        "explicit: each particle's J through the Tait EOS with material.bulk_modulus_pa (the thesis's weakly "
        "compressible MPM: the time step follows its sound speed, and a stiff kappa locks); the built-in scenes "
        "whose deposits are a few cells deep keep it (docs/incompressible-default.md).",
        choices=("explicit", "incompressible"),
    ),
    "numerics.void_closure": Key(
        str,
        "off",
        "-",
        "With numerics.pressure = incompressible, how voids inside the material are closed. off: only cells packed "
        "denser than the material are corrected, so the particles can spread (the lab deposit packs at 0.86 at "
        "h = 1 cm and runs 11 % further). position (experimental): every 4th step a second solve moves the particles, "
        "not their velocity, into the deep cells packed below 0.99 (lab packing 0.96), but yield-stress deposits at "
        "their limit then creep on fine grids (a slump at 32 cells over its height: 23 % past its static front, "
        "still moving; docs/incompressible.md, Voids). velocity (experimental): the pressure solve itself corrects "
        "the deep cells' packing both ways beyond 1 % (packed below 0.99 or above 1.01), with no second solve "
        "(lab packing 0.94, runout 1.275 m instead of 1.413; the inertial slump -1.0 % instead of +6.5 %), but "
        "the yield-stress slumps then stop short at 16 cells over their height (-12 % against -3.4 % with off, "
        "which dilation partly flattered; -6 % at 32 cells).",
        choices=("off", "position", "velocity"),
    ),
    "numerics.stress_quadrature": Key(
        str,
        "particles",
        "-",
        "How the internal force integrates the stress. particles: at the particles, -sum V sigma grad w (MPM's "
        "own). Once shear has disordered the particles, a stress that is uniform along the flow gives a spurious "
        "force there, and a layer sheared steadily over its bed leaves its steady flow after a bed shear strain of "
        "about 25-35 with the grid pressure (50-70 with the particles' pressure). corrected (experimental): the "
        "stress's smooth part (the particles' stress averaged on the nodes) integrated exactly over the deep "
        "material cells, the particles' sum only the remainder: a film on an incline then holds its exact speed "
        "past a bed strain of 50, but the lab dam break costs 1.6x the loop CPU and runs 5 % shorter "
        "(docs/incompressible-default.md, Long shear); with the particles' pressure a film holds -0.25 % to a bed "
        "strain of 98 (-13.6 % without) but the inertial slump stops 7.4 % short (1.8 % without). Needs the gimp or linear shape, the gradient force and, over several "
        "devices, the replicated decomposition.",
        choices=_quadrature.MODES,
    ),
    "numerics.wall_yield": Key(
        str,
        "wall",
        "-",
        "Where the particles next to an axis-aligned no-slip box face test their yield stress. cell: as every "
        "particle, at the rate of its cell row, so the row next to the wall yields when the stress at its centre, "
        "h/2 above the wall, reaches tau_y (a deposit stops on a bed raised by h/2: an error of h/(2H) in the "
        "stopping stress, first order in h). wall: that row's flow rule integrated across the row with the stress "
        "gradient measured there, so it yields when the wall's own stress reaches tau_y (Bingham and "
        "Herschel-Bulkley; other laws unchanged; a near-yield layer 5 cells deep: -97 % with cell, -1.6 % with "
        "wall; docs/wall-yield.md). The default since 2026-12-05 (cell before); it needs the gimp or linear shape, "
        "the standard shear measure and the full formulation, and falls back to cell where a scene has another.",
        choices=("cell", "wall"),
    ),
    "numerics.cell_shear": Key(
        str,
        "uniform",
        "-",
        "How the particles of one cell share its shear across the bed (the last axis, where a no-slip box face "
        "lies across it). uniform: each at the cell's one rate (in parallel; the cell's stress the particles' mean). "
        "series: stacked across the bed, each at its own rate with the shear stress continuous between them, the "
        "cell's mean rate the grid's, and the stress gradient measured from the neighbouring cells: a shear band "
        "can then end inside a cell. Acts on laws with internal variables (Coussot), whose particles differ at one "
        "rate; a no-op elsewhere. A Coussot film 5 cm deep at twice its flow curve's minimum stress: -15.5 / "
        "+12.5 / -0.1 % in its mean speed at 5 / 10 / 20 cells across it with uniform, +2.3 / +3.8 / +0.1 % with "
        "series; the lab dam break's runout +0.6 % at h = 1 cm (docs/coussot-film.md). Needs the gimp or linear shape, the standard "
        "shear measure and the full formulation.",
        choices=_cell_shear.MODES,
    ),
    "numerics.dtype": Key(str, "float32", "-", "Floating-point precision.", choices=("float32", "float64")),
    "numerics.devices": Key(
        int,
        1,
        "-",
        "Devices one run is split over (mpmjax run --devices): the particles are divided among them, and the grid is "
        "shared as numerics.decomposition says. On a CPU these are host devices, one per core. Same results as one "
        "device to float rounding. Not with a pipe inflow yet. "
        'Measured speed-up: docs/performance.md, "One simulation across devices".',
        lo=1,
        hi=1024,
    ),
    "numerics.decomposition": Key(
        str,
        "replicated",
        "-",
        "How a run split over numerics.devices > 1 shares the grid: replicated (every device holds the whole grid; "
        "the grids are summed every step) or slab (the grid cut into slabs along x, one per device, each holding its "
        "slab plus a halo of 2-3 node planes exchanged with its neighbours; particles move between devices with "
        "their slab, rebalanced every 32 steps). Slab: not with a periodic x axis or Navier slip on x walls; it "
        "replaces the whole-grid sum by halo exchange (meant for many GPUs) but does not cut grid memory, and on 2 "
        'CPU cores it is slower than one device (0.6-0.9x). Measured: docs/performance.md, "Slabs with halo '
        'exchange".',
        choices=("replicated", "slab"),
    ),
    "numerics.slab_capacity": Key(
        float,
        1.5,
        "-",
        "Particle slots per device with numerics.decomposition = slab, as a multiple of an even share (particles / "
        "devices): room for particles that crowd into one slab between rebalancings. A particle that finds no slot "
        "is dropped and counted as lost, which stops mpmjax run with a hint to raise this. Each step costs in "
        "proportion to the slots (1.25: no particle lost on the built-in dam breaks tried, 7-17 % faster).",
        lo=1.0,
        hi=1024.0,
    ),
    "time.t_end_s": Key(float, _REQ, "s", "Simulated time.", lo=0.0, lo_open=True),
    "time.n_frames": Key(int, 30, "-", "Number of saved frames (outer scan length).", lo=1, hi=100000),
}

_TAIL: dict[str, Key] = {
    "gravity.g_m_s2": Key(float, 9.81, "m/s^2", "Magnitude of gravity (acts along -last axis before tilting).", lo=0.0),
    "gravity.slope_deg": Key(
        float,
        0.0,
        "deg",
        "Tilt of gravity about the vertical-x plane: the base slopes down towards +x by this angle.",
        lo=-89.0,
        hi=89.0,
    ),
    "gravity.transverse_slope_deg": Key(
        float, 0.0, "deg", "3D only: tilt towards +y.", lo=-89.0, hi=89.0, only_3d=True
    ),
    "bodies": Key(
        "table-list",
        [],
        "-",
        "Material bodies: a list of tables ([[bodies]]), each with a type (box, cylinder, cone, polygon, mesh) and the "
        "keys of its type, listed below as bodies[].KEY. At least one body, an inflow or a release is required. "
        "Shaped bodies are seeded on the domain's particle lattice, each particle inside the shape holding the "
        "lattice volume (h / ppc)^dim; a shaped body may extend past a symmetry face of the domain only if its "
        "axis lies on that face (a half or quarter model), and must otherwise lie inside the domain.",
    ),
    "gate.point_m": Key("vec", None, "m", "Aging gate: a point on the plane (optional)."),
    "gate.normal": Key("vec", None, "-", "Aging gate: normal; material ages once (x - point).normal > 0."),
    "inflow.point_m": Key("vec", None, "m", "Pipe inflow: centre of the pipe exit (optional; no inflow without it)."),
    "inflow.direction": Key("vec", None, "-", "Pipe inflow: flow direction at the exit (normalised)."),
    "inflow.width_m": Key(
        float, 0.1, "m", "Pipe inflow: cross-section, the width in 2D, the diameter in 3D.", lo=0.0, lo_open=True
    ),
    "inflow.flow_rate_m3_s": Key(
        float,
        0.001,
        "m^3/s (2D: m^2/s)",
        "Pipe inflow: volumetric flow rate Q (2D: per metre of depth).",
        lo=0.0,
        lo_open=True,
    ),
    "inflow.t_start_s": Key(float, 0.0, "s", "Pipe inflow: start time.", lo=0.0),
    "inflow.t_stop_s": Key(float, math.nan, "s", "Pipe inflow: stop time; default: time.t_end_s.", lo=0.0),
    "inflow.aging_gate": Key(
        bool,
        True,
        "-",
        "Pipe inflow: released material ages only once past the exit plane (an aging gate there; "
        "it cannot be combined with gate.point_m).",
    ),
    "terrain.type": Key(
        str,
        "none",
        "-",
        "Height-map boundary z = z_b(x[, y]) (bilinear between samples; nodes below it get the condition): "
        "none, noslip, slip, coulomb (slip with Coulomb friction) or voellmy (depth-averaged formulation only: "
        "the Coulomb friction terrain.friction plus the turbulent drag rho g u^2 / terrain.turbulence_m_s2, "
        "added to the law's basal shear).",
        choices=("none", "noslip", "slip", "coulomb", "voellmy"),
    ),
    "terrain.heights_m": Key(
        "table-list",
        None,
        "m",
        "Terrain samples z_b: a list of numbers along x (2D) or a list of rows along x, each a list along y "
        "(3D). Alternative: terrain.csv.",
    ),
    "terrain.csv": Key(
        str,
        "",
        "-",
        "CSV file of terrain samples z_b [m] (rows along x; in 3D columns along y; # comments), "
        "relative to the scene file.",
    ),
    "terrain.origin_m": Key("vec", None, "m", "Terrain: position of the first sample (x0[, y0]); default domain.lo_m."),
    "terrain.spacing_m": Key(
        float, 1.0, "m", "Terrain: sample spacing along each horizontal axis.", lo=0.0, lo_open=True
    ),
    "terrain.friction": Key(
        float, 0.0, "-", "Terrain: Coulomb friction coefficient (type coulomb or voellmy).", lo=0.0, hi=10.0
    ),
    "terrain.turbulence_m_s2": Key(
        float,
        200.0,
        "m/s^2",
        "Terrain type voellmy: the turbulence coefficient xi of Voellmy's basal drag rho g u^2 / xi (RAMMS's "
        "starting value for debris flows: 200; larger is less drag).",
        lo=0.0,
        lo_open=True,
        hi=1e6,
    ),
    "terrain.dem": Key(
        str,
        "",
        "-",
        "DEM raster of the terrain elevation z_b [m], relative to the scene file (3D only): an ESRI ASCII grid "
        "(.asc, CRS from a .prj beside it) or a GeoTIFF (.tif, read with rasterio). Pixel values are elevations at "
        "pixel centres; no-data pixels under the domain are an error. Alternative to terrain.heights_m and "
        "terrain.csv: it sets the samples, terrain.origin_m and terrain.spacing_m. Scene coordinates = map "
        "coordinates - terrain.map_origin_m; z is the elevation in both.",
    ),
    "terrain.crop_map_m": Key(
        "vec",
        None,
        "m",
        "DEM crop window [xmin, ymin, xmax, ymax] in map coordinates (must lie inside the raster; the domain must "
        "lie inside it); default: the whole raster.",
    ),
    "terrain.map_origin_m": Key(
        "vec",
        None,
        "m",
        "Map coordinates (x, y) of the scene origin: scene = map - map_origin. Default with terrain.dem: the "
        "lower-left corner of the crop window, or of the raster; without a DEM: (0, 0) (map = scene).",
    ),
    "terrain.resample": Key(
        str,
        "none",
        "-",
        "DEM resampling: none (samples at the pixel centres; square pixels needed) or bilinear (the raster "
        "interpolated bilinearly onto the grid nodes of the domain, spacing domain.cell_size_m).",
        choices=("none", "bilinear"),
    ),
    "terrain.crs": Key(
        str,
        "",
        "-",
        "CRS of the DEM ('EPSG:32719' or WKT) for a raster that has none (an .asc without .prj); must be "
        "projected (metres). Default: the raster's own.",
    ),
    "release.region_map_m": Key(
        "region",
        None,
        "m",
        "Breach release: the pond's plan-view region in map coordinates, a box [xmin, ymin, xmax, ymax] or a "
        "polygon [[x, y], ...] (3D), or [xmin, xmax] (2D). Filled from the terrain (or the domain floor) up to "
        "release.pond_level_m.",
    ),
    "release.pond_level_m": Key(
        float, None, "m", "Breach release: the pond surface elevation z (needed with release.region_map_m)."
    ),
    "output.runout_axis": Key(int, 0, "-", "Axis along which runout is measured.", lo=0, hi=2),
    "output.runout_origin_m": Key(
        float, math.nan, "m", "Origin of runout; default: the back (min) of the material along runout_axis at t = 0."
    ),
    "output.slump_test": Key(
        bool,
        False,
        "-",
        "Slump test metrics in summary.json (slump_test: slump height, spread diameter and the yield stress "
        "back-calculated with the Pashias et al. 1996 relation): needs a 3D scene whose one body is a vertical "
        "cylinder standing on the domain floor (docs/slump-test.md).",
    ),
    "output.hazard_maps": Key(
        bool,
        False,
        "-",
        "Hazard maps (3D: plan-view rasters; 2D: profiles along x): maximum flow depth, maximum speed, maximum "
        "depth x speed and arrival time over the whole run, and the final deposit thickness (docs/output.md).",
    ),
    "output.hazard_format": Key(
        str,
        "auto",
        "-",
        "Hazard raster format: geotiff (needs a CRS), ascii (ESRI ASCII grid), or auto (GeoTIFF when the scene "
        "has a CRS, else ESRI ASCII).",
        choices=("auto", "geotiff", "ascii"),
    ),
    "output.hazard_every_steps": Key(
        int, 1, "-", "Hazard maps: accumulate every k-th time step (1: every step).", lo=1, hi=1000000
    ),
    "output.hazard_depth_m": Key(
        float,
        0.1,
        "m",
        "Hazard maps: flow depth above which a bin is wet: the arrival time is the first time the depth exceeds "
        "it, and speeds count only where it is exceeded.",
        lo=0.0,
        lo_open=True,
    ),
}


# The keys of one [[bodies]] table (shown as bodies[].KEY in docs/scenes.md); which type takes
# which key: BODY_TYPES.  Cross-key rules (top radius <= radius, a simple polygon, a closed mesh,
# inside the domain) are checked in validate._validate_bodies.
BODY_KEYS: dict[str, Key] = {
    "type": Key(
        str,
        "box",
        "-",
        "Body shape: box (any dim), cylinder and cone (3D, axis-aligned), polygon (2D), mesh (3D, a closed "
        "triangle mesh from an STL or OBJ file).",
        choices=("box", "cylinder", "cone", "polygon", "mesh"),
    ),
    "lo_m": Key("vec", _REQ, "m", "box: lower corner."),
    "hi_m": Key("vec", _REQ, "m", "box: upper corner (> lo_m on every axis)."),
    "base_m": Key("vec", _REQ, "m", "cylinder, cone: centre of the base, the end face at the low end along the axis."),
    "axis": Key(int, None, "-", "cylinder, cone: the axis (0 x, 1 y, 2 z); default: the vertical (2).", lo=0, hi=2),
    "radius_m": Key(float, _REQ, "m", "cylinder: radius; cone: radius at the base.", lo=0.0, lo_open=True),
    "top_radius_m": Key(
        float,
        _REQ,
        "m",
        "cone: radius at the top (the end at base + height along the axis); 0 is a full cone; at most radius_m.",
        lo=0.0,
    ),
    "height_m": Key(float, _REQ, "m", "cylinder, cone: length along the axis.", lo=0.0, lo_open=True),
    "vertices_m": Key(
        "points",
        _REQ,
        "m",
        "polygon: vertices [[x, y], ...] in order (either orientation), at least 3, not self-intersecting.",
    ),
    "file": Key(
        str,
        _REQ,
        "-",
        "mesh: STL or OBJ file, relative to the scene file; a closed (watertight) triangle surface, read with trimesh.",
    ),
    "scale": Key(
        float,
        1.0,
        "-",
        "mesh: factor from the file's coordinates to metres (0.001 for a file in mm); applied before offset_m.",
        lo=0.0,
        lo_open=True,
    ),
    "offset_m": Key("vec", None, "m", "mesh: added to the scaled coordinates; default 0."),
    "velocity_m_s": Key("vec", None, "m/s", "Initial velocity of the body; default 0."),
}

# body type -> (the dimensions it exists in, its keys besides type and velocity_m_s)
BODY_TYPES: dict[str, tuple[tuple[int, ...], tuple[str, ...]]] = {
    "box": ((2, 3), ("lo_m", "hi_m")),
    "cylinder": ((3,), ("base_m", "radius_m", "height_m", "axis")),
    "cone": ((3,), ("base_m", "radius_m", "top_radius_m", "height_m", "axis")),
    "polygon": ((2,), ("vertices_m",)),
    "mesh": ((3,), ("file", "scale", "offset_m")),
}
