"""Scene keys: the schema, validation, TOML loading and ``--set`` overrides.

A scene file is a TOML document whose keys are listed in ``SCHEMA`` (each with its
unit, default, allowed range and meaning; ``mpmjax scenes --keys`` prints them and
docs/scenes.md is generated from them by ``schema_markdown``).  The ``material.*`` keys
are not listed here: each rheology law declares its own (``_rheology.Param`` /
``_rheology.Option``), and ``SCHEMA`` is rebuilt from those declarations whenever a law
is registered.  ``load_scene(name_or_path, overrides)`` returns a validated flat dict;
``_build.build(cfg)`` turns it into a run.

Errors are ``SceneError`` (a ``ValueError``) naming the key, the value and the
allowed range.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from . import _dem, _release, _rheology, _shapes
from ._boundary import inflow_layout
from ._scene import FACE_KINDS, WALL_KINDS


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
    "numerics.maxwell_shear_modulus_pa": Key(
        float,
        0.0,
        "Pa",
        "Maxwell regularisation modulus G; 0 means G = bulk modulus, or with numerics.pressure = incompressible "
        "G = rho v^2, v the velocity scale of the time step, so that the shear waves are no faster than the flow.",
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
        "(1.37 m instead of 1.19 m at h = 0.01 m); see benchmarks/accuracy/ppc_probe.md and docs/scenarios.md, overpacking.",
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
        "explicit",
        "-",
        "Where the pressure comes from. explicit: each particle's J through the Tait EOS with "
        "material.bulk_modulus_pa (the thesis's weakly compressible MPM: the time step follows its sound speed, "
        "and a stiff kappa locks). incompressible: one pressure per grid cell solved every step so that the flow "
        "keeps its volume (fractional step, conjugate gradients; kappa is not used); the time step then follows the "
        "flow speed and the Maxwell shear waves (docs/validation.md, \"Incompressible limit\").",
        choices=("explicit", "incompressible"),
    ),
    "numerics.dtype": Key(str, "float32", "-", "Floating-point precision.", choices=("float32", "float64")),
    "numerics.devices": Key(
        int,
        1,
        "-",
        "Devices one run is split over (mpmjax run --devices): the particles are divided among them, and the grid is "
        "shared as numerics.decomposition says. On a CPU these are host devices, one per core. Same results as one "
        "device to float rounding. Not with a pipe inflow yet. "
        "Measured speed-up: docs/performance.md, \"One simulation across devices\".",
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
        "CPU cores it is slower than one device (0.6-0.9x). Measured: docs/performance.md, \"Slabs with halo "
        "exchange\".",
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
        'Material blocks: tables with type = "box", lo_m, hi_m and optional velocity_m_s. At least one body, an '
        "inflow or a release is required.",
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
        "none, noslip, slip or coulomb (slip with Coulomb friction).",
        choices=("none", "noslip", "slip", "coulomb"),
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
    "terrain.friction": Key(float, 0.0, "-", "Terrain: Coulomb friction coefficient (type coulomb).", lo=0.0, hi=10.0),
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


def _material_key(decl) -> Key:
    """The schema entry of a law's ``Param`` or ``Option``."""
    if isinstance(decl, _rheology.Option):
        return Key(str, decl.default, "-", decl.doc, choices=decl.choices)
    default = _REQ if decl.default is None else decl.default
    return Key(float, default, decl.unit, decl.doc, lo=decl.lo, lo_open=decl.lo_open, hi=decl.hi)


SCHEMA: dict[str, Key] = {}
SECTIONS: set[str] = set()


def _rebuild() -> None:
    """Refill ``SCHEMA`` (in place) from the fixed keys and the registered laws' declarations."""
    SCHEMA.clear()
    SCHEMA.update(_HEAD)
    SCHEMA["material.model"] = Key(str, "newtonian", "-", "Rheology.", choices=tuple(_rheology.MODELS))
    SCHEMA.update({d.key: _material_key(d) for d in _rheology.MATERIAL_KEYS})
    SCHEMA.update(_TAIL)
    SECTIONS.clear()
    SECTIONS.update(k.split(".")[0] for k in SCHEMA if "." in k)


_rebuild()
_rheology._listeners.append(_rebuild)


