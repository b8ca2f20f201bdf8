"""A breach release: the pond behind a breach, seeded from a region in map coordinates and a pond
surface elevation, filled down to the terrain.

``release.region_map_m`` is a plan-view region in map coordinates (scene = map -
``terrain.map_origin_m``; docs/scenes.md): in 3D a box ``[xmin, ymin, xmax, ymax]`` or a polygon
``[[x, y], ...]`` (at least 3 vertices, even-odd rule), in 2D an interval ``[xmin, xmax]``.
``release.pond_level_m`` is the pond's surface elevation z [m].  The released material is every
point of the region with terrain z_b < z < pond level (the floor of the domain box where there is
no terrain).

Seeding (``seed_release``): the plan is cut into columns of the particle spacing s = h / ppc on the
lattice of the domain (centres lo + (i + 1/2) s); a column whose centre lies in the region and
whose pond depth d = pond - z_b(centre) is positive gets n = max(1, round(d / s)) particles
evenly spread over the depth (z_b + (k + 1/2) d / n), each of volume s^(dim-1) d / n.  The
seeded volume is therefore the midpoint rule of the geometric volume
V = integral over the region of max(0, pond - z_b) on the column lattice; ``geometric_volume``
evaluates the same integral on a lattice ``GEOMETRIC_SUBDIVISION`` times finer per axis (the
reference of summary.json's ``release`` figures; the two differ by the region's edge and the
curvature of the bilinear terrain on the scale of s).  Particles inside an earlier body box are
dropped (bodies and a release are seeded as their union, as overlapping bodies are).
"""

from __future__ import annotations

import math

import numpy as np

from . import _bodies

GEOMETRIC_SUBDIVISION = 8  # sub-columns per axis and particle column of the reference volume


def _finite(a) -> bool:
    """math.isfinite that is False, not OverflowError, for an int too large for a float (TOML and JSON
    integers are unbounded: the fuzz test found one)."""
    try:
        return math.isfinite(a)
    except OverflowError:
        return False


def region_error(val, dim: int) -> str | None:
    """None if ``val`` is a valid ``release.region_map_m`` for a ``dim``-D scene, else why not."""
    nums = isinstance(val, list) and all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in val)
    if dim == 2:
        if not (nums and len(val) == 2):
            return "expected [xmin, xmax] (map m) in a 2D scene"
        return None if _finite(val[0]) and _finite(val[1]) and val[0] < val[1] else "need finite xmin < xmax"
    if nums:
        if len(val) != 4:
            return "expected a box [xmin, ymin, xmax, ymax] or a polygon [[x, y], ...] (map m)"
        ok = all(_finite(a) for a in val) and val[0] < val[2] and val[1] < val[3]
        return None if ok else "a box needs finite xmin < xmax and ymin < ymax"
    pairs = isinstance(val, list) and all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in p)
        for p in val
    )
    if not pairs or len(val) < 3:
        return "expected a box [xmin, ymin, xmax, ymax] or a polygon of at least 3 vertices [[x, y], ...] (map m)"
    if not all(_finite(a) for p in val for a in p):
        return "vertices must be finite"
    return None


def region_polygon(region, map_origin, dim: int) -> np.ndarray:
    """The region in scene coordinates: 2D (2,) [xmin, xmax]; 3D a closed polygon (k, 2)."""
    o = np.zeros(dim - 1) if map_origin is None else np.asarray(map_origin, float)
    if dim == 2:
        return np.asarray(region, float) - o[0]
    r = np.asarray(region, float)
    if r.ndim == 1:
        r = np.array([[r[0], r[1]], [r[2], r[1]], [r[2], r[3]], [r[0], r[3]]])
    return r - o[None, :]


def _inside(poly: np.ndarray, xy: np.ndarray) -> np.ndarray:
    if poly.ndim == 1:
        return (xy[:, 0] >= poly[0]) & (xy[:, 0] < poly[1])
    # matplotlib's polygon test (a dependency), imported only when a polygon is seeded: a heavy import
    from matplotlib.path import Path as PolyPath

    return PolyPath(poly).contains_points(xy)


def _columns(poly: np.ndarray, lo, hi, s: float, sub: int = 1) -> np.ndarray:
    """Centres (m, dim-1) of the lattice columns of spacing s / sub (aligned to ``lo``) in the region."""
    ds = s / sub
    if poly.ndim == 1:
        b_lo, b_hi = [poly[0]], [poly[1]]
    else:
        b_lo, b_hi = poly.min(axis=0), poly.max(axis=0)
    axes = []
    for a in range(len(b_lo)):
        i0 = max(0, math.floor((b_lo[a] - lo[a]) / ds))
        i1 = min(math.ceil((hi[a] - lo[a]) / ds), math.ceil((b_hi[a] - lo[a]) / ds))
        axes.append(lo[a] + (np.arange(i0, max(i1, i0)) + 0.5) * ds)
    grid = np.meshgrid(*axes, indexing="ij")
    xy = np.stack([g.ravel() for g in grid], axis=1)
    return xy[_inside(poly, xy)] if len(xy) else xy


