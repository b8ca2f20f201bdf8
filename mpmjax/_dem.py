"""Terrain from a DEM raster, and rasters written back on the map.

Rasters (``read_raster``): an ESRI ASCII grid (``.asc``: a documented text format, parsed with
numpy; its CRS from a ``.prj`` file beside it, as ESRI writes it) or a GeoTIFF (``.tif`` /
``.tiff``, read with rasterio, which carries the transform and the CRS).  A pixel's value is the
elevation at the pixel's centre [m]; no-data pixels are NaN.  Rotated or sheared rasters are refused.

Coordinate convention (docs/scenes.md, docs/output.md): **scene coordinates = map coordinates -
``terrain.map_origin_m``** on the horizontal axes (x east, y north, metres of the raster's CRS,
which must be projected); **z is the elevation in metres**, the same number in the scene and on
the map (no vertical offset).  The map origin defaults to the lower-left corner of the crop
window (``terrain.crop_map_m``) or, without one, of the raster.

``terrain_samples`` turns a raster into the existing height-map boundary (``_scene.Terrain``):
samples at the pixel centres (x along the columns, y from south to north), or, with
``terrain.resample = "bilinear"``, the raster interpolated bilinearly onto the grid nodes of the
domain (spacing h), where the boundary condition is evaluated.  ``map_info`` is the metadata
every output carries so it can be placed back on the map; ``write_raster`` writes a plan-view
map (GeoTIFF with rasterio, or an ESRI ASCII grid) in map coordinates.

Errors are ``SceneError`` naming the file and what is wrong (exit status 2 from the CLI).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import rasterio  # GeoTIFF with its transform and CRS, read and written (pyproject.toml)
from rasterio.crs import CRS
from rasterio.errors import CRSError
from rasterio.transform import Affine

from ._scene import Terrain

NODATA = -9999.0  # no-data value of the rasters written here


class _Error(ValueError):
    """Raised inside this module; ``_schema`` turns it into a ``SceneError`` (no import cycle)."""


@dataclasses.dataclass(frozen=True)
class Raster:
    """A north-up raster: ``z`` (nrows, ncols) [m], row 0 the northernmost, NaN where no data;
    ``left``, ``top``: map coordinates of the outer upper-left corner [m]; ``dx``, ``dy``: pixel
    width and height [m] (> 0); ``crs_wkt`` / ``epsg``: the CRS when known; ``path``."""

    z: np.ndarray
    left: float
    top: float
    dx: float
    dy: float
    crs_wkt: str | None
    epsg: int | None
    path: str

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the raster's outer extent [m]."""
        nr, nc = self.z.shape
        return self.left, self.top - nr * self.dy, self.left + nc * self.dx, self.top


def _asc_header(lines: list[str], path) -> tuple[dict, int]:
    head = {}
    k = 0
    for k, line in enumerate(lines):
        parts = line.split()
        if len(parts) == 2 and parts[0][:1].isalpha():
            head[parts[0].lower()] = parts[1]
        else:
            break
    else:
        k = len(lines)
    need = {"ncols", "nrows", "cellsize"}
    if not need <= set(head) or not ({"xllcorner", "xllcenter"} & set(head)) or not (
        {"yllcorner", "yllcenter"} & set(head)
    ):
        raise _Error(
            f"{path}: not an ESRI ASCII grid: the header must give ncols, nrows, xllcorner (or xllcenter), "
            f"yllcorner (or yllcenter) and cellsize; found {sorted(head)}"
        )
    return head, k


def _read_asc(path: Path) -> Raster:
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise _Error(f"{path}: cannot be read as an ESRI ASCII grid: {e}") from None
    head, k = _asc_header(lines, path)
    try:
        nc, nr = int(head["ncols"]), int(head["nrows"])
        cs = float(head["cellsize"])
        nodata = float(head.get("nodata_value", "nan"))
        corner = "xllcorner" in head
        x = float(head["xllcorner" if corner else "xllcenter"])
        y = float(head["yllcorner" if "yllcorner" in head else "yllcenter"])
        z = np.array(" ".join(lines[k:]).split(), dtype=float)
    except ValueError as e:
        raise _Error(f"{path}: not an ESRI ASCII grid: {e}") from None
    if not (nc >= 2 and nr >= 2 and math.isfinite(cs) and cs > 0):
        raise _Error(f"{path}: ncols = {nc}, nrows = {nr}, cellsize = {cs}: need at least 2 x 2 pixels of size > 0")
    if z.size != nc * nr:
        raise _Error(f"{path}: the header says {nrows_ncols(nr, nc)} = {nr * nc} values; the file holds {z.size}")
    z = z.reshape(nr, nc)
    z[(z == nodata) | ~np.isfinite(z)] = np.nan
    if not corner:  # centre of the lower-left pixel -> its outer corner
        x, y = x - 0.5 * cs, y - 0.5 * cs
    prj = path.with_suffix(".prj")
    wkt, epsg = (None, None)
    if prj.is_file():
        wkt, epsg = parse_crs(prj.read_text(errors="replace").strip(), f"{prj} (the CRS of {path.name})")
    return Raster(z, x, y + nr * cs, cs, cs, wkt, epsg, str(path))