def register_law(cls):
    """Register a rheology law (a ``_rheology.Law`` subclass): ``material.model = cls.name``
    becomes valid and its parameters and options become scene keys.  Returns ``cls``."""
    return _rheology.register(cls)


def unregister_law(name: str) -> None:
    """Remove a law added by ``register_law`` and the scene keys only it declared."""
    _rheology.unregister(name)



def _flatten(d: dict, prefix="") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and key in SECTIONS:
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def builtin_scenes() -> dict[str, Path]:
    """Built-in scene names -> paths of the TOML files shipped inside the package."""
    root = resources.files("mpmjax") / "scenes"
    return {Path(str(p)).stem: Path(str(p)) for p in root.iterdir() if str(p).endswith(".toml")}


def parse_override(text: str) -> tuple[str, Any]:
    """``key=value`` with a TOML value (numbers, strings, lists); bare words become strings."""
    if "=" not in text:
        raise SceneError(f"--set {text!r}: expected key=value, e.g. material.mu0_pa_s=2.0")
    key, raw = text.split("=", 1)
    key = key.strip()
    try:
        val = tomllib.loads(f"v = {raw.strip()}")["v"]
    except (ValueError, RecursionError, KeyError):  # TOMLDecodeError, integer too long, deep nesting
        val = raw.strip()
    return key, val


def _plain(val: Any) -> Any:
    """Numpy scalars and arrays (also inside lists, tuples and dicts) as plain Python numbers
    and lists, so that messages print ``5.0``, not ``np.float64(5.0)``."""
    if isinstance(val, np.ndarray):
        return val.tolist()
    if isinstance(val, np.generic):
        return val.item()
    if isinstance(val, (list, tuple)):
        return [_plain(a) for a in val]
    if isinstance(val, dict):
        return {k: _plain(a) for k, a in val.items()}
    return val


def _show(val: Any, limit: int = 120) -> str:
    """``repr`` for error messages (numpy values as plain numbers, ``_plain``): never raises
    (huge ints) and is cut to ``limit`` characters."""
    try:
        text = repr(_plain(val))
    except Exception:  # e.g. ValueError: int too large for str()  # noqa: BLE001
        text = f"<{type(val).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _to_float(a) -> float:
    """float(a), with integers too large for a float mapped to +-inf (rejected as non-finite)."""
    try:
        return float(a)
    except OverflowError:
        return math.inf if a > 0 else -math.inf


def _check(key: str, val: Any, spec: Key, dim: int):
    def bad(why):
        raise SceneError(f"{key} = {_show(val)} is invalid: {why} ({spec.doc} Unit: {spec.unit})")

    if spec.type == "vec":
        # horizontal axes only: terrain origins; a crop window: [xmin, ymin, xmax, ymax]
        n = {"terrain.origin_m": dim - 1, "terrain.map_origin_m": dim - 1, "terrain.crop_map_m": 4}.get(key, dim)
        if not isinstance(val, (list, tuple)) or not all(
            isinstance(a, (int, float)) and not isinstance(a, bool) for a in val
        ):
            bad(f"expected a list of {n} numbers")
        if len(val) != n:
            bad(f"expected {n} components for a {dim}D scene (domain.dim = {dim})")
        vals = [_to_float(a) for a in val]
        if not all(math.isfinite(a) for a in vals):
            bad("components must be finite")
        return vals
    if key == "terrain.heights_m":
        arr = _terrain_array(val, dim, lambda why: bad(why))
        return arr.tolist()
    if spec.type == "region":
        why = _release.region_error(_plain(val), dim)
        if why:
            bad(why)
        return _plain(val)
    if spec.type == "table-list":
        if not isinstance(val, list) or not all(isinstance(a, dict) for a in val):
            bad("expected a list of tables ([[...]] in TOML)")
        return val
    if spec.type is float:
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            bad("expected a number")
        val = _to_float(val)
        if not math.isfinite(val):
            # NaN is the internal "derived" default of the _NAN_DEFAULT keys, never a user's value
            bad("must be finite" + (" (leave the key out for the default)" if key in _NAN_DEFAULT else ""))
    elif spec.type is int:
        if isinstance(val, bool) or not isinstance(val, int):
            bad("expected an integer")
    elif spec.type is bool:
        if not isinstance(val, bool):
            bad("expected true or false")
    elif spec.type is str:
        if not isinstance(val, str):
            bad("expected a string")
        if "\x00" in val:
            bad("must not contain NUL characters")
    if spec.choices is not None and val not in spec.choices:
        bad(f"allowed values: {', '.join(map(str, spec.choices))}")
    if spec.lo is not None:
        if val < spec.lo or (spec.lo_open and val == spec.lo):
            rng = f"> {spec.lo}" if spec.lo_open else f">= {spec.lo}"
            if spec.hi is not None:
                rng += f" and <= {spec.hi}"
            bad(f"allowed range: {rng}")
    if spec.hi is not None and val > spec.hi:
        bad(f"allowed range: <= {spec.hi}")
    return val


