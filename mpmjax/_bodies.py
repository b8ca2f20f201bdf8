"""Geometry of the material bodies of a scene (``[[bodies]]``): which points a body holds, its
bounding box and its exact volume.

Types (their keys, units and ranges are in the scene schema, ``_schema.keys.BODY_KEYS``):

* ``box`` (any dimension): ``lo_m``, ``hi_m``; seeded on its own lattice (``_build.seed_bodies``,
  unchanged: each particle holds the box's volume / its particle count);
* ``cylinder`` (3D): axis-aligned along ``axis`` (default: the vertical), base centre ``base_m``
  (the centre of its end face at the low end along the axis), ``radius_m``, ``height_m``;
* ``cone`` (3D): a truncated cone, as the cylinder with radius ``radius_m`` at the base and
  ``top_radius_m`` (<= ``radius_m``; 0: a full cone) at the other end;
* ``polygon`` (2D): a simple polygon ``vertices_m`` [[x, y], ...] (either orientation);
* ``mesh`` (3D): a closed triangle mesh read from ``file`` (STL or OBJ, with trimesh), its
  coordinates times ``scale`` plus ``offset_m`` in metres.  Inside is trimesh's ray-parity test
  (``contains_points``: a ray each way from every point, the two must agree; the degenerate rays
  through edges and vertices are the library's business, not this module's).  A lattice point
  exactly on a mesh face may go either way (trimesh leaves it undefined), unlike the other shapes.

Shaped bodies (all but ``box``) are seeded on the domain's particle lattice: the points
domain.lo_m + (i + 1/2) s on every axis, s = h / ppc, that lie inside the shape (a point on its
surface counts as inside), each holding the lattice volume s^dim.  The lattice is the one a box
spanning the whole domain would have, so a body cut by a symmetry wall through its axis (a
quarter or half cylinder against symmetry walls) is seeded up to the wall with no gap or overlap.
The seeded volume differs from the exact one only by the cells the surface cuts: every lattice
cell (the cube of side s around a point) whose centre is inside lies within s sqrt(dim) / 2 of the
shape, so |seeded - exact| <= A s sqrt(dim) / 2 for a convex shape of surface area A (the band of
that half-width on both sides), and faces on the lattice planes (the domain walls) do not
count; in practice the cut cells' errors cancel and it is far smaller (tests/test_bodies.py).
Particles keep the lattice volume rather than being scaled to the exact volume so that they pack
at the density their J says (the project's overpacking measurements assume it).
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np

SHAPED = ("cylinder", "cone", "polygon", "mesh")


def kind(b: dict) -> str:
    return b.get("type", "box")


def _axis(b: dict, dim: int) -> int:
    a = b.get("axis")
    return dim - 1 if a is None else int(a)


def _radii(b: dict) -> tuple[float, float]:
    r0 = float(b["radius_m"])
    r1 = float(b.get("top_radius_m", r0)) if kind(b) == "cone" else r0
    return r0, r1


def bounds(b: dict, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The body's bounding box (lo, hi) [m]."""
    t = kind(b)
    if t == "box":
        return np.asarray(b["lo_m"], float), np.asarray(b["hi_m"], float)
    if t == "polygon":
        v = np.asarray(b["vertices_m"], float)
        return v.min(axis=0), v.max(axis=0)
    if t == "mesh":
        lo, hi = load_mesh(b).bounds
        return np.array(lo, float), np.array(hi, float)
    a = _axis(b, dim)
    base = np.asarray(b["base_m"], float)
    r = max(_radii(b))
    lo, hi = base - r, base + r
    lo[a], hi[a] = base[a], base[a] + float(b["height_m"])
    return lo, hi


def start(cfg: dict, b: dict, axis: int) -> float:
    """Where a body starts along ``axis`` [m]: the low side of its bounding box, inside the domain
    (the default runout origin)."""
    return max(float(bounds(b, cfg["domain.dim"])[0][axis]), float(cfg["domain.lo_m"][axis]))


def volume(b: dict, dim: int) -> float:
    """The exact volume [m^3; 2D: m^2 per metre of depth] of the whole shape (not cut by the domain)."""
    t = kind(b)
    if t == "box":
        lo, hi = bounds(b, dim)
        return float(np.prod(hi - lo))
    if t == "polygon":
        return abs(polygon_area(np.asarray(b["vertices_m"], float)))
    if t == "mesh":
        return float(load_mesh(b).volume)
    r0, r1 = _radii(b)
    return math.pi * float(b["height_m"]) * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0


