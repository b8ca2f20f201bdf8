"""Scene files: TOML with documented keys in SI units, validation, and building a run.

A scene file is a TOML document whose keys are listed in ``SCHEMA`` (each with its
unit, default, allowed range and meaning; ``mpmjax scenes --keys`` prints them and
docs/scenes.md is generated from them).  ``load_scene(name_or_path, overrides)``
returns a validated nested dict; ``build(cfg)`` turns it into a static ``Scene``,
traced ``Params`` and the initial ``State``.

Errors are ``SceneError`` (a ``ValueError``) naming the key, the value and the
allowed range.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import math
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from . import _rheology, _shapes
from ._scene import FACE_KINDS, WALL_KINDS, Gate, Inflow, Params, Scene, Terrain, Wall, ghost_cells, init_state


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


_REQ = object()  # marker: required

SCHEMA: dict[str, Key] = {
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
    "boundary.z_lo": Key(str, "noslip", "-", "Condition on the z-min face (3D).", choices=FACE_KINDS),
    "boundary.z_hi": Key(str, "slip", "-", "Condition on the z-max face (3D).", choices=FACE_KINDS),
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
        "Shape function (gimp: the thesis's choice; see docs/validation.md for the measured accuracy of each).",
        choices=tuple(_shapes.STENCIL),
    ),
    "numerics.transfer": Key(
        str, "apic", "-", "Particle-grid transfer: APIC or a FLIP/PIC blend.", choices=("apic", "flip")
    ),
    "numerics.flip_blend": Key(
        float, 0.95, "-", "FLIP fraction of the FLIP/PIC blend (transfer = flip).", lo=0.0, hi=1.0
    ),
    "numerics.ppc": Key(int, 2, "-", "Particles per cell per axis for seeded bodies.", lo=1, hi=8),
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
        float, 0.0, "Pa", "Maxwell regularisation modulus G; 0 means G = bulk modulus.", lo=0.0
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
        "Grid volume check (a diagnostic, off by default): a particle's J is capped at (1 + cap) / phi, phi "
        "the packing of reference volume measured on the grid (nodal mass / (rho h^d), wall-corrected) at the "
        "particle. It keeps thin pipe-fed deposits at their volume but biases free-surface flows towards longer "
        "runouts (dambreak-lab: 1.38 m instead of 1.10 m as h -> 0); see docs/scenarios.md, overpacking.",
        lo=0.0,
        hi=1.0,
    ),
    "numerics.dtype": Key(str, "float32", "-", "Floating-point precision.", choices=("float32", "float64")),
    "time.t_end_s": Key(float, _REQ, "s", "Simulated time.", lo=0.0, lo_open=True),
    "time.n_frames": Key(int, 30, "-", "Number of saved frames (outer scan length).", lo=1, hi=100000),
    "material.model": Key(str, "newtonian", "-", "Rheology.", choices=tuple(_rheology.MODELS)),
    "material.density_kg_m3": Key(float, _REQ, "kg/m^3", "Reference density rho.", lo=0.0, lo_open=True),
    "material.bulk_modulus_pa": Key(float, _REQ, "Pa", "Bulk modulus kappa of the Tait EOS.", lo=0.0, lo_open=True),
    "material.viscosity_pa_s": Key(
        float, 1.0, "Pa s", "Newtonian viscosity, or Bingham plastic viscosity.", lo=0.0, lo_open=True
    ),
    "material.yield_stress_pa": Key(float, 0.0, "Pa", "Yield stress tau_y (Bingham, Herschel-Bulkley).", lo=0.0),
    "material.bingham_variant": Key(
        str, "papanastasiou", "-", "Bingham law.", choices=("papanastasiou", "biviscosity")
    ),
    "material.alpha_b": Key(float, 100.0, "-", "Bi-viscosity ratio below yield.", lo=1.0, lo_open=True),
    "material.papanastasiou_m_s": Key(float, 100.0, "s", "Papanastasiou regularisation time m.", lo=0.0, lo_open=True),
    "material.consistency_pa_sn": Key(float, 1.0, "Pa s^n", "Herschel-Bulkley consistency K.", lo=0.0, lo_open=True),
    "material.flow_index": Key(float, 1.0, "-", "Herschel-Bulkley flow index.", lo=0.0, lo_open=True, hi=3.0),
    "material.mu0_pa_s": Key(float, 4.0, "Pa s", "Coussot minimum viscosity mu0.", lo=0.0, lo_open=True),
    "material.alpha": Key(float, 1.0, "-", "Coussot destructuration coefficient alpha.", lo=0.0, lo_open=True),
    "material.T_s": Key(float, 0.5, "s", "Coussot restructuring time T.", lo=0.0, lo_open=True),
    "material.n": Key(float, 2.5, "-", "Coussot exponent n.", lo=0.0, lo_open=True, hi=10.0),
    "material.lambda0": Key(float, 1.5, "-", "Coussot initial structure lambda0.", lo=0.0),
    "material.mu_max_pa_s": Key(
        float, 5000.0, "Pa s", "Viscosity cap mu_max (Coussot, Herschel-Bulkley).", lo=0.0, lo_open=True
    ),
    "material.lambda_integrator": Key(
        str,
        "exact",
        "-",
        "Structure update: exact exponential, or the thesis's explicit Euler.",
        choices=("exact", "euler"),
    ),
    "material.shear_measure": Key(
        str,
        "standard",
        "-",
        "standard: sqrt(2 d':d'); thesis: d':d'/4 (eq. 3.8 and Annex 1).",
        choices=("standard", "thesis"),
    ),
    "gravity.g_m_s2": Key(float, 9.81, "m/s^2", "Magnitude of gravity (acts along -last axis before tilting).", lo=0.0),
    "gravity.slope_deg": Key(
        float,
        0.0,
        "deg",
        "Tilt of gravity about the vertical-x plane: the base slopes down towards +x by this angle.",
        lo=-89.0,
        hi=89.0,
    ),
    "gravity.transverse_slope_deg": Key(float, 0.0, "deg", "3D only: tilt towards +y.", lo=-89.0, hi=89.0),
    "bodies": Key(
        "table-list", _REQ, "-", 'Material blocks: tables with type = "box", lo_m, hi_m and optional velocity_m_s.'
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
    "output.runout_axis": Key(int, 0, "-", "Axis along which runout is measured.", lo=0, hi=2),
    "output.runout_origin_m": Key(
        float, math.nan, "m", "Origin of runout; default: the back (min) of the material along runout_axis at t = 0."
    ),
}

SECTIONS = {k.split(".")[0] for k in SCHEMA if "." in k}


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


def _show(val: Any, limit: int = 120) -> str:
    """``repr`` for error messages: never raises (huge ints) and is cut to ``limit`` characters."""
    try:
        text = repr(val)
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
        n = dim - 1 if key == "terrain.origin_m" else dim  # horizontal axes only
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
    if spec.type == "table-list":
        if not isinstance(val, list) or not all(isinstance(a, dict) for a in val):
            bad("expected a list of tables ([[...]] in TOML)")
        return val
    if spec.type is float:
        if isinstance(val, bool) or not isinstance(val, (int, float)):
            bad("expected a number")
        val = _to_float(val)
        if not math.isfinite(val) and not (key in _NAN_DEFAULT and math.isnan(val)):
            bad("must be finite")
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
    if spec.lo is not None and not (isinstance(val, float) and math.isnan(val)):
        if val < spec.lo or (spec.lo_open and val == spec.lo):
            rng = f"> {spec.lo}" if spec.lo_open else f">= {spec.lo}"
            if spec.hi is not None:
                rng += f" and <= {spec.hi}"
            bad(f"allowed range: {rng}")
    if spec.hi is not None and val > spec.hi:
        bad(f"allowed range: <= {spec.hi}")
    return val


_NAN_DEFAULT = ("output.runout_origin_m", "inflow.t_stop_s")
_MAX_PARTICLES = 2**31 - 1
_F32 = np.finfo(np.float32)
# float keys that become float32 arrays (material parameters, gravity, positions, velocities)
_F32_KEYS = tuple(k for k, s in SCHEMA.items() if s.type is float and k.split(".")[0] in ("material", "gravity")) + (
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

    for key in _F32_KEYS:
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


def _validate_terrain(out: dict, dim: int, lo):
    kind = out["terrain.type"]
    if kind == "none":
        return
    if out["terrain.heights_m"] is None and not out["terrain.csv"]:
        raise SceneError(f"terrain.type = {kind!r} needs terrain.heights_m or terrain.csv")
    if out["terrain.heights_m"] is not None and out["terrain.csv"]:
        raise SceneError("terrain.heights_m and terrain.csv are alternatives; give one")
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
        raise SceneError(f"inflow.point_m = {pt} lies outside the domain [{list(lo)}, {list(hi)}] (m)")
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
    n = _inflow_layout(out, dim)[2]
    if n > _MAX_PARTICLES:
        raise SceneError(
            f"inflow: {n:.4g} pool particles (flow_rate_m3_s = {out['inflow.flow_rate_m3_s']}, "
            f"{t1 - t0} s); the limit is {_MAX_PARTICLES}"
        )


def _perp_basis(d: np.ndarray) -> list[np.ndarray]:
    """Unit vectors spanning the plane normal to the unit vector ``d``."""
    if d.size == 2:
        return [np.array([-d[1], d[0]])]
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return [e1, np.cross(d, e1)]


def _inflow_layout(cfg: dict, dim: int):
    """Cross-section offsets (n_per, dim) [m], area A [m^2; 2D: m], pool size, layer count and layer dt [s].

    The particle spacing is sp = h / ppc.  2D: n_per = round(width / sp) points evenly across the
    width.  3D: the points of a square lattice of spacing sp' = min(sp, diameter/2) (centred on
    the axis) inside the disc of the diameter (so at least 2 x 2 points); layers sp' thick.
    Layer time dt_l = sp' / u (2D: sp / u) rounded so that a whole number of layers spans
    [t_start, t_stop]; each layer carries Q dt_l.
    """
    sp = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
    d = np.asarray(cfg["inflow.direction"], float)
    d = d / np.linalg.norm(d)
    w = cfg["inflow.width_m"]
    basis = _perp_basis(d)
    if dim == 2:
        m = max(1, int(round(w / sp)))
        offs = [((j + 0.5) * w / m - 0.5 * w) * basis[0] for j in range(m)]
        area = w
    else:
        # at least 2 x 2 points across: a single particle on the pipe axis sits on a plane of
        # symmetry in y and never spreads sideways (measured in field-pipe-3d at h = 0.5 m)
        sp = min(sp, 0.5 * w)
        area = math.pi * w * w / 4.0
        m = max(1, int(math.ceil(w / sp)))
        c = (np.arange(m) - 0.5 * (m - 1)) * sp
        offs = [a * basis[0] + b * basis[1] for a in c for b in c if a * a + b * b <= 0.25 * w * w]
        offs = offs or [0.0 * d]
    t0 = cfg["inflow.t_start_s"]
    t1 = cfg["time.t_end_s"] if math.isnan(cfg["inflow.t_stop_s"]) else cfg["inflow.t_stop_s"]
    u = cfg["inflow.flow_rate_m3_s"] / area
    with np.errstate(all="ignore"):
        n_layers = max(1, int(round(min((t1 - t0) * u / sp, 1e12))))
    return np.asarray(offs), area, float(n_layers) * len(offs), n_layers, (t1 - t0) / n_layers, u, d


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
            f"domain.cell_size_m = {h} gives {n_cells:.4g} cells for the domain size {list(size)} m; "
            "the limit is 5e7 (including the ghost layers)"
        )
    if np.any(ncell < 1) or np.any(np.abs(ncell - np.round(ncell)) > 1e-6 * np.maximum(ncell, 1)):
        raise SceneError(
            f"domain.cell_size_m = {h} must divide the domain size {list(size)} into a whole number (>= 1) of cells"
        )
    if dim == 2 and any(k.startswith("boundary.z") for k in flat):
        raise SceneError("boundary.z_lo / boundary.z_hi are only valid in 3D scenes (domain.dim = 3)")
    if not out["bodies"] and out["inflow.point_m"] is None:
        raise SceneError("bodies = [] is invalid: at least one material body (or an inflow) is required")
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
            raise SceneError(f"bodies[{i}]: hi_m = {list(bhi)} must exceed lo_m = {list(blo)} on every axis")
        if np.any(blo < lo - 1e-9) or np.any(bhi > hi + 1e-9):
            raise SceneError(
                f"bodies[{i}] = [{list(blo)}, {list(bhi)}] lies outside the domain "
                f"[domain.lo_m, domain.hi_m] = [{list(lo)}, {list(hi)}] (m)"
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
    _validate_terrain(out, dim, lo)
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
    ter = raw.get("terrain")
    if isinstance(ter, dict) and isinstance(ter.get("csv"), str) and ter["csv"]:
        if "\x00" in ter["csv"]:
            raise SceneError(f"terrain.csv = {ter['csv']!r}: a file path cannot contain a NUL character")
        ter["csv"] = str((path.parent / ter["csv"]).resolve()) if not Path(ter["csv"]).is_absolute() else ter["csv"]
    return validate(raw)


def make_params(cfg: dict, dim: int | None = None, dtype="float32") -> Params:
    """Traced parameters from a validated scene dict."""
    dim = cfg["domain.dim"] if dim is None else dim
    dt = jnp.dtype(dtype)

    def a(key):
        return jnp.asarray(cfg[key], dt)

    model = cfg["material.model"]
    base = {"rho": a("material.density_kg_m3"), "kappa": a("material.bulk_modulus_pa")}
    if model == "newtonian":
        mat = _rheology.NewtonianParams(mu=a("material.viscosity_pa_s"), **base)
    elif model == "bingham":
        mat = _rheology.BinghamParams(
            mu=a("material.viscosity_pa_s"),
            tau_y=a("material.yield_stress_pa"),
            alpha_b=a("material.alpha_b"),
            m=a("material.papanastasiou_m_s"),
            **base,
        )
    elif model == "herschel_bulkley":
        mat = _rheology.HerschelBulkleyParams(
            tau_y=a("material.yield_stress_pa"),
            K=a("material.consistency_pa_sn"),
            n_hb=a("material.flow_index"),
            m=a("material.papanastasiou_m_s"),
            mu_max=a("material.mu_max_pa_s"),
            **base,
        )
    else:
        mat = _rheology.CoussotParams(
            mu0=a("material.mu0_pa_s"),
            alpha=a("material.alpha"),
            T=a("material.T_s"),
            n=a("material.n"),
            lambda0=a("material.lambda0"),
            mu_max=a("material.mu_max_pa_s"),
            **base,
        )
    g = cfg["gravity.g_m_s2"]
    th = math.radians(cfg["gravity.slope_deg"])
    ph = math.radians(cfg["gravity.transverse_slope_deg"])
    if dim == 2:
        gv = [g * math.sin(th), -g * math.cos(th)]
    else:
        gv = [g * math.sin(th), g * math.sin(ph), -g * math.cos(th) * math.cos(ph)]
    return Params(material=mat, gravity=jnp.asarray(gv, dt))


def make_rheology(cfg: dict):
    model = cfg["material.model"]
    if model == "bingham":
        return _rheology.Bingham(variant=cfg["material.bingham_variant"], shear_measure=cfg["material.shear_measure"])
    if model == "coussot":
        return _rheology.Coussot(integrator=cfg["material.lambda_integrator"])
    return _rheology.MODELS[model]()


def seed_bodies(cfg: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regular particle seeding: ``ppc`` per axis per cell.  Returns x (n, dim) [m],
    vol0 (n,) [m^dim] and v (n, dim) [m/s]."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    dx = h / ppc
    xs, vs = [np.zeros((0, dim))], [np.zeros((0, dim))]
    for b in cfg["bodies"]:
        lo, hi = np.asarray(b["lo_m"]), np.asarray(b["hi_m"])
        counts = np.maximum(np.round((hi - lo) / dx).astype(int), 1)
        axes = [lo[d] + (np.arange(counts[d]) + 0.5) * (hi[d] - lo[d]) / counts[d] for d in range(dim)]
        mesh = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)
        xs.append(mesh)
        vs.append(np.broadcast_to(np.asarray(b.get("velocity_m_s", [0.0] * dim), float), mesh.shape))
    x = np.concatenate(xs)
    # each body's particles fill it exactly: volume = body volume / count
    vols = [np.zeros(0)]
    for b, xb in zip(cfg["bodies"], xs[1:]):
        vols.append(np.full(len(xb), np.prod(np.asarray(b["hi_m"]) - np.asarray(b["lo_m"])) / len(xb)))
    return x, np.concatenate(vols), np.concatenate(vs)


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
    """
    mat = params.material
    rho, kappa = float(mat.rho), float(mat.kappa)
    h, dim = cfg["domain.cell_size_m"], cfg["domain.dim"]
    maxwell = cfg["numerics.viscous_update"] == "maxwell"
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
        visc = {
            "newtonian": ["material.viscosity_pa_s"],
            "bingham": [
                "material.viscosity_pa_s",
                "material.yield_stress_pa",
                "material.papanastasiou_m_s",
                "material.alpha_b",
            ],
        }.get(cfg["material.model"], ["material.mu_max_pa_s"])
        text += (
            f", numerics.viscous_safety = {cfg['numerics.viscous_safety']!r}, "
            + ", ".join(f"{k} = {cfg[k]!r}" for k in visc)
            + f" (material.model = {cfg['material.model']!r}: mu_max = {lim['mu_max_pa_s']!r} Pa s)"
        )
    return text


