"""Write the SYNTHETIC test DEMs of data/: a valley with a tailings dam and a breach notch.

    python data/make_synthetic_dem.py          # rewrites data/synthetic_valley_dem.{asc,tif,prj}
                                               # and data/synthetic_valley_long_dem.{asc,tif,prj}

Nothing here is a real place: the valley is a formula, placed in UTM zone 19S (EPSG:32719)
coordinates only so that the GIS side of mpmjax (CRS, transform) has something to carry.

Local coordinates x = X - 350000 m (east, down the valley), y = Y - 6300000 m (north):

* valley floor z0(x) = 100 - 0.04 x [m] (a 4 % fall towards +x), axis y = 250 m;
* sides rising as 40 ((y - 250) / 250)^2 m (40 m above the floor at the raster's edges);
* a dam across the valley, crest z0(450) + 20 = 102 m at x = 450 m, 10 m wide, faces 1:2;
* a breach notch 80 m wide (|y - 250| < 40 m) cut through the dam down to the valley floor.

Raster: 80 x 25 pixels of 20 m (1600 m x 500 m), lower-left corner (350000, 6300000); the
elevation of each pixel is the formula at the pixel centre.  Written as an ESRI ASCII grid
(numpy, 2 decimals, with a .prj sidecar holding the CRS's WKT) and as a GeoTIFF (rasterio, float32,
deflate).  The same heights in both, to the ASCII grid's 0.01 m.

The LONG variant (synthetic_valley_long_dem.*, for the depth-averaged field-breach-da, whose runout
leaves the short raster's open east end) is the same formula for x <= 1600 m, the same CRS, origin
and pixels, 140 x 25 pixels (2800 m x 500 m).  Beyond x = 1600 m the valley floor levels out into a
basin and rises again (the sides unchanged), with s = x - 1600 m:

* z0(x) = 36 - 0.04 s + 0.04 s^2 / 800 [m]: the slope goes from -4 % (continuous at x = 1600 m)
  linearly to 0 at x = 2000 m (the basin's bottom, z0 = 28 m) and to a +4 % counter-slope at
  x = 2400 m (z0 = 36 m), +8 % at the raster's east end x = 2800 m (z0 = 60 m).

Again a formula, no real place.  The short raster's files are not changed by the long one.
"""

from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import from_origin

X0, Y0, CELL, NCOLS, NROWS = 350000.0, 6300000.0, 20.0, 80, 25
EPSG = 32719


NCOLS_LONG, X_BASIN = 140, 1600.0


def elevation(x, y, long=False):
    """Elevation [m] at local coordinates x, y [m] (module docstring); long: the basin beyond x = 1600 m."""
    floor = 100.0 - 0.04 * x
    if long:
        s = np.maximum(x - X_BASIN, 0.0)
        floor = floor + 0.04 * s**2 / 800.0  # -4 % at s = 0, level at s = 400 m, +4 % at s = 800 m
    valley = floor + 40.0 * ((y - 250.0) / 250.0) ** 2
    crest = 100.0 - 0.04 * 450.0 + 20.0
    dam = crest - 0.5 * np.maximum(0.0, np.abs(x - 450.0) - 5.0)
    dam = np.where(np.abs(y - 250.0) < 40.0, -np.inf, dam)  # the breach notch
    return np.maximum(valley, dam)


def write(out, stem, ncols, long):
    xc = (np.arange(ncols) + 0.5) * CELL
    yc = (NROWS - 0.5 - np.arange(NROWS)) * CELL  # rows from north to south
    z = np.round(elevation(xc[None, :], yc[:, None], long), 2).astype(np.float32)
    crs = CRS.from_epsg(EPSG)
    head = (
        f"ncols {ncols}\nnrows {NROWS}\nxllcorner {X0:.1f}\nyllcorner {Y0:.1f}\ncellsize {CELL:g}\n"
        "NODATA_value -9999\n"
    )
    with open(out / f"{stem}.asc", "w") as f:
        f.write(head)
        np.savetxt(f, z, fmt="%.2f")
    (out / f"{stem}.prj").write_text(crs.to_wkt())
    prof = dict(driver="GTiff", width=ncols, height=NROWS, count=1, dtype="float32", crs=crs, nodata=-9999.0,
                transform=from_origin(X0, Y0 + NROWS * CELL, CELL, CELL), compress="deflate")
    with rasterio.open(out / f"{stem}.tif", "w", **prof) as dst:
        dst.write(z, 1)


def main(out=Path(__file__).parent):
    write(out, "synthetic_valley_dem", NCOLS, long=False)
    write(out, "synthetic_valley_long_dem", NCOLS_LONG, long=True)


if __name__ == "__main__":
    main()