def contains(b: dict, x: np.ndarray) -> np.ndarray:
    """Which of the points x (n, dim) lie inside the body or on its surface."""
    x = np.asarray(x, float)
    dim = x.shape[1]
    t = kind(b)
    if t == "box":
        lo, hi = bounds(b, dim)
        return np.all((x >= lo) & (x <= hi), axis=1)
    if t == "polygon":
        return polygon_contains(np.asarray(b["vertices_m"], float), x)
    if t == "mesh":
        return mesh_contains(load_mesh(b), x)
    a = _axis(b, dim)
    base = np.asarray(b["base_m"], float)
    H = float(b["height_m"])
    r0, r1 = _radii(b)
    d = x - base
    along = d[:, a]
    radial = np.delete(d, a, axis=1)
    rr = np.einsum("ij,ij->i", radial, radial)
    frac = np.clip(along / H, 0.0, 1.0)
    r = r0 + (r1 - r0) * frac
    return (along >= 0.0) & (along <= H) & (rr <= r * r * (1 + 1e-12))


def lattice(cfg: dict, b: dict) -> np.ndarray:
    """The points of the domain's particle lattice inside a shaped body (module docstring):
    positions (n, dim) [m]; each holds the lattice volume (h / ppc)^dim."""
    dim, h, ppc = cfg["domain.dim"], cfg["domain.cell_size_m"], cfg["numerics.ppc"]
    s = h / ppc
    dlo, dhi = np.asarray(cfg["domain.lo_m"], float), np.asarray(cfg["domain.hi_m"], float)
    blo, bhi = bounds(b, dim)
    blo, bhi = np.maximum(blo, dlo), np.minimum(bhi, dhi)
    axes = []
    n_max = np.round((dhi - dlo) / s).astype(int)
    for d in range(dim):
        i0 = max(0, math.floor((blo[d] - dlo[d]) / s - 0.5))
        i1 = min(int(n_max[d]), math.ceil((bhi[d] - dlo[d]) / s + 0.5))
        axes.append(dlo[d] + (np.arange(i0, max(i0, i1)) + 0.5) * s)
    mesh = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=-1)
    return mesh[contains(b, mesh)] if len(mesh) else np.zeros((0, dim))


def lattice_count_bound(cfg: dict, b: dict) -> float:
    """An upper bound on the particles of a body, from its bounding box (for the particle limit
    and the memory estimate, before anything is seeded)."""
    dim = cfg["domain.dim"]
    s = cfg["domain.cell_size_m"] / cfg["numerics.ppc"]
    lo, hi = bounds(b, dim)
    with np.errstate(all="ignore"):
        return float(np.prod(np.floor((hi - lo) / s) + 2.0))


# --- triangle meshes (trimesh) -------------------------------------------------------------------

MESH_SUFFIXES = (".stl", ".obj")
# The ray direction of the inside test: nearly vertical, so that each ray's bounding box (which
# trimesh's r-tree queries for candidate triangles) is a thin column: ~45 us a point against ~1 ms
# with trimesh's default diagonal (icosphere of 1280 faces: 85k points in 3.7 s, 64k in 69 s);
# tilted off the axes so that it never runs inside an axis-aligned face.
_RAY = np.array([0.0123456789, 0.0234567891, 1.0])
_CHUNK = 100_000  # points per ray batch (memory)


class MeshError(ValueError):
    """A mesh file that cannot be used; the message says why (validation adds the key)."""


def load_mesh(b: dict):
    """The body's trimesh.Trimesh, scaled and offset (cached per file, its modification time, scale
    and offset).  Raises MeshError: unreadable, not a triangle mesh, not closed."""
    path = str(b["file"])
    try:
        stamp = os.stat(path).st_mtime_ns
    except OSError as e:
        raise MeshError(f"cannot be read: {e.strerror or e}") from None
    offset = tuple(float(a) for a in (b.get("offset_m") or (0.0, 0.0, 0.0)))
    return _load_mesh(path, stamp, float(b.get("scale", 1.0)), offset)