# keys whose default is NaN, meaning "derived from the scene" (the key's doc says how); a NaN
# given by the user is refused like any non-finite value
_NAN_DEFAULT = ("output.runout_origin_m", "inflow.t_stop_s")
_MAX_PARTICLES = 2**31 - 1
_F32 = np.finfo(np.float32)
# float keys that become float32 arrays (material parameters, gravity, positions, velocities)
def _f32_keys() -> tuple[str, ...]:
    return tuple(k for k, s in SCHEMA.items() if s.type is float and k.split(".")[0] in ("material", "gravity")) + (
        "numerics.maxwell_shear_modulus_pa",
        "domain.cell_size_m",
        "domain.lo_m",
        "domain.hi_m",
        "gate.point_m",
        "inflow.point_m",
    )


def _check_float32_range(out: dict):
    """With numerics.dtype = float32, every parameter must survive the conversion: no
    overflow to inf, and no underflow to 0 of a value that must be positive."""

    def check(key, val, positive):
        a = abs(val)
        if a > float(_F32.max) or (positive and a < float(_F32.tiny)):
            raise SceneError(
                f"{key} = {_show(val)} is invalid with numerics.dtype = float32: allowed magnitude "
                f'{_F32.tiny:.3g} .. {_F32.max:.3g} (use numerics.dtype = "float64" for more range)'
            )

    for key in _f32_keys():
        val = out.get(key)
        if val is None:
            continue
        spec = SCHEMA[key]
        for v in val if isinstance(val, list) else [val]:
            if not math.isnan(v):
                check(key, v, spec.lo_open and spec.lo == 0.0)
    for i, b in enumerate(out["bodies"]):
        if isinstance(b, dict):
            for sub in ("lo_m", "hi_m", "velocity_m_s"):
                v = b.get(sub)
                if isinstance(v, list):
                    for a in v:
                        if isinstance(a, (int, float)) and not isinstance(a, bool):
                            check(f"bodies[{i}].{sub}", _to_float(a), False)


def _usable_normal(nrm) -> bool:
    with np.errstate(all="ignore"):
        length = float(np.linalg.norm(np.asarray(nrm, float)))
    return math.isfinite(length) and length >= np.finfo(float).tiny


def _body_particle_count(blo, bhi, dx) -> float:
    with np.errstate(all="ignore"):
        counts = np.maximum(np.round((bhi - blo) / dx), 1.0)
        return float(np.prod(counts))