def seed_release(cfg: dict, height, bodies=()) -> tuple[np.ndarray, np.ndarray, dict]:
    """Particles of the release: positions (n, dim) [m], volumes (n,) [m^dim] and the figures
    summary.json reports (volumes, mass, the geometric reference and their difference).

    height: z_b [m] at plan positions (m, dim-1) (the terrain's ``height``, or the domain floor);
    bodies: the scene's bodies (``_bodies``), whose volume the release does not seed again."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    s = h / ppc
    pond = float(cfg["release.pond_level_m"])
    poly = region_polygon(cfg["release.region_map_m"], cfg["terrain.map_origin_m"], dim)
    lo, hi = cfg["domain.lo_m"][: dim - 1], cfg["domain.hi_m"][: dim - 1]
    xy = _columns(poly, lo, hi, s)
    depth = pond - np.asarray(height(xy), float) if len(xy) else np.zeros(0)
    wet = depth > 0
    xy, depth = xy[wet], depth[wet]
    n = np.maximum(1, np.round(depth / s)).astype(int)
    col = np.repeat(np.arange(len(n)), n)
    k = np.arange(col.size) - np.repeat(np.cumsum(n) - n, n)
    zb = pond - depth
    z = zb[col] + (k + 0.5) * depth[col] / n[col]
    x = np.concatenate([xy[col], z[:, None]], axis=1)
    vol = s ** (dim - 1) * depth[col] / n[col]
    keep = np.ones(len(x), bool)
    for b in bodies:
        keep &= ~_bodies.contains(b, x)
    x, vol = x[keep], vol[keep]
    v_geo = geometric_volume(cfg, height)
    rho = float(cfg["material.density_kg_m3"])
    v_seed = float(vol.sum())
    unit = "m^3" if dim == 3 else "m^2 per metre of depth"
    info = {
        "volume_m3": v_seed,
        "mass_kg": rho * v_seed,
        "geometric_volume_m3": v_geo,
        "geometric_mass_kg": rho * v_geo,
        "volume_relative_error": (v_seed - v_geo) / v_geo if v_geo > 0 else None,
        "volume_unit": unit,
        "mass_unit": "kg" if dim == 3 else "kg per metre of depth",
        "particles": int(len(x)),
        "columns": int(len(n)),
        "pond_level_m": pond,
        "region_map_m": cfg["release.region_map_m"],
        "max_depth_m": float(depth.max()) if len(depth) else 0.0,
        "definition": (
            "released volume: the particles' rest volumes (columns of the particle spacing "
            f"{s:g} m, filled from the terrain to the pond level); geometric volume: the integral of "
            f"max(0, pond level - terrain) over the region on a lattice {GEOMETRIC_SUBDIVISION}x finer per axis"
        ),
    }
    return x, vol, info


def wet_columns(cfg: dict, height) -> int:
    """How many of the release's particle columns (spacing h / ppc) have the pond above the terrain: the
    particles the depth-averaged formulation seeds for it (one a column), for the memory estimate."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    poly = region_polygon(cfg["release.region_map_m"], cfg["terrain.map_origin_m"], dim)
    xy = _columns(poly, cfg["domain.lo_m"][: dim - 1], cfg["domain.hi_m"][: dim - 1], h / ppc)
    if not len(xy):
        return 0
    return int(np.count_nonzero(float(cfg["release.pond_level_m"]) > np.asarray(height(xy), float)))


def geometric_volume(cfg: dict, height) -> float:
    """The volume [m^3; 2D: m^2] between the terrain and the pond level over the region: the
    integral of max(0, pond - z_b) on columns ``GEOMETRIC_SUBDIVISION`` times finer per axis
    than the particle spacing (midpoint rule, region membership per sub-column)."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    s = h / ppc
    sub = GEOMETRIC_SUBDIVISION
    poly = region_polygon(cfg["release.region_map_m"], cfg["terrain.map_origin_m"], dim)
    lo, hi = cfg["domain.lo_m"][: dim - 1], cfg["domain.hi_m"][: dim - 1]
    xy = _columns(poly, lo, hi, s, sub)
    if not len(xy):
        return 0.0
    depth = np.maximum(0.0, float(cfg["release.pond_level_m"]) - np.asarray(height(xy), float))
    return float(depth.sum() * (s / sub) ** (dim - 1))