@functools.lru_cache(maxsize=8)
def _load_mesh(path: str, _stamp: int, scale: float, offset: tuple):
    import trimesh  # heavy (about 1 s): only when a scene has a mesh body

    suffix = os.path.splitext(path)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"the file type {suffix or '(none)'!r} is not a mesh format; allowed: .stl or .obj")
    try:
        mesh = trimesh.load(path, file_type=suffix[1:], force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for a bad file  # noqa: BLE001
        raise MeshError(f"cannot be read as {suffix[1:].upper()}: {type(e).__name__}: {e}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshError(f"holds no triangle mesh (read as {suffix[1:].upper()}: no faces)")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError("has non-finite vertex coordinates")
    if not mesh.is_watertight:
        raise MeshError(
            f"is not closed (not watertight: {len(mesh.faces)} faces, some edges not shared by exactly two faces); "
            "allowed: a closed triangle surface"
        )
    if mesh.volume < 0:  # inside-out winding: the same solid
        mesh.invert()
    mesh.apply_scale(scale)
    mesh.apply_translation(offset)
    if not mesh.volume > 0:
        raise MeshError("encloses no volume")
    return mesh


def mesh_contains(mesh, x: np.ndarray) -> np.ndarray:
    """Which of the points x (n, 3) lie inside the closed mesh (trimesh's ray parity, ``_RAY``)."""
    from trimesh.ray.ray_util import contains_points  # heavy: only when a scene has a mesh body

    x = np.asarray(x, float)
    out = np.zeros(len(x), bool)
    for i in range(0, len(x), _CHUNK):
        out[i : i + _CHUNK] = contains_points(mesh.ray, x[i : i + _CHUNK], check_direction=_RAY)
    return out


# --- polygons ------------------------------------------------------------------------------------


def polygon_area(v: np.ndarray) -> float:
    """Signed area (shoelace; > 0 counter-clockwise)."""
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_contains(v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points p (n, 2) inside the simple polygon v (m, 2) or on its boundary (even-odd rule, plus
    a distance test for the boundary)."""
    p = np.asarray(p, float)
    x, y = p[:, 0:1], p[:, 1:2]
    a, b = v, np.roll(v, -1, axis=0)
    ax, ay, bx, by = a[:, 0], a[:, 1], b[:, 0], b[:, 1]
    crosses = (ay > y) != (by > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = ax + (y - ay) * (bx - ax) / (by - ay)
    inside = np.sum(crosses & (x < xint), axis=1) % 2 == 1
    # on an edge (within a relative 1e-12 of the polygon's size): inside, as for the other shapes
    ex, ey = bx - ax, by - ay
    L2 = ex * ex + ey * ey
    t = np.clip(((x - ax) * ex + (y - ay) * ey) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    dist2 = (ax + t * ex - x) ** 2 + (ay + t * ey - y) ** 2
    scale = float(np.max(np.ptp(v, axis=0))) if len(v) else 1.0
    on_edge = np.any(dist2 <= (1e-12 * scale) ** 2, axis=1)
    return inside | on_edge


def _segments_cross(p1, p2, q1, q2) -> bool:
    """Whether the closed segments p1p2 and q1q2 intersect."""

    def orient(a, b, c):
        v = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return 0 if v == 0 else (1 if v > 0 else -1)

    def on(a, b, c):  # c on segment ab, given collinear
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    o1, o2, o3, o4 = orient(p1, p2, q1), orient(p1, p2, q2), orient(q1, q2, p1), orient(q1, q2, p2)
    if o1 != o2 and o3 != o4:
        return True
    return (
        (o1 == 0 and on(p1, p2, q1))
        or (o2 == 0 and on(p1, p2, q2))
        or (o3 == 0 and on(q1, q2, p1))
        or (o4 == 0 and on(q1, q2, p2))
    )


def polygon_self_intersection(v: np.ndarray) -> tuple[int, int] | None:
    """The first pair of edges (i, j) of the closed polygon v that touch or cross other than at
    the vertex two neighbouring edges share (also repeated vertices); None for a simple polygon."""
    m = len(v)
    pts = [tuple(map(float, p)) for p in v]
    for i in range(m):
        p1, p2 = pts[i], pts[(i + 1) % m]
        for j in range(i + 1, m):
            if j == i + 1 or (i == 0 and j == m - 1):  # neighbours share a vertex
                a, b, c = (p1, p2, pts[(j + 1) % m]) if j == i + 1 else (pts[j], p1, p2)
                back = (a[0] - b[0]) * (c[0] - b[0]) + (a[1] - b[1]) * (c[1] - b[1]) > 0
                if a == b or b == c or ((a[0] - b[0]) * (c[1] - b[1]) == (a[1] - b[1]) * (c[0] - b[0]) and back):
                    return (i, j)  # a zero-length edge, or an edge folded back onto its neighbour
                continue
            if _segments_cross(p1, p2, pts[j], pts[(j + 1) % m]):
                return (i, j)
    return None