def _terrain_array(val, dim: int, bad) -> np.ndarray:
    """Terrain samples as a float array of dim - 1 axes (each >= 2 samples), all finite."""
    try:
        arr = np.asarray(val, dtype=float)
    except (TypeError, ValueError, OverflowError):
        bad(f"expected {'a list of numbers' if dim == 2 else 'a list of equal-length lists of numbers'}")
    if arr.ndim != dim - 1 or min(arr.shape) < 2:
        bad(f"expected {dim - 1} axis/axes of at least 2 samples (domain.dim = {dim}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad("samples must be finite")
    return arr


_DEM_ONLY = ("terrain.crop_map_m", "terrain.resample", "terrain.crs")


def _validate_terrain(out: dict, dim: int, lo, flat: dict):
    kind = out["terrain.type"]
    if kind == "none":
        given = [k for k in ("terrain.dem", *_DEM_ONLY) if k in flat]
        if given:
            raise SceneError(f"{given[0]} = {_show(flat[given[0]])} is invalid with terrain.type = 'none'; allowed: "
                             "set terrain.type (noslip, slip or coulomb) to use a DEM")
        return
    sources = [k for k in ("terrain.heights_m", "terrain.csv", "terrain.dem") if out[k]]
    if not sources:
        raise SceneError(f"terrain.type = {kind!r} needs terrain.heights_m or terrain.csv (or terrain.dem)")
    if len(sources) > 1:
        raise SceneError(f"{' and '.join(sources)} are alternatives; give one")
    if out["terrain.dem"]:
        _validate_dem(out, dim, flat)
        return
    given = [k for k in _DEM_ONLY if k in flat]
    if given:
        raise SceneError(f"{given[0]} = {_show(flat[given[0]])} is invalid without terrain.dem: it describes a DEM")
    if out["terrain.csv"]:
        path = Path(out["terrain.csv"])
        try:
            data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
        except (OSError, ValueError) as e:
            raise SceneError(f"terrain.csv = {str(path)!r} cannot be read as a CSV of numbers: {e}") from None
        if dim == 2:
            data = data.ravel()

        def bad(why):
            raise SceneError(f"terrain.csv = {str(path)!r} is invalid: {why}")

        out["terrain.heights_m"] = _terrain_array(data, dim, bad).tolist()
        out["terrain.csv"] = str(path)
    if out["terrain.origin_m"] is None:
        out["terrain.origin_m"] = [float(a) for a in lo[: dim - 1]]


def _validate_dem(out: dict, dim: int, flat: dict):
    """Read ``terrain.dem`` (``_dem.terrain_samples``) and fill the terrain and map keys from it."""
    if dim != 3:
        raise SceneError(
            f"terrain.dem = {out['terrain.dem']!r} is invalid in a 2D scene (domain.dim = 2): a DEM is a plan-view "
            "grid; allowed: a 3D scene, or a 2D profile in terrain.csv or terrain.heights_m"
        )
    derived = [k for k in ("terrain.origin_m", "terrain.spacing_m") if k in flat]
    if derived:
        raise SceneError(
            f"{derived[0]} = {_show(flat[derived[0]])} is invalid with terrain.dem: the DEM sets it (the map origin "
            "is terrain.map_origin_m)"
        )
    try:
        got = _dem.terrain_samples(out, Path(out["terrain.dem"]))
    except _dem._Error as e:
        raise SceneError(f"terrain.dem: {e}") from None
    out.update({k: v for k, v in got.items() if k.startswith("terrain.")})


def _validate_release(out: dict, dim: int, lo, hi, flat: dict):
    region, pond = out["release.region_map_m"], out["release.pond_level_m"]
    if region is None:
        if pond is not None:
            raise SceneError(
                f"release.pond_level_m = {pond} is invalid without release.region_map_m (the pond's region)"
            )
        return
    if pond is None:
        raise SceneError("release.region_map_m needs release.pond_level_m, the pond surface elevation z [m]")
    poly = _release.region_polygon(region, out["terrain.map_origin_m"], dim)
    pts = poly.reshape(-1, dim - 1)
    tol = 1e-9 * out["domain.cell_size_m"]
    if np.any(pts < lo[: dim - 1] - tol) or np.any(pts > hi[: dim - 1] + tol):
        origin = out["terrain.map_origin_m"] or [0.0] * (dim - 1)
        raise SceneError(
            f"release.region_map_m = {_show(region)} is not inside the domain's plan: in scene coordinates "
            f"(map - terrain.map_origin_m = {_show(origin)}) it spans [{_plain(pts.min(axis=0))}, "
            f"{_plain(pts.max(axis=0))}] m; the domain spans [{_plain(lo[: dim - 1])}, {_plain(hi[: dim - 1])}] m"
        )
    if not lo[-1] < pond <= hi[-1]:
        raise SceneError(
            f"release.pond_level_m = {pond} is invalid: allowed range: > domain.lo_m z = {lo[-1]} and <= domain.hi_m "
            f"z = {hi[-1]} (m; the pond must lie inside the domain)"
        )


def _validate_inflow(out: dict, dim: int, lo, hi, h):
    pt, dr = out["inflow.point_m"], out["inflow.direction"]
    if (pt is None) != (dr is None):
        raise SceneError("inflow.point_m and inflow.direction must be given together")
    if pt is None:
        return
    if not _usable_normal(dr):
        raise SceneError(
            f"inflow.direction = {dr} is invalid: allowed: a non-zero vector whose length is a finite, normal float"
        )
    p = np.asarray(pt)
    if np.any(p < lo) or np.any(p > hi):
        raise SceneError(f"inflow.point_m = {pt} lies outside the domain [{_plain(lo)}, {_plain(hi)}] (m)")
    t0, t1 = out["inflow.t_start_s"], out["inflow.t_stop_s"]
    t1 = out["time.t_end_s"] if math.isnan(t1) else t1
    if t1 <= t0:
        raise SceneError(f"inflow.t_stop_s = {t1} is invalid: allowed range: > inflow.t_start_s = {t0} (s)")
    if out["inflow.aging_gate"] and out["gate.point_m"] is not None:
        raise SceneError(
            "gate.point_m is invalid with inflow.aging_gate = true (the inflow puts the aging gate at the pipe "
            "exit); allowed: set inflow.aging_gate = false to use gate.point_m"
        )
    if 2 * out["inflow.width_m"] < h / out["numerics.ppc"]:
        raise SceneError(
            f"inflow.width_m = {out['inflow.width_m']} is invalid: allowed range: >= half the particle spacing "
            f"domain.cell_size_m / numerics.ppc = {h / out['numerics.ppc']} m"
        )
    if out["numerics.devices"] > 1:
        raise SceneError(
            f"numerics.devices = {out['numerics.devices']} is invalid with a pipe inflow (its release schedule numbers "
            "the pool particles globally, which one device's share does not see); allowed: 1"
        )
    n = inflow_layout(out, dim)[2]
    if n > _MAX_PARTICLES:
        raise SceneError(
            f"inflow: {n:.4g} pool particles (flow_rate_m3_s = {out['inflow.flow_rate_m3_s']}, "
            f"{t1 - t0} s); the limit is {_MAX_PARTICLES}"
        )


def _law_keys(law) -> set[str]:
    """The material keys a law reads: its parameters and options, the model and the shear
    measure (every law's viscosity is fed the shear rate it selects: ``Scene.shear_measure``)."""
    return {d.key for d in law.params + law.options} | {"material.model", "material.shear_measure"}


def _validate_material(flat: dict, out: dict) -> None:
    """The material keys given must belong to the chosen law, and its ordered parameter pairs
    (``Law.ordered_params``, e.g. Coussot's mu0 <= mu_max) must be in order."""
    model = out["material.model"]
    law = _rheology.MODELS[model]
    used = _law_keys(law)
    unused = [k for k in flat if k.startswith("material.") and k not in used]
    if unused:
        k = unused[0]
        users = [name for name, cls in _rheology.MODELS.items() if k in _law_keys(cls)]
        raise SceneError(
            f"{k} = {_show(flat[k])} is invalid with material.model = {model!r}: that law does not use it"
            + (f" ({len(unused) - 1} more such key(s): {', '.join(unused[1:])})" if len(unused) > 1 else "")
            + f"; allowed material keys for {model}: {', '.join(sorted(used))}"
            + (f" (the key belongs to material.model = {', '.join(users)})" if users else "")
        )
    key_of = {p.name: p for p in law.params}
    for lo_name, hi_name in law.ordered_params:
        lo_p, hi_p = key_of[lo_name], key_of[hi_name]
        a, b = out[lo_p.key], out[hi_p.key]
        if b < a:
            raise SceneError(
                f"{hi_p.key} = {_show(b)} is invalid with {lo_p.key} = {_show(a)}: allowed range: >= {lo_p.key} "
                f"= {_show(a)} ({hi_p.unit}); material.model = {model!r} needs {lo_name} <= {hi_name}"
            )


def _check_pressure(out: dict):
    """numerics.pressure = incompressible keeps the volume itself: the particle-level volume devices
    and the slab decomposition (whose halos the grid solve does not exchange) are refused."""
    if out["numerics.pressure"] == "explicit":
        return
    for key, off in (("numerics.volume_averaging", "none"), ("numerics.grid_density_cap", 0.0)):
        if out[key] != off:
            raise SceneError(
                f"{key} = {_show(out[key])} is invalid with numerics.pressure = 'incompressible' (the grid pressure "
                f"keeps the volume itself); allowed: {off!r}"
            )
    if out["numerics.devices"] > 1 and out["numerics.decomposition"] == "slab":
        raise SceneError(
            "numerics.decomposition = 'slab' is invalid with numerics.pressure = 'incompressible' (the pressure is "
            "solved on the whole grid); allowed: 'replicated'"
        )


def validate(raw: dict) -> dict:
    """Check a nested scene dict against ``SCHEMA``; returns a flat dict with defaults."""
    if not isinstance(raw, dict):
        raise SceneError(f"a scene must be a table of keys (a TOML document), got {_show(raw)}")
    for sec in sorted(SECTIONS):
        if sec in raw and not isinstance(raw[sec], dict):
            raise SceneError(
                f"{sec} = {_show(raw[sec])} is invalid: expected a table ([{sec}] in TOML) "
                f"with keys {', '.join(k for k in SCHEMA if k.startswith(sec + '.'))}"
            )
    flat = _flatten(raw)
    unknown = sorted(str(k) for k in flat if k not in SCHEMA)
    if unknown:
        raise SceneError(
            f"unknown key(s): {', '.join(unknown)}. Known keys: see `mpmjax scenes --keys` or docs/scenes.md"
        )
    dim = flat.get("domain.dim", 2)
    dim = _check("domain.dim", dim, SCHEMA["domain.dim"], 2)
    out = {}
    for key, spec in SCHEMA.items():
        if key in flat:
            out[key] = _check(key, flat[key], spec, dim)
        elif spec.default is _REQ:
            raise SceneError(f"missing required key {key} ({spec.doc} Unit: {spec.unit})")
        else:
            out[key] = copy.deepcopy(spec.default)
    if out["numerics.dtype"] == "float32":
        _check_float32_range(out)
    _check_pressure(out)
    lo, hi = np.asarray(out["domain.lo_m"]), np.asarray(out["domain.hi_m"])
    if np.any(hi <= lo):
        raise SceneError(
            f"domain.hi_m = {out['domain.hi_m']} must exceed domain.lo_m = {out['domain.lo_m']} on every axis"
        )
    h = out["domain.cell_size_m"]
    with np.errstate(all="ignore"):
        size = hi - lo
        ncell = size / h
        n_total = float(np.prod(np.round(ncell) + 7))
    if not np.all(np.isfinite(size)):
        raise SceneError(
            f"domain.lo_m = {out['domain.lo_m']}, domain.hi_m = {out['domain.hi_m']}: the domain size "
            "overflows a float; allowed: a finite size on every axis"
        )
    if not math.isfinite(n_total) or n_total > 5e7:
        n_cells = float(np.prod(np.round(ncell))) if math.isfinite(n_total) else math.inf
        raise SceneError(
            f"domain.cell_size_m = {h} gives {n_cells:.4g} cells for the domain size {_plain(size)} m; "
            "the limit is 5e7 (including the ghost layers)"
        )
    if np.any(ncell < 1) or np.any(np.abs(ncell - np.round(ncell)) > 1e-6 * np.maximum(ncell, 1)):
        raise SceneError(
            f"domain.cell_size_m = {h} must divide the domain size {_plain(size)} into a whole number (>= 1) of cells"
        )
    if dim == 2:
        only3 = [k for k in flat if SCHEMA[k].only_3d]
        if only3:
            raise SceneError(
                f"{', '.join(f'{k} = {_show(flat[k])}' for k in only3)} is invalid in a 2D scene (domain.dim = 2): "
                "allowed only in 3D scenes (domain.dim = 3); remove it"
            )
    _validate_material(flat, out)
    if not out["bodies"] and out["inflow.point_m"] is None and out["release.region_map_m"] is None:
        raise SceneError(
            "bodies = [] is invalid: at least one material body (or an inflow, or a release.region_map_m) is required"
        )
    n_particles = 0
    for i, b in enumerate(out["bodies"]):
        extra = set(b) - {"type", "lo_m", "hi_m", "velocity_m_s"}
        if extra:
            raise SceneError(
                f"bodies[{i}]: unknown key(s) {sorted(map(str, extra))}; allowed: type, lo_m, hi_m, velocity_m_s"
            )
        if not isinstance(b.get("type", "box"), str) or b.get("type", "box") != "box":
            raise SceneError(f"bodies[{i}].type = {_show(b.get('type'))} is invalid: allowed values: box")
        vspec = Key("vec", None, "m", "body corner")
        blo = np.asarray(_check(f"bodies[{i}].lo_m", b.get("lo_m"), vspec, dim))
        bhi = np.asarray(_check(f"bodies[{i}].hi_m", b.get("hi_m"), vspec, dim))
        _check(
            f"bodies[{i}].velocity_m_s", b.get("velocity_m_s", [0.0] * dim), Key("vec", None, "m/s", "velocity"), dim
        )
        if np.any(bhi <= blo):
            raise SceneError(f"bodies[{i}]: hi_m = {_plain(bhi)} must exceed lo_m = {_plain(blo)} on every axis")
        if np.any(blo < lo - 1e-9) or np.any(bhi > hi + 1e-9):
            raise SceneError(
                f"bodies[{i}] = [{_plain(blo)}, {_plain(bhi)}] lies outside the domain "
                f"[domain.lo_m, domain.hi_m] = [{_plain(lo)}, {_plain(hi)}] (m)"
            )
        n_particles += _body_particle_count(blo, bhi, h / out["numerics.ppc"])
    if n_particles > _MAX_PARTICLES:
        raise SceneError(
            f"bodies: {n_particles:.4g} particles at numerics.ppc = {out['numerics.ppc']} per cell and "
            f"domain.cell_size_m = {h}; the limit is {_MAX_PARTICLES} (int32 particle indices)"
        )
    for i, p in enumerate(out["boundary.planes"]):
        extra = set(p) - {"point_m", "normal", "type"}
        if extra:
            raise SceneError(
                f"boundary.planes[{i}]: unknown key(s) {sorted(map(str, extra))}; allowed: point_m, normal, type"
            )
        _check(f"boundary.planes[{i}].point_m", p.get("point_m"), Key("vec", None, "m", "plane point"), dim)
        nrm = _check(f"boundary.planes[{i}].normal", p.get("normal"), Key("vec", None, "-", "plane normal"), dim)
        if not _usable_normal(nrm):
            raise SceneError(
                f"boundary.planes[{i}].normal = {nrm} is invalid: allowed: a non-zero vector whose "
                "length is a finite, normal float"
            )
        _check(
            f"boundary.planes[{i}].type",
            p.get("type", "noslip"),
            Key(str, None, "-", "wall type", choices=WALL_KINDS),
            dim,
        )
    if (out["gate.point_m"] is None) != (out["gate.normal"] is None):
        raise SceneError("gate.point_m and gate.normal must be given together")
    if out["gate.normal"] is not None and not _usable_normal(out["gate.normal"]):
        raise SceneError(
            f"gate.normal = {out['gate.normal']} is invalid: allowed: a non-zero vector whose "
            "length is a finite, normal float"
        )
    _validate_inflow(out, dim, lo, hi, h)
    _validate_terrain(out, dim, lo, flat)
    if out["output.hazard_maps"] and out["output.hazard_format"] == "geotiff" and not out["terrain.crs"]:
        raise SceneError(
            "output.hazard_format = 'geotiff' needs a CRS, and the scene has none"
            + (
                f" (the DEM {out['terrain.dem']} has no CRS in the file and no .prj beside it)"
                if out["terrain.dem"]
                else " (no terrain.dem)"
            )
            + "; allowed: set terrain.crs (e.g. 'EPSG:32719') with a DEM, or output.hazard_format = 'ascii' (or 'auto')"
        )
    _validate_release(out, dim, lo, hi, flat)
    if out["output.runout_axis"] >= dim:
        raise SceneError(
            f"output.runout_axis = {out['output.runout_axis']} is invalid: allowed range 0..{dim - 1} "
            f"(domain.dim = {dim})"
        )
    for ax in range(dim):
        lo_k, hi_k = out[f"boundary.{'xyz'[ax]}_lo"], out[f"boundary.{'xyz'[ax]}_hi"]
        if (lo_k == "periodic") != (hi_k == "periodic"):
            raise SceneError(
                f"boundary.{'xyz'[ax]}_lo = {lo_k!r}, boundary.{'xyz'[ax]}_hi = {hi_k!r}: "
                "periodic must be set on both faces of an axis"
            )
    return out


def load_scene(name_or_path: str | Path, overrides: list[str] | dict | None = None) -> dict:
    """Read a built-in scene by name, or a TOML file by path, apply ``key=value``
    overrides and validate.  Returns the flat validated dict."""
    scenes = builtin_scenes()
    name = str(name_or_path)
    if name in scenes:
        path = scenes[name]
    else:
        path = Path(name)
        if not path.is_file():
            raise SceneError(
                f"scene {name!r} is neither a built-in scene ({', '.join(sorted(scenes))}) nor a TOML file"
            )
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: not a UTF-8 text file (TOML must be UTF-8): {e}") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot be read: {e}") from None
    try:
        raw = tomllib.loads(text)
    except (ValueError, RecursionError) as e:  # TOMLDecodeError; ValueError: integer too long; deep nesting
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    items = overrides.items() if isinstance(overrides, dict) else [parse_override(o) for o in (overrides or [])]
    items = list(items)
    file_mat = raw.get("material") if isinstance(raw.get("material"), dict) else {}
    file_model = file_mat.get("model", SCHEMA["material.model"].default)
    for key, val in items:
        if key not in SCHEMA:
            raise SceneError(f"--set {key}: unknown key. Known keys: see `mpmjax scenes --keys` or docs/scenes.md")
        node = raw
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise SceneError(f"--set {key}: {p} is not a table in {path}")
        node[parts[-1]] = val
    _drop_switched_law_keys(raw, file_model, file_mat, {k for k, _ in items})
    ter = raw.get("terrain")
    for k in ("csv", "dem"):
        if isinstance(ter, dict) and isinstance(ter.get(k), str) and ter[k]:
            if "\x00" in ter[k]:
                raise SceneError(f"terrain.{k} = {ter[k]!r}: a file path cannot contain a NUL character")
            ter[k] = str((path.parent / ter[k]).resolve()) if not Path(ter[k]).is_absolute() else ter[k]
    return validate(raw)


