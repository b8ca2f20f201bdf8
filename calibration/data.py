"""Measured flume profiles: loading, validation and writing.

A *profile* is the deposit height h [m] at horizontal stations x [m], at one time t [s]
(or at the end of the experiment, when no time is given), with an optional standard
deviation sigma [m] per station.  Loaders return a list of :class:`Profile`, one per
distinct time, in increasing time order.

File formats
------------
**CSV** (comma separated, one header line, ``#`` comment lines allowed anywhere):
columns ``x_m, h_m`` and optionally ``t_s`` and ``sigma_m``, in any order; extra columns
are an error (a misspelt ``sigma_mm`` must not be silently ignored).  Rows with the same
``t_s`` form one profile; without ``t_s`` the file is one final profile.

**HDF5** (h5py): datasets ``x_m`` (M,) and ``h_m`` (M,) or (K, M) with ``t_s`` (K,);
optional ``sigma_m`` of the same shape as ``h_m`` (or a scalar); or one group per profile,
each holding ``x_m``, ``h_m``, optional ``sigma_m`` and a scalar attribute or dataset
``t_s``.  Units are in the names and may also be given as a ``units`` attribute
(``"m"`` / ``"s"``), which is checked when present.

Validation (:class:`DataError`, a ``ValueError``, names the file, the field, the row or
index, the value and the allowed range): every number finite; ``h_m >= 0``;
``sigma_m > 0``; ``t_s >= 0``; ``x_m`` strictly increasing within a profile; at least
two stations per profile; no duplicate (t, x) pairs.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

import mpmjax

__all__ = ["DataError", "Profile", "load_profiles", "write_profiles_csv"]

COLUMNS = ("x_m", "h_m", "t_s", "sigma_m")
REQUIRED = ("x_m", "h_m")
UNITS = {"x_m": "m", "h_m": "m", "t_s": "s", "sigma_m": "m"}


class DataError(ValueError):
    """Invalid measured data (the message names the file, field, position, value and allowed range)."""


@dataclass(frozen=True)
class Profile:
    """One measured height profile.

    x_m: (M,) stations [m], strictly increasing; h_m: (M,) heights [m] >= 0;
    t_s: time of the measurement [s] (None: the final, deposited profile);
    sigma_m: (M,) standard deviation of h [m] (None: unknown, estimated from the fit
    residuals); source: where it came from (file name), for messages and plots.
    """

    x_m: np.ndarray
    h_m: np.ndarray
    t_s: float | None = None
    sigma_m: np.ndarray | None = None
    source: str = field(default="", compare=False)

    def __post_init__(self):
        _check_profile(self.x_m, self.h_m, self.sigma_m, self.t_s, self.source or "profile", rows=None)


def _fmt_where(src, name, where):
    return f"{src}: {name}{'' if where is None else ' ' + where}"


def _check_profile(x, h, sigma, t, src, rows):
    x = np.asarray(x)
    h = np.asarray(h)
    if x.ndim != 1 or h.shape != x.shape:
        raise DataError(f"{src}: x_m has shape {x.shape} and h_m {h.shape}; they must be equal 1-D arrays")
    if x.size < 2:
        tt = "" if t is None else f" at t_s = {t:g} s"
        raise DataError(f"{src}: a profile{tt} has {x.size} station(s); at least 2 are needed")

    def where(i):
        return f"({rows[i]})" if rows is not None else f"index {i}"

    for name, a, ok, rng in (
        ("x_m", x, np.isfinite(x), "finite [m]"),
        ("h_m", h, np.isfinite(h) & (h >= 0), ">= 0 and finite [m]"),
    ):
        bad = np.flatnonzero(~ok)
        if bad.size:
            i = int(bad[0])
            raise DataError(f"{_fmt_where(src, name, where(i))} = {float(a[i])!r}; allowed range: {rng}")
    if sigma is not None:
        s = np.asarray(sigma)
        if s.shape != x.shape:
            raise DataError(f"{src}: sigma_m has shape {s.shape}; expected {x.shape} like x_m")
        bad = np.flatnonzero(~(np.isfinite(s) & (s > 0)))
        if bad.size:
            i = int(bad[0])
            raise DataError(
                f"{_fmt_where(src, 'sigma_m', where(i))} = {float(s[i])!r}; allowed range: > 0 and finite [m]"
            )
    if t is not None and not (math.isfinite(t) and t >= 0):
        raise DataError(f"{src}: t_s = {t!r}; allowed range: >= 0 and finite [s]")
    d = np.diff(x)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        kind = "repeats" if d[i - 1] == 0 else "decreases"
        raise DataError(
            f"{_fmt_where(src, 'x_m', where(i))} = {float(x[i])!r} {kind} (previous {float(x[i - 1])!r}); "
            "allowed: strictly increasing within a profile (sort the rows by x_m)"
        )


def _parse_float(src, row, col, text):
    try:
        return float(text)
    except ValueError:
        raise DataError(f"{src}: {col} row {row} = {text!r} is not a number; allowed: a decimal number") from None


def _load_csv(path: Path) -> list[Profile]:
    src = str(path)
    with open(path, newline="") as f:
        lines = [(i + 1, ln) for i, ln in enumerate(f) if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{src}: no header line; expected columns x_m, h_m [, t_s, sigma_m]")
    reader = csv.reader([ln for _, ln in lines])
    rows = list(reader)
    header = [c.strip() for c in rows[0]]
    unknown = [c for c in header if c not in COLUMNS]
    if unknown:
        raise DataError(
            f"{src}: unknown column(s) {', '.join(map(repr, unknown))}; allowed columns: "
            f"{', '.join(COLUMNS)} (SI units: metres and seconds)"
        )
    for c in REQUIRED:
        if c not in header:
            raise DataError(f"{src}: missing required column {c!r}; the columns are x_m, h_m [, t_s, sigma_m]")
    if len(set(header)) != len(header):
        raise DataError(f"{src}: repeated column names in the header {header}")
    data = {c: [] for c in header}
    line_no = []
    for (lineno, _), r in zip(lines[1:], rows[1:], strict=True):
        if len(r) != len(header):
            raise DataError(f"{src}: line {lineno} has {len(r)} fields; the header has {len(header)}")
        for c, v in zip(header, r, strict=True):
            data[c].append(_parse_float(src, f"{lineno} (line)", c, v.strip()))
        line_no.append(lineno)
    if not line_no:
        raise DataError(f"{src}: the file has a header but no data rows")
    arr = {c: np.asarray(v, float) for c, v in data.items()}
    line_no = np.asarray(line_no)
    if "t_s" in arr:
        bad = np.flatnonzero(~(np.isfinite(arr["t_s"]) & (arr["t_s"] >= 0)))
        if bad.size:
            i = int(bad[0])
            raise DataError(
                f"{src}: t_s line {line_no[i]} = {float(arr['t_s'][i])!r}; allowed range: >= 0 and finite [s]"
            )
        times = np.unique(arr["t_s"])
        groups = [(float(t), np.flatnonzero(arr["t_s"] == t)) for t in times]
    else:
        groups = [(None, np.arange(line_no.size))]
    out = []
    for t, idx in groups:
        sig = arr["sigma_m"][idx] if "sigma_m" in arr else None
        _check_profile(arr["x_m"][idx], arr["h_m"][idx], sig, t, src, rows=[f"line {n}" for n in line_no[idx]])
        out.append(Profile(arr["x_m"][idx], arr["h_m"][idx], t, sig, source=path.name))
    return out


def _units_ok(src, name, ds):
    u = ds.attrs.get("units")
    if u is None:
        return
    u = u.decode() if isinstance(u, bytes) else str(u)
    if u != UNITS[name]:
        raise DataError(f"{src}: {name} has units attribute {u!r}; expected {UNITS[name]!r} (convert to SI)")


def _load_h5(path: Path) -> list[Profile]:
    src = str(path)
    out = []
    with h5py.File(path, "r") as f:
        if "x_m" in f:
            for k in f:
                if k not in COLUMNS:
                    raise DataError(f"{src}: unknown dataset {k!r}; allowed: {', '.join(COLUMNS)}")
            for k in f:
                _units_ok(src, k, f[k])
            if "h_m" not in f:
                raise DataError(f"{src}: missing dataset 'h_m' [m]")
            x = np.asarray(f["x_m"][()], float)
            h = np.asarray(f["h_m"][()], float)
            sig = np.asarray(f["sigma_m"][()], float) if "sigma_m" in f else None
            if h.ndim == 1:
                t = float(f["t_s"][()]) if "t_s" in f else None
                if sig is not None and sig.ndim == 0:
                    sig = np.full_like(h, float(sig))
                out.append(Profile(x, h, t, sig, source=path.name))
            elif h.ndim == 2:
                if "t_s" not in f:
                    raise DataError(f"{src}: h_m has shape {h.shape} (K, M); a dataset t_s of shape (K,) is needed")
                t = np.atleast_1d(np.asarray(f["t_s"][()], float))
                if t.shape != (h.shape[0],):
                    raise DataError(f"{src}: t_s has shape {t.shape}; expected ({h.shape[0]},) for h_m {h.shape}")
                if sig is not None and sig.ndim == 0:
                    sig = np.full_like(h, float(sig))
                if sig is not None and sig.shape != h.shape:
                    raise DataError(f"{src}: sigma_m has shape {sig.shape}; expected {h.shape} like h_m")
                for k in range(h.shape[0]):
                    out.append(Profile(x, h[k], float(t[k]), None if sig is None else sig[k], source=path.name))
            else:
                raise DataError(f"{src}: h_m has shape {h.shape}; expected (M,) or (K, M)")
        else:
            if not len(f):
                raise DataError(f"{src}: empty file; expected datasets x_m, h_m or one group per profile")
            for name in f:
                g = f[name]
                if not isinstance(g, h5py.Group) or "x_m" not in g or "h_m" not in g:
                    raise DataError(f"{src}: /{name} is not a profile group with datasets x_m and h_m")
                for k in g:
                    _units_ok(f"{src}:/{name}", k, g[k]) if k in UNITS else None
                t = g.attrs.get("t_s", g["t_s"][()] if "t_s" in g else None)
                sig = np.asarray(g["sigma_m"][()], float) if "sigma_m" in g else None
                x = np.asarray(g["x_m"][()], float)
                if sig is not None and sig.ndim == 0:
                    sig = np.full_like(x, float(sig))
                out.append(
                    Profile(
                        x, np.asarray(g["h_m"][()], float), None if t is None else float(t), sig, f"{path.name}:/{name}"
                    )
                )
    return out


def load_profiles(path) -> list[Profile]:
    """Load measured profiles from a CSV or HDF5 file (see the module docstring).

    Returns the profiles sorted by time (a final profile without time last).  Raises
    :class:`DataError` with the file, field, position, value and allowed range.
    """
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        profs = _load_csv(path)
    elif suffix in (".h5", ".hdf5", ".hdf"):
        try:
            profs = _load_h5(path)
        except OSError as e:
            raise DataError(f"{path}: not a readable HDF5 file ({e})") from None
    else:
        raise DataError(f"{path}: unknown file type {suffix!r}; allowed: .csv, .h5, .hdf5")
    if sum(p.t_s is None for p in profs) > 1:
        raise DataError(f"{path}: more than one profile without t_s")
    ts = [p.t_s for p in profs if p.t_s is not None]
    if len(set(ts)) != len(ts):
        raise DataError(f"{path}: two profiles share the time t_s; use one profile per time")
    return sorted(profs, key=lambda p: (p.t_s is None, p.t_s or 0.0))


def write_profiles_csv(path, profiles, header_comment: str = ""):
    """Write profiles as CSV (columns x_m, h_m, t_s [, sigma_m]); ``header_comment`` lines
    are written first, prefixed with ``#`` (state the origin of the data there)."""
    path = Path(path)
    with_sigma = all(p.sigma_m is not None for p in profiles)
    if any(p.t_s is None for p in profiles) and len(profiles) > 1:
        raise DataError("write_profiles_csv: several profiles need a t_s each")
    cols = ["x_m", "h_m"] + (["t_s"] if profiles[0].t_s is not None else []) + (["sigma_m"] if with_sigma else [])
    lines = [f"# {ln}" for ln in header_comment.splitlines()] + [",".join(cols)]
    for p in profiles:
        for i in range(p.x_m.size):
            row = [f"{p.x_m[i]:.6g}", f"{p.h_m[i]:.6g}"]
            if "t_s" in cols:
                row.append(f"{p.t_s:.6g}")
            if with_sigma:
                row.append(f"{p.sigma_m[i]:.6g}")
            lines.append(",".join(row))
    mpmjax.atomic_write_text(path, "\n".join(lines) + "\n")