def nrows_ncols(nr, nc) -> str:
    return f"nrows x ncols = {nr} x {nc}"


def _read_tif(path: Path) -> Raster:
    try:
        with rasterio.open(path) as src:
            t = src.transform
            z = src.read(1, masked=True).astype(float).filled(np.nan)
            crs = src.crs
    except rasterio.errors.RasterioError as e:
        raise _Error(f"{path}: cannot be read as a GeoTIFF: {e}") from None
    if t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
        raise _Error(
            f"{path}: the raster is rotated, sheared or not north-up (transform {tuple(t)[:6]}); allowed: a north-up "
            "raster (warp it first, e.g. gdalwarp)"
        )
    if min(z.shape) < 2:
        raise _Error(f"{path}: {nrows_ncols(*z.shape)}: need at least 2 x 2 pixels")
    z[~np.isfinite(z)] = np.nan
    wkt, epsg = (None, None)
    if crs is not None:
        wkt, epsg = crs.to_wkt(), crs.to_epsg()
    return Raster(z, float(t.c), float(t.f), float(t.a), float(-t.e), wkt, epsg, str(path))


def read_raster(path) -> Raster:
    """A DEM raster from an ESRI ASCII grid (.asc) or a GeoTIFF (.tif, .tiff)."""
    path = Path(path)
    try:
        found = path.is_file()
    except OSError as e:  # e.g. a name too long
        raise _Error(f"{path}: cannot be read: {e.strerror or e}") from None
    if not found:
        raise _Error(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".asc":
        return _read_asc(path)
    if suffix in (".tif", ".tiff"):
        return _read_tif(path)
    raise _Error(f"{path}: unknown raster type {suffix!r}; allowed: .asc (ESRI ASCII grid), .tif or .tiff (GeoTIFF)")


def parse_crs(text: str, where: str) -> tuple[str, int | None]:
    """(WKT, EPSG code or None) of a CRS given as 'EPSG:n' or WKT (checked with rasterio)."""
    try:
        crs = CRS.from_user_input(text)
    except CRSError as e:
        raise _Error(f"{where} = {text[:80]!r} is not a CRS rasterio understands ('EPSG:32719' or WKT): {e}") from None
    if not crs.is_projected:
        raise _Error(
            f"{where}: the CRS {crs.to_string()[:80]!r} is not projected; allowed: a projected CRS in metres (the "
            "scene's x and y are metres on the map; reproject geographic rasters first, e.g. gdalwarp -t_srs)"
        )
    return crs.to_wkt(), crs.to_epsg()


def crop(r: Raster, window) -> Raster:
    """The pixels of ``r`` whose centres lie in ``window`` = (xmin, ymin, xmax, ymax) [map m],
    widened by half a pixel (so a window on pixel edges keeps exactly the pixels inside it).
    A window not inside the raster's extent is an error."""
    xmin, ymin, xmax, ymax = map(float, window)
    b = r.bounds
    tol = 1e-6 * max(r.dx, r.dy)
    if not (xmin < xmax and ymin < ymax):
        raise _Error(
            f"terrain.crop_map_m = {list(window)}: allowed: [xmin, ymin, xmax, ymax] with xmin < xmax, ymin < ymax"
        )
    if xmin < b[0] - tol or ymin < b[1] - tol or xmax > b[2] + tol or ymax > b[3] + tol:
        raise _Error(
            f"terrain.crop_map_m = {list(window)} lies (partly) outside the raster {r.path}, whose extent is "
            f"[{b[0]:.10g}, {b[1]:.10g}, {b[2]:.10g}, {b[3]:.10g}] (xmin, ymin, xmax, ymax, map m); "
            "allowed: a window inside it"
        )
    nr, nc = r.z.shape
    xc = r.left + (np.arange(nc) + 0.5) * r.dx
    yc = r.top - (np.arange(nr) + 0.5) * r.dy
    cols = np.nonzero((xc >= xmin - 0.5 * r.dx - tol) & (xc <= xmax + 0.5 * r.dx + tol))[0]
    rows = np.nonzero((yc >= ymin - 0.5 * r.dy - tol) & (yc <= ymax + 0.5 * r.dy + tol))[0]
    if len(cols) < 2 or len(rows) < 2:
        raise _Error(f"terrain.crop_map_m = {list(window)} holds fewer than 2 x 2 pixels of {r.path}")
    z = r.z[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    return dataclasses.replace(r, z=z, left=r.left + cols[0] * r.dx, top=r.top - rows[0] * r.dy)


def _samples(r: Raster, origin) -> tuple[np.ndarray, tuple[float, float]]:
    """Heights (ncols, nrows) in scene (x, y) order (y from south to north) and the scene position of
    the first sample (the centre of the south-west pixel) [m]."""
    nr, _ = r.z.shape
    z = r.z[::-1, :].T
    first = (r.left + 0.5 * r.dx - origin[0], r.top - (nr - 0.5) * r.dy - origin[1])
    return z, first


def terrain_samples(cfg: dict, path: Path) -> dict:
    """From ``terrain.dem`` and the other ``terrain.*`` keys of a (3D) scene: the terrain keys the
    height-map boundary reads (``terrain.heights_m`` (nx, ny) [m], ``terrain.origin_m`` [scene m],
    ``terrain.spacing_m`` [m]) and the map keys (``terrain.map_origin_m``, ``terrain.crs``) filled
    in.  Checks that the domain lies inside the raster (and the crop window) and that no pixel the
    boundary reads under the domain is no-data."""
    r = read_raster(path)
    if cfg["terrain.crs"]:
        wkt, epsg = parse_crs(cfg["terrain.crs"], "terrain.crs")
        if r.crs_wkt is not None and epsg != r.epsg and wkt != r.crs_wkt:
            raise _Error(
                f"terrain.crs = {cfg['terrain.crs'][:80]!r} differs from the CRS of {path} (EPSG {r.epsg}); "
                "allowed: leave terrain.crs out for a raster that has a CRS"
            )
        r = dataclasses.replace(r, crs_wkt=wkt, epsg=epsg)
    elif r.crs_wkt is not None:
        r = dataclasses.replace(r, crs_wkt=parse_crs(r.crs_wkt, f"the CRS of {path}")[0])
    window = cfg["terrain.crop_map_m"]
    if window is not None:
        r = crop(r, window)
        corner = (float(window[0]), float(window[1]))
    else:
        corner = (r.bounds[0], r.bounds[1])
    origin = cfg["terrain.map_origin_m"]
    origin = corner if origin is None else (float(origin[0]), float(origin[1]))
    lo, hi, h = cfg["domain.lo_m"], cfg["domain.hi_m"], cfg["domain.cell_size_m"]
    ext = (window if window is not None else r.bounds)
    dom = (lo[0] + origin[0], lo[1] + origin[1], hi[0] + origin[0], hi[1] + origin[1])
    tol = 1e-6 * max(r.dx, r.dy)
    if dom[0] < ext[0] - tol or dom[1] < ext[1] - tol or dom[2] > ext[2] + tol or dom[3] > ext[3] + tol:
        what = "the crop window terrain.crop_map_m" if window is not None else f"the raster {path}"
        raise _Error(
            f"the domain's plan [{dom[0]:.10g}, {dom[1]:.10g}, {dom[2]:.10g}, {dom[3]:.10g}] "
            "(map m: domain.lo_m/hi_m + "
            f"terrain.map_origin_m = {list(origin)}) is not inside {what}, [{ext[0]:.10g}, {ext[1]:.10g}, "
            f"{ext[2]:.10g}, {ext[3]:.10g}] (xmin, ymin, xmax, ymax); allowed: a domain inside it "
            "(scene = map - origin)"
        )
    z, first = _samples(r, origin)
    # the samples the bilinear boundary reads under the domain: one pixel beyond its plan on each side
    sp = (r.dx, r.dy)
    used = []
    for a in range(2):
        u_lo = math.floor((lo[a] - first[a]) / sp[a]) - 1
        u_hi = math.ceil((hi[a] - first[a]) / sp[a]) + 1
        used.append(slice(max(u_lo, 0), min(u_hi, z.shape[a] - 1) + 1))
    sub = z[used[0], used[1]]
    holes = np.argwhere(np.isnan(sub))
    if holes.size:
        i, j = holes[0] + [used[0].start, used[1].start]
        xm, ym = first[0] + i * sp[0] + origin[0], first[1] + j * sp[1] + origin[1]
        raise _Error(
            f"{path}: {len(holes)} no-data pixel(s) under the domain, the first at map ({xm:.10g}, {ym:.10g}); "
            "allowed: a DEM without holes there (fill them, e.g. gdal_fillnodata, or move the domain or crop window)"
        )
    z, first = sub, (first[0] + used[0].start * sp[0], first[1] + used[1].start * sp[1])
    if cfg["terrain.resample"] == "bilinear":
        ter = Terrain(origin=first, spacing=sp, heights=z, kind="slip")
        axes = [lo[a] + h * np.arange(int(round((hi[a] - lo[a]) / h)) + 1) for a in range(2)]
        gx, gy = np.meshgrid(*axes, indexing="ij")
        z = ter.height(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape)
        first, spacing = (float(lo[0]), float(lo[1])), float(h)
    elif abs(r.dx - r.dy) > 1e-9 * r.dx:
        raise _Error(
            f"{path}: pixels of {r.dx:g} m x {r.dy:g} m; the height-map boundary needs square pixels: set "
            'terrain.resample = "bilinear" (samples at the grid nodes)'
        )
    else:
        spacing = float(r.dx)
    return {
        "terrain.heights_m": np.asarray(z, float).tolist(),
        "terrain.origin_m": [float(first[0]), float(first[1])],
        "terrain.spacing_m": spacing,
        "terrain.map_origin_m": [float(origin[0]), float(origin[1])],
        "terrain.crs": r.crs_wkt or "",
        "raster": {
            "path": str(path),
            "bounds_map_m": list(r.bounds),
            "pixel_m": [r.dx, r.dy],
            "epsg": r.epsg,
        },
    }


CONVENTION = (
    "scene coordinates = map coordinates - map_origin_m on the horizontal axes (x east, y north, metres of the "
    "CRS); z is the elevation in metres in both"
)


def map_info(cfg: dict) -> dict | None:
    """The map metadata of a scene (``summary.json`` ``map``, ``result.h5`` attribute ``map_json``):
    the map origin, the CRS (WKT and EPSG code when known), the DEM and its crop window and
    resampling, and the convention.  None for a scene without map coordinates (no DEM and no
    ``terrain.map_origin_m``)."""
    if not cfg.get("terrain.dem") and cfg.get("terrain.map_origin_m") is None:
        return None
    crs = cfg.get("terrain.crs") or ""
    epsg = None
    if crs:
        epsg = CRS.from_user_input(crs).to_epsg()
    return {
        "map_origin_m": cfg["terrain.map_origin_m"],
        "crs_wkt": crs or None,
        "epsg": epsg,
        "dem": cfg.get("terrain.dem") or None,
        "crop_map_m": cfg.get("terrain.crop_map_m"),
        "resample": cfg.get("terrain.resample", "none"),
        "convention": CONVENTION,
    }


def _north_up(left, top, cell):
    """The north-up transform of square ``cell`` [m] pixels from the top-left corner (``left``, ``top``):
    rasterio's ``from_origin`` written out: its ``*`` composition warns (affine 3.0 deprecates ``*`` for ``@``)."""
    return Affine(cell, 0.0, left, 0.0, -cell, top)


def write_raster(path, values, left: float, top: float, cell: float, crs_wkt: str | None, fmt: str) -> Path:
    """Write a plan-view map to ``path`` (suffix set by ``fmt``: ``geotiff`` -> .tif with rasterio,
    ``ascii`` -> .asc, with a .prj beside it when the CRS is known).

    values: (nrows, ncols) [row 0 north], NaN where no data (written as ``NODATA``);
    left, top: map coordinates of the outer upper-left corner [m]; cell: pixel size [m].
    Returns the path written."""
    z = np.where(np.isfinite(values), values, NODATA).astype(np.float32)
    nr, nc = z.shape
    path = Path(path)
    if fmt == "geotiff":
        path = path.with_suffix(".tif")
        prof = dict(
            driver="GTiff", width=nc, height=nr, count=1, dtype="float32", nodata=NODATA,
            transform=_north_up(left, top, cell), crs=crs_wkt, compress="deflate",
        )
        with rasterio.open(path, "w", **prof) as dst:
            dst.write(z, 1)
        return path
    path = path.with_suffix(".asc")
    head = (
        f"ncols {nc}\nnrows {nr}\nxllcorner {left:.17g}\nyllcorner {top - nr * cell:.17g}\ncellsize {cell:.17g}\n"
        f"NODATA_value {NODATA:g}\n"
    )
    with open(path, "w") as f:
        f.write(head)
        np.savetxt(f, z, fmt="%.7g")
    if crs_wkt:
        path.with_suffix(".prj").write_text(crs_wkt)
    return path