def _drop_switched_law_keys(raw: dict, file_model, file_keys: dict, set_keys: set) -> None:
    """``--set material.model=OTHER`` switches a scene file's law: the file's keys of its own
    law that the new law does not read are dropped (they described the old law; the validated
    scene then holds the defaults there).  Keys the file's own law never read are still
    refused, as are ``--set`` keys the new law does not read."""
    mat = raw.get("material")
    if "material.model" not in set_keys or not isinstance(mat, dict):
        return
    new_model = mat.get("model")
    if not (isinstance(new_model, str) and isinstance(file_model, str)) or new_model == file_model:
        return
    if new_model not in _rheology.MODELS or file_model not in _rheology.MODELS:
        return
    old_keys = _law_keys(_rheology.MODELS[file_model])
    new_keys = _law_keys(_rheology.MODELS[new_model])
    for k in list(file_keys):
        key = f"material.{k}"
        if key in old_keys and key not in new_keys and key not in set_keys:
            mat.pop(k, None)


def schema_markdown() -> str:
    """The scene-key reference as a Markdown table (docs/scenes.md is generated from it)."""
    rows = ["| key | unit | default | allowed | meaning |", "|---|---|---|---|---|"]
    for key, spec in SCHEMA.items():
        if spec.default is _REQ:
            default = "required"
        elif isinstance(spec.default, float) and math.isnan(spec.default):
            default = "(derived)"
        else:
            default = f"`{spec.default!r}`" if spec.default is not None else "(none)"
        if spec.choices:
            allowed = ", ".join(f"`{c}`" for c in spec.choices)
        else:
            parts = []
            if spec.lo is not None:
                parts.append(f"{'>' if spec.lo_open else '≥'} {spec.lo:g}")
            if spec.hi is not None:
                parts.append(f"≤ {spec.hi:g}")
            allowed = ", ".join(parts) or "-"
        rows.append(f"| `{key}` | {spec.unit} | {default} | {allowed} | {spec.doc} |")
    return "\n".join(rows)