def build(cfg: dict) -> Setup:
    """Validated scene dict -> ``Setup`` (scene, params, initial state, info).

    A ``float64`` scene switches on ``jax_enable_x64`` (without it JAX would silently
    truncate every array to float32).
    """
    dim, h = cfg["domain.dim"], cfg["domain.cell_size_m"]
    dtype = cfg["numerics.dtype"]
    if dtype == "float64" and not jax.config.jax_enable_x64:
        jax.config.update("jax_enable_x64", True)
    params = make_params(cfg, dim, dtype)
    rheology = make_rheology(cfg)
    x, vol0, v = seed_bodies(cfg)
    n_bodies = len(x)
    inflow = None
    if cfg["inflow.point_m"] is not None:
        offs, area, _, n_layers, layer_dt, u, d = _inflow_layout(cfg, dim)
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
    ncell = np.round((hi - lo) / h).astype(int)
    origin = tuple(float(lo[a] - (0 if periodic[a] else ng * h)) for a in range(dim))
    shape = tuple(int(ncell[a] if periodic[a] else ncell[a] + 2 * ng + 1) for a in range(dim))
    walls = []
    for a in range(dim):
        for side, kind in zip((0, 1), faces[a]):
            if kind in WALL_KINDS:
                nrm = [0.0] * dim
                nrm[a] = 1.0 if side == 0 else -1.0
                pt = [0.0] * dim
                pt[a] = float(lo[a] if side == 0 else hi[a])
                walls.append(Wall(tuple(pt), tuple(nrm), kind))
    for p in cfg["boundary.planes"]:
        walls.append(Wall(tuple(map(float, p["point_m"])), tuple(map(float, p["normal"])), p.get("type", "noslip")))
    gate = None
    if cfg["gate.point_m"] is not None:
        gate = Gate(tuple(cfg["gate.point_m"]), tuple(cfg["gate.normal"]))
    elif inflow is not None and cfg["inflow.aging_gate"]:
        gate = Gate(inflow.point, inflow.direction)
    terrain = None
    if cfg["terrain.type"] != "none":
        hs = np.asarray(cfg["terrain.heights_m"], float)
        terrain = Terrain(
            origin=tuple(map(float, cfg["terrain.origin_m"])),
            spacing=(float(cfg["terrain.spacing_m"]),) * (dim - 1),
            heights=tuple(map(tuple, hs)) if hs.ndim == 2 else tuple(map(float, hs)),
            kind=cfg["terrain.type"],
            friction=float(cfg["terrain.friction"]),
        )
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
        transfer=cfg["numerics.transfer"],
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
    active = np.arange(len(x)) < n_bodies
    state = init_state(scene, params, x, vol0, np.where(active[:, None], v, 0.0), active=active)
    if inflow is not None and gate is not None and cfg["gate.point_m"] is None:
        # the exit gate holds only the pipe material back: initial bodies age from t = 0
        state = state._replace(gate=jnp.asarray(active))
    axis = cfg["output.runout_axis"]
    origin_r = cfg["output.runout_origin_m"]
    if math.isnan(origin_r):
        starts = [b["lo_m"][axis] for b in cfg["bodies"]]
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
    if inflow is not None:
        info.update(
            inflow_pool_particles=int(len(x) - n_bodies),
            inflow_speed_m_s=inflow.speed,
            inflow_layer_dt_s=inflow.layer_dt,
            inflow_volume_m3=float(np.sum(vol0[n_bodies:])),
            inflow_t_stop_s=inflow.t_stop,
        )
    return Setup(cfg=cfg, scene=scene, params=params, state=state, info=info)


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
