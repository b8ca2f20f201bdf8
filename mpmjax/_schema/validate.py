"""Validation: ``_check`` of one key's value against its ``Key``, and ``validate`` of a whole
scene (the cross-field checks: domain, bodies, planes, gate, inflow, terrain, release, material)."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np

from .. import _bodies, _dem, _quadrature, _release, _rheology, _shapes, _wall_yield
from .._boundary import inflow_layout
from .._scene import WALL_KINDS
from .keys import _REQ, BODY_KEYS, BODY_TYPES, Key, SceneError
from .table import SCHEMA, SECTIONS


def _flatten(d: dict, prefix="") -> dict:
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and key in SECTIONS:
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


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
    if spec.type == "points":  # a polygon's vertices: [[x, y], ...], at least 3
        ok = isinstance(val, (list, tuple)) and all(
            isinstance(p, (list, tuple))
            and len(p) == 2
            and all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in p)
            for p in val
        )
        if not ok:
            bad("expected a list of [x, y] pairs of numbers")
        if len(val) < 3:
            bad(f"a polygon needs at least 3 vertices, got {len(val)}")
        pts = [[_to_float(a) for a in p] for p in val]
        if not all(math.isfinite(a) for p in pts for a in p):
            bad("components must be finite")
        return pts
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
            for sub in ("lo_m", "hi_m", "velocity_m_s", "base_m", "radius_m", "top_radius_m", "height_m", "vertices_m"):
                v = b.get(sub)
                flat = v if isinstance(v, list) else [v]
                flat = [a for p in flat for a in (p if isinstance(p, list) else [p])]
                for a in flat:
                    if isinstance(a, (int, float)) and not isinstance(a, bool):
                        check(f"bodies[{i}].{sub}", _to_float(a), sub in ("radius_m", "height_m") and a != 0)


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
    if "terrain.turbulence_m_s2" in flat and kind != "voellmy":
        raise SceneError(
            f"terrain.turbulence_m_s2 = {_show(flat['terrain.turbulence_m_s2'])} is invalid with terrain.type = "
            f"{kind!r}: it is Voellmy's drag coefficient; allowed: terrain.type = 'voellmy' "
            "(model.formulation = 'depth-averaged'), or unset"
        )
    if kind == "none":
        given = [k for k in ("terrain.dem", *_DEM_ONLY) if k in flat]
        if given:
            raise SceneError(
                f"{given[0]} = {_show(flat[given[0]])} is invalid with terrain.type = 'none'; allowed: "
                "set terrain.type (noslip, slip, coulomb or voellmy) to use a DEM"
            )
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


def _one_rate_conflict(out: dict) -> str | None:
    """Why a cell's particles do not share one strain rate in 1/s here (the key and value that conflict, and what is
    allowed), or None where they do (``_wall_yield.applies``): the ground of both ``numerics.wall_yield = "wall"``
    and ``numerics.cell_shear = "series"``."""
    measure = out.get("material.shear_measure", "standard")
    if _wall_yield.applies(out["numerics.shape"], measure, out["model.formulation"]):
        return None
    if out["model.formulation"] == "depth-averaged":
        return f"model.formulation = {_show(out['model.formulation'])} (a column has no cell rows across its depth)"
    if out["numerics.shape"] not in _wall_yield.SHAPES:
        return (
            f"numerics.shape = {_show(out['numerics.shape'])} (it needs one strain rate per cell row); allowed: "
            f"numerics.shape = {' or '.join(repr(x) for x in _wall_yield.SHAPES)}"
        )
    return f"material.shear_measure = {_show(measure)} (it needs a shear rate in 1/s); allowed: material.shear_measure = 'standard'"


def _check_cell_shear(out: dict):
    """numerics.cell_shear = "series" where a cell has no one rate (``_one_rate_conflict``): refused, naming the key
    that conflicts (the default, uniform, acts everywhere)."""
    why = _one_rate_conflict(out) if out["numerics.cell_shear"] == "series" else None
    if why is not None:
        raise SceneError(f"numerics.cell_shear = 'series' is invalid with {why}, or numerics.cell_shear = 'uniform'")


def _check_wall_yield(out: dict, given: dict):
    """numerics.wall_yield = "wall" where the wall row has no one rate (``_one_rate_conflict``): the default falls
    back to "cell"; a "wall" the scene sets itself is refused, naming the key that conflicts.  ``given``: the keys
    the scene set."""
    why = _one_rate_conflict(out) if out["numerics.wall_yield"] == "wall" else None
    if why is None:
        return
    if "numerics.wall_yield" in given:
        raise SceneError(f"numerics.wall_yield = 'wall' is invalid with {why}, or numerics.wall_yield = 'cell'")
    out["numerics.wall_yield"] = "cell"


def _check_pressure(out: dict):
    """numerics.pressure = incompressible keeps the volume itself: the particle-level volume devices
    and the slab decomposition (whose halos the grid solve does not exchange) are refused.  The
    depth-averaged step uses neither pressure; ``_validate_formulation`` checks its keys.  An ``optional``
    material parameter (the bulk modulus) is required wherever the step reads it
    (``_rheology.unused_parameters``)."""
    unused = _rheology.unused_parameters(out)
    for p in _rheology.MODELS[out["material.model"]].params:
        if p.optional and out[p.key] is None and p.name not in unused:
            raise SceneError(
                f"missing required key {p.key} with numerics.pressure = {out['numerics.pressure']!r} and "
                f"model.formulation = {out['model.formulation']!r} ({p.doc} Unit: {p.unit}); set it, or set "
                "numerics.pressure = 'incompressible' (the pressure solved on the grid, which does not use it)"
            )
    if out["numerics.stress_quadrature"] == "corrected":
        needs = (
            ("model.formulation", ("full",)),
            ("numerics.shape", _quadrature.SHAPES),
            ("numerics.force", ("gradient",)),
        )
        if out["numerics.devices"] > 1:
            needs += (("numerics.decomposition", ("replicated",)),)
        for key, allowed in needs:
            if out[key] not in allowed:
                raise SceneError(
                    f"{key} = {_show(out[key])} is invalid with numerics.stress_quadrature = 'corrected' (the "
                    "stress's smooth part is integrated against the grid's hat functions, on the whole grid); "
                    f"allowed: {', '.join(repr(a) for a in allowed)}, or numerics.stress_quadrature = 'particles'"
                )
    if out["model.formulation"] == "depth-averaged":
        return
    if out["numerics.pressure"] == "explicit":
        if out["numerics.void_closure"] != "off":
            raise SceneError(
                f"numerics.void_closure = {_show(out['numerics.void_closure'])} is invalid with numerics.pressure = "
                "'explicit' (it closes voids through the grid pressure's solve); allowed: 'off'"
            )
        return
    for key, off in (("numerics.volume_averaging", "none"), ("numerics.grid_density_cap", 0.0)):
        if out[key] != off:
            raise SceneError(
                f"{key} = {_show(out[key])} is invalid with numerics.pressure = 'incompressible' (the grid pressure "
                f"keeps the volume itself; the default since 2026-12-08); allowed: {off!r}, or set "
                "numerics.pressure = 'explicit' for the per-particle pressure it belongs to"
            )
    if out["numerics.devices"] > 1 and out["numerics.decomposition"] == "slab":
        raise SceneError(
            "numerics.decomposition = 'slab' is invalid with numerics.pressure = 'incompressible' (the pressure is "
            "solved on the whole grid); allowed: 'replicated', or set numerics.pressure = 'explicit'"
        )


def _validate_domain(out: dict):
    """The domain box: corners in order, a finite size, a cell count under the limit and a whole
    number of cells on every axis.  Returns the corners (arrays) and the cell size."""
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
    return lo, hi, h


def _validate_bodies(out: dict, dim: int, lo, hi, h):
    """The material bodies: at least one source of material, each of a known type with its keys
    (``BODY_KEYS``, ``BODY_TYPES``) inside the domain, and a particle count that int32 indices can
    number.  The validated bodies replace ``out["bodies"]`` (numbers as floats; a shaped body's
    axis filled in); a box keeps exactly the keys it was given."""
    if not out["bodies"] and out["inflow.point_m"] is None and out["release.region_map_m"] is None:
        raise SceneError(
            "bodies = [] is invalid: at least one material body (or an inflow, or a release.region_map_m) is required"
        )
    n_particles = 0
    faces = [(out[f"boundary.{'xyz'[a]}_lo"], out[f"boundary.{'xyz'[a]}_hi"]) for a in range(dim)]
    bodies = []
    for i, b in enumerate(out["bodies"]):
        btype = b.get("type", "box")
        if not isinstance(btype, str) or btype not in BODY_TYPES:
            raise SceneError(
                f"bodies[{i}].type = {_show(btype)} is invalid: allowed values: {', '.join(BODY_TYPES)} "
                f"({BODY_KEYS['type'].doc})"
            )
        dims, keys = BODY_TYPES[btype]
        if dim not in dims:
            raise SceneError(
                f"bodies[{i}].type = {btype!r} is invalid in a {dim}D scene (domain.dim = {dim}); allowed in "
                f"{dim}D: {', '.join(t for t, (d, _) in BODY_TYPES.items() if dim in d)}"
            )
        allowed = ("type", *keys, "velocity_m_s")
        extra = set(b) - set(allowed)
        if extra:
            raise SceneError(
                f"bodies[{i}]: unknown key(s) {sorted(map(str, extra))}; allowed"
                + ("" if btype == "box" else f" for type = {btype!r}")
                + f": {', '.join(allowed)}"
            )
        if btype == "box":
            vspec = Key("vec", None, "m", "body corner")
            blo = np.asarray(_check(f"bodies[{i}].lo_m", b.get("lo_m"), vspec, dim))
            bhi = np.asarray(_check(f"bodies[{i}].hi_m", b.get("hi_m"), vspec, dim))
            _check(
                f"bodies[{i}].velocity_m_s",
                b.get("velocity_m_s", [0.0] * dim),
                Key("vec", None, "m/s", "velocity"),
                dim,
            )
            if np.any(bhi <= blo):
                raise SceneError(f"bodies[{i}]: hi_m = {_plain(bhi)} must exceed lo_m = {_plain(blo)} on every axis")
            if np.any(blo < lo - 1e-9) or np.any(bhi > hi + 1e-9):
                raise SceneError(
                    f"bodies[{i}] = [{_plain(blo)}, {_plain(bhi)}] lies outside the domain "
                    f"[domain.lo_m, domain.hi_m] = [{_plain(lo)}, {_plain(hi)}] (m)"
                )
            n_particles += _body_particle_count(blo, bhi, h / out["numerics.ppc"])
            bodies.append(b)
            continue
        body = {"type": btype}
        for k in (*keys, "velocity_m_s"):
            spec = BODY_KEYS[k]
            if k in b:
                body[k] = _check(f"bodies[{i}].{k}", b[k], spec, dim)
            elif spec.default is _REQ:
                raise SceneError(
                    f"bodies[{i}] (type = {btype!r}) is missing the required key {k} ({spec.doc} Unit: {spec.unit})"
                )
        if "axis" in keys:
            body["axis"] = dim - 1 if body.get("axis") is None else body["axis"]
        if btype == "mesh":
            body.setdefault("scale", BODY_KEYS["scale"].default)
            body["offset_m"] = body.get("offset_m") or [0.0] * dim
        _check_shape(body, i, dim, lo, hi, h, faces)
        n_particles += _bodies.lattice_count_bound(out, body)
        bodies.append(body)
    out["bodies"] = bodies
    if n_particles > _MAX_PARTICLES:
        raise SceneError(
            f"bodies: {n_particles:.4g} particles at numerics.ppc = {out['numerics.ppc']} per cell and "
            f"domain.cell_size_m = {h}; the limit is {_MAX_PARTICLES} (int32 particle indices)"
        )


def _check_shape(body: dict, i: int, dim: int, lo, hi, h, faces):
    """Cross-key checks of a shaped body: a cone's top radius at most its base radius, a simple
    polygon of non-zero area, a mesh file that holds a closed triangle mesh, and the body inside the
    domain except across a symmetry face that its axis lies on (a half or quarter model)."""
    btype = body["type"]
    if btype == "cone" and body["top_radius_m"] > body["radius_m"]:
        raise SceneError(
            f"bodies[{i}].top_radius_m = {_show(body['top_radius_m'])} is invalid: allowed range: >= 0 and <= "
            f"bodies[{i}].radius_m = {_show(body['radius_m'])} (m; the cone narrows from its base to its top)"
        )
    if btype == "polygon":
        v = np.asarray(body["vertices_m"], float)
        cross = _bodies.polygon_self_intersection(v)
        if cross is not None:
            a, b = cross
            raise SceneError(
                f"bodies[{i}].vertices_m = {_show(body['vertices_m'])} is invalid: edges {a} and {b} (counting from "
                "0, edge k from vertex k to k + 1) touch or cross; allowed: a simple polygon (no edge meets another "
                "except its two neighbours at their shared vertices)"
            )
        if _bodies.polygon_area(v) == 0.0:
            raise SceneError(
                f"bodies[{i}].vertices_m = {_show(body['vertices_m'])} is invalid: the polygon has no area"
            )
    if btype == "mesh":
        try:
            _bodies.load_mesh(body)
        except _bodies.MeshError as e:
            raise SceneError(
                f"bodies[{i}].file = {_show(body['file'], 400)} is invalid: the file {e} (allowed: an STL or OBJ file "
                "holding a closed triangle mesh; relative paths are relative to the scene file)"
            ) from None
    blo, bhi = _bodies.bounds(body, dim)
    tol = 1e-6 * h
    for a in range(dim):
        for side, past in ((0, blo[a] < lo[a] - tol), (1, bhi[a] > hi[a] + tol)):
            if not past:
                continue
            face = ("lo", "hi")[side]
            wall = (lo, hi)[side][a]
            on_face = btype in ("cylinder", "cone") and a != body["axis"] and abs(body["base_m"][a] - wall) <= tol
            if faces[a][side] == "symmetry" and on_face:
                continue
            why = (
                f"boundary.{'xyz'[a]}_{face} = {faces[a][side]!r} is not a symmetry face"
                if on_face
                else "a body may pass a domain face only where it is a symmetry face and the body's axis lies on it"
            )
            raise SceneError(
                f"bodies[{i}] ({btype}, spanning [{_plain(blo)}, {_plain(bhi)}] m) lies outside the domain "
                f"[domain.lo_m, domain.hi_m] = [{_plain(lo)}, {_plain(hi)}] (m) along {'xyz'[a]}: {why}; allowed: "
                f"{'xyz'[a]} within [{lo[a]}, {hi[a]}] m"
            )


def _validate_slump(out: dict, dim: int, lo, h):
    """output.slump_test: one vertical cylinder standing on the domain floor of a 3D scene, under
    vertical gravity, with no other source of material (docs/slump-test.md)."""
    if not out["output.slump_test"]:
        return
    bodies = out["bodies"]
    need = (
        "allowed: a 3D scene (domain.dim = 3) whose one body is a cylinder with a vertical axis (type = 'cylinder', "
        "axis = 2) standing on the domain floor, no inflow or release, and gravity.slope_deg = "
        "gravity.transverse_slope_deg = 0"
    )
    what = None
    if dim != 3:
        what = f"domain.dim = {dim}"
    elif len(bodies) != 1 or _bodies.kind(bodies[0]) != "cylinder" or bodies[0]["axis"] != 2:
        what = f"bodies = {_show(bodies)}"
    elif out["inflow.point_m"] is not None or out["release.region_map_m"] is not None:
        what = "an inflow or a release.region_map_m is given"
    elif out["gravity.slope_deg"] != 0.0 or out["gravity.transverse_slope_deg"] != 0.0:
        what = f"gravity.slope_deg = {out['gravity.slope_deg']}, transverse = {out['gravity.transverse_slope_deg']}"
    elif abs(bodies[0]["base_m"][2] - lo[2]) > 1e-6 * h:
        what = f"bodies[0].base_m z = {bodies[0]['base_m'][2]} is not on the floor domain.lo_m z = {lo[2]} m"
    if what is not None:
        raise SceneError(f"output.slump_test = true is invalid with {what}; {need}")


def _validate_planes_and_gate(out: dict, dim: int):
    """The extra wall planes (point, usable normal, wall type) and the gate (point and normal together)."""
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


def _validate_axes(out: dict, dim: int):
    """The runout axis exists and periodic faces come in pairs."""
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


# model.formulation = "depth-averaged": the keys of the full model it does not take, with the value they must keep.
# numerics.pressure is not among them: the depth-averaged step uses neither value (its pressure is the column's
# hydrostatic rho g_n H, and its depth the column's volume over its area), so either is accepted
_DA_FIXED = {
    "numerics.volume_averaging": "none",
    "numerics.grid_density_cap": 0.0,
    "numerics.force": "gradient",
    "numerics.transfer": "apic",
    "numerics.devices": 1,
    "numerics.void_closure": "off",
}


def _validate_formulation(out: dict, dim: int, given: dict):
    """model.formulation = "depth-averaged" (``_shallow``): refuse what that step does not do, and in the full
    model what only that step does (Voellmy's drag, the bed's curvature term, column splitting: its default
    falls back to 0 there, a value the scene sets itself is refused).  ``given``: the keys the scene set."""
    if out["model.formulation"] != "depth-averaged":
        if out["terrain.type"] == "voellmy":
            raise SceneError(
                "terrain.type = 'voellmy' is invalid with model.formulation = 'full': Voellmy's drag is a basal "
                "closure of the depth-averaged formulation; allowed: none, noslip, slip, coulomb, or "
                "model.formulation = 'depth-averaged'"
            )
        if out["numerics.split_levels"] != 0:
            if "numerics.split_levels" in given:
                raise SceneError(
                    f"numerics.split_levels = {_show(out['numerics.split_levels'])} is invalid with model.formulation "
                    "= 'full': column splitting is the depth-averaged formulation's; allowed: 0 or unset, or "
                    "model.formulation = 'depth-averaged'"
                )
            out["numerics.split_levels"] = 0  # the depth-averaged default: not the full model's
        if out["numerics.depth_layers"] != 1:
            if "numerics.depth_layers" in given:
                raise SceneError(
                    f"numerics.depth_layers = {_show(out['numerics.depth_layers'])} is invalid with "
                    "model.formulation = 'full': layers across a column's depth are the depth-averaged formulation's "
                    "(the full model resolves the depth itself); allowed: 1 or unset, or model.formulation = "
                    "'depth-averaged'"
                )
            out["numerics.depth_layers"] = 1  # the depth-averaged default: not the full model's
        if out["model.bed_curvature"] != "centrifugal":
            raise SceneError(
                f"model.bed_curvature = {_show(out['model.bed_curvature'])} is invalid with model.formulation = "
                "'full': the full model follows the bed's curvature itself; allowed: unset, or "
                "model.formulation = 'depth-averaged'"
            )
        if out["model.internal_friction_deg"] is not None:
            raise SceneError(
                f"model.internal_friction_deg = {_show(out['model.internal_friction_deg'])} is invalid with "
                "model.formulation = 'full': the earth-pressure coefficient is the depth-averaged column's (the full "
                "model's stress is its law's); allowed: unset, or model.formulation = 'depth-averaged'"
            )
        return
    phi = out["model.internal_friction_deg"]
    if phi is not None:
        if out["terrain.type"] not in ("coulomb", "voellmy"):
            raise SceneError(
                f"model.internal_friction_deg = {_show(phi)} is invalid with terrain.type = "
                f"{_show(out['terrain.type'])}: Savage & Hutter's coefficient needs the bed's Coulomb friction; "
                "allowed: terrain.type = 'coulomb' or 'voellmy', or model.internal_friction_deg unset"
            )
        friction = out["terrain.friction"]
        if friction > math.tan(math.radians(phi)):  # the bed cannot be rougher than the material's own friction
            delta = math.degrees(math.atan(friction))
            top = SCHEMA["model.internal_friction_deg"].hi  # the key's own range
            allowed = (
                f"allowed range [{delta:.6g}, {top:g}] deg, or terrain.friction <= tan(phi) = "
                f"{math.tan(math.radians(phi)):.6g}"
                if delta <= top
                else f"allowed: terrain.friction <= tan({top:g} deg) = {math.tan(math.radians(top)):.6g} (the largest "
                "internal friction angle)"
            )
            raise SceneError(
                f"model.internal_friction_deg = {_show(phi)} is invalid with terrain.friction = {_show(friction)} "
                f"(a bed friction angle of {delta:.6g} deg, above it): the bed cannot be rougher than the material; "
                f"{allowed}"
            )
    why = "(model.formulation = 'depth-averaged': docs/depth-averaged.md, 'Missing')"
    for key, val in _DA_FIXED.items():
        if out[key] != val:
            raise SceneError(
                f"{key} = {_show(out[key])} is invalid with model.formulation = 'depth-averaged'; "
                f"allowed: {val!r} {why}"
            )
    if out["numerics.shape"] in _shapes.BOUNDARY_MODIFIED:
        raise SceneError(
            f"numerics.shape = {_show(out['numerics.shape'])} is invalid with model.formulation = 'depth-averaged'; "
            f"allowed: {', '.join(k for k in _shapes.STENCIL if k not in _shapes.BOUNDARY_MODIFIED)} {why}"
        )
    for a in range(dim - 1):
        for end in ("lo", "hi"):
            key = f"boundary.{'xyz'[a]}_{end}"
            if out[key] == "periodic":
                raise SceneError(
                    f"{key} = 'periodic' is invalid with model.formulation = 'depth-averaged'; allowed: noslip, slip, "
                    f"symmetry, open {why}"
                )
    if out["boundary.planes"]:
        raise SceneError(
            f"boundary.planes = {_show(out['boundary.planes'])} is invalid with model.formulation = 'depth-averaged'; "
            f"allowed: [] {why}"
        )
    for key in ("gate.point_m", "inflow.point_m"):
        if out[key] is not None:
            raise SceneError(
                f"{key} = {_show(out[key])} is invalid with model.formulation = 'depth-averaged'; allowed: unset {why}"
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
    _check_wall_yield(out, flat)
    _check_cell_shear(out)
    lo, hi, h = _validate_domain(out)
    if dim == 2:
        only3 = [k for k in flat if SCHEMA[k].only_3d]
        if only3:
            raise SceneError(
                f"{', '.join(f'{k} = {_show(flat[k])}' for k in only3)} is invalid in a 2D scene (domain.dim = 2): "
                "allowed only in 3D scenes (domain.dim = 3); remove it"
            )
    _validate_material(flat, out)
    _validate_bodies(out, dim, lo, hi, h)
    _validate_slump(out, dim, lo, h)
    _validate_planes_and_gate(out, dim)
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
    _validate_axes(out, dim)
    _validate_formulation(out, dim, flat)
    if out["numerics.split_levels"] == 0 and "numerics.split_pool" not in flat:
        # no spare slots without splitting: the pool's default (3 since stop 65, 1 before) has nothing to size, so it
        # is held at the old 1 there and the configuration (its hash: checkpoints, validate's records) does not move
        out["numerics.split_pool"] = 1.0
    return out
