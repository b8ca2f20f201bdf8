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
import stat
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


def check_file(path) -> Path:
    """``path`` as a ``Path`` if it is a regular file; ``DataError`` naming it otherwise (missing, a
    folder, a FIFO or device: reading one of those could hang or fail with an unnamed error)."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as e:
        raise DataError(f"{path}: cannot be read ({e.strerror or e})") from None
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "a FIFO" if stat.S_ISFIFO(mode) else "not a regular file"
        raise DataError(f"{path}: is {kind}; allowed: a regular CSV or HDF5 file")
    return path


def text_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, line) of the lines of a text file that are neither blank nor ``#`` comments;
    ``DataError`` naming the file where it is not UTF-8 text (a binary file, a Latin-1 export)."""
    try:
        with open(path, newline="", encoding="utf-8") as f:
            return [(i + 1, ln) for i, ln in enumerate(f) if ln.strip() and not ln.lstrip().startswith("#")]
    except UnicodeDecodeError as e:
        line = path.read_bytes()[: e.start].count(b"\n") + 1
        raise DataError(
            f"{path}: line {line}: byte 0x{e.object[e.start]:02x} is not UTF-8 text; allowed: a UTF-8 (or ASCII) CSV "
            "file (save it as UTF-8; a binary file is not a CSV)"
        ) from None
    except OSError as e:
        raise DataError(f"{path}: cannot be read ({e.strerror or e})") from None


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
    lines = text_lines(path)
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
    path = check_file(path)
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
    if ts and len(ts) == len(profs) and max(ts) == 0:
        raise DataError(
            f"{path}: t_s = 0 in every row: every profile is the initial state, which no parameter changes; allowed: "
            "at least one profile after the release (t_s > 0 [s]), or no t_s column (the final deposit)"
        )
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


# ------------------------------------------------------------------------------------------
# Tables of the other experiment kinds: runout series, rest times, rheometer shear histories
# ------------------------------------------------------------------------------------------
# kind -> (required columns, optional columns); every column's unit is in its name (see
# docs/calibration.md, "Data formats").  "weight" (the experiment's loss weight, one value for
# the whole file) may be a column or an HDF5 attribute; so may the kind's sigma column (a
# scalar attribute applies to every row).
TABLES = {
    "flow curve": (("gamma_dot_1_s", "tau_pa"), ()),
    "runout series": (("t_s", "x_front_m"), ("sigma_m", "weight")),
    "rest times": (("t_rest_s", "t_s", "x_front_m"), ("sigma_m", "lambda_rest", "weight")),
    "shear history": (("test", "t_s", "gamma_dot_1_s"), ("tau_pa", "sigma_ln", "weight")),
}
# columns that may be left empty in a CSV row (NaN): a shear-history row without a stress is a
# schedule row (it sets the rate only)
BLANK_OK = {"tau_pa"}
TABLE_UNITS = {
    "t_s": "s", "t_rest_s": "s", "x_front_m": "m", "sigma_m": "m", "gamma_dot_1_s": "1/s", "tau_pa": "Pa",
    "sigma_ln": "-", "lambda_rest": "-", "weight": "-", "test": "-",
}


class Table:
    """Columns of a data file as float arrays (``cols``), where each row came from (``rows``:
    "line N" for CSV, "index i" for HDF5), and the file's name (``src``)."""

    def __init__(self, src, cols, rows):
        self.src, self.cols, self.rows = src, cols, rows

    def where(self, i):
        return f"{self.src}: {self.rows[i]}"

    def check(self, col, ok, allowed):
        """DataError naming the file, row, column, value and ``allowed`` at the first row where
        ``ok`` is False."""
        bad = np.flatnonzero(~np.asarray(ok, bool))
        if bad.size:
            i = int(bad[0])
            raise DataError(f"{self.where(i)}: {col} = {float(self.cols[col][i])!r}; allowed range: {allowed}")

    def scalar(self, col):
        """The one value of a per-file column (e.g. weight), or None; DataError if it varies."""
        a = self.cols.get(col)
        if a is None:
            return None
        self.check(col, np.isfinite(a) & (a > 0), f"> 0 and finite [{TABLE_UNITS[col]}]")
        bad = np.flatnonzero(a != a[0])
        if bad.size:
            i = int(bad[0])
            raise DataError(
                f"{self.where(i)}: {col} = {float(a[i])!r} differs from the first row's {float(a[0])!r}; "
                f"allowed: one {col} per file"
            )
        return float(a[0])


def read_table(path, kind: str) -> Table:
    """Read a data file of ``kind`` (a key of ``TABLES``): CSV (one header line naming the
    columns, ``#`` comment lines anywhere, empty fields only in ``BLANK_OK`` columns) or HDF5
    (one 1-D dataset per column, all of one length; a column may instead be a scalar root
    attribute, which applies to every row; a ``units`` attribute, when present, is checked).
    Unknown columns are an error; every value must be a number."""
    path = check_file(path)
    src = str(path)
    req, opt = TABLES[kind]
    allowed = req + opt
    suffix = path.suffix.lower()
    if suffix == ".csv":
        lines = text_lines(path)
        if not lines:
            raise DataError(f"{src}: no header line; expected columns {', '.join(req)} [, {', '.join(opt)}]")
        rows = list(csv.reader([ln for _, ln in lines]))
        header = [c.strip() for c in rows[0]]
        if len(set(header)) != len(header):
            raise DataError(f"{src}: repeated column names in the header {header}")
        cols = {c: [] for c in header}
        where = []
        for (lineno, _), r in zip(lines[1:], rows[1:], strict=True):
            if len(r) != len(header):
                raise DataError(f"{src}: line {lineno} has {len(r)} fields; the header has {len(header)}")
            for c, v in zip(header, r, strict=True):
                v = v.strip()
                if v == "" and c in BLANK_OK:
                    cols[c].append(math.nan)
                else:
                    cols[c].append(_parse_float(src, f"{lineno} (line)", c, v))
            where.append(f"line {lineno}")
        cols = {c: np.asarray(v, float) for c, v in cols.items()}
    elif suffix in (".h5", ".hdf5", ".hdf"):
        try:
            with h5py.File(path, "r") as f:
                header = list(f.keys())
                cols = {}
                for k in header:
                    if k in TABLE_UNITS:
                        u = f[k].attrs.get("units")
                        u = u.decode() if isinstance(u, bytes) else u
                        if u is not None and str(u) != TABLE_UNITS[k]:
                            raise DataError(
                                f"{src}: {k} has units attribute {u!r}; expected {TABLE_UNITS[k]!r} (convert to SI)"
                            )
                    cols[k] = np.atleast_1d(np.asarray(f[k][()], float))
                    if cols[k].ndim != 1:
                        raise DataError(f"{src}: dataset {k} has shape {cols[k].shape}; expected 1-D (one per row)")
                attrs = {k: float(np.asarray(v)) for k, v in f.attrs.items() if k in allowed and k not in cols}
        except OSError as e:
            raise DataError(f"{path}: not a readable HDF5 file ({e})") from None
        lengths = {k: v.size for k, v in cols.items()}
        if len(set(lengths.values())) > 1:
            raise DataError(f"{src}: datasets of different lengths {lengths}; one value per row in each")
        n = next(iter(lengths.values()), 0)
        for k, v in attrs.items():
            cols[k] = np.full(n, v)
        header = list(cols)
        where = [f"index {i}" for i in range(n)]
    else:
        raise DataError(f"{path}: unknown file type {suffix!r}; allowed: .csv, .h5, .hdf5")
    unknown = [c for c in header if c not in allowed]
    if unknown:
        raise DataError(
            f"{src}: unknown column(s) {', '.join(map(repr, unknown))}; allowed for a {kind} file: "
            f"{', '.join(allowed)} (units in the names; docs/calibration.md)"
        )
    for c in req:
        if c not in cols:
            raise DataError(f"{src}: missing required column {c!r}; a {kind} file has {', '.join(req)}")
    if not where:
        raise DataError(f"{src}: the file has a header but no data rows")
    t = Table(src, cols, where)
    for c, a in cols.items():
        ok = np.isfinite(a) | (np.isnan(a) & (c in BLANK_OK))
        t.check(c, ok, f"a finite number [{TABLE_UNITS[c]}]")
    return t


@dataclass(frozen=True)
class RunoutSeries:
    """A measured front position against time: t_s (m,) [s] >= 0, strictly increasing;
    x_front_m (m,) [m]; sigma_m (m,) [m] or None; rest_time_s [s] (rest-time files) or None;
    lambda_rest [-] or None; weight or None (the file's); source: the file's name."""

    t_s: np.ndarray
    x_front_m: np.ndarray
    sigma_m: np.ndarray | None = None
    rest_time_s: float | None = None
    lambda_rest: float | None = None
    weight: float | None = None
    source: str = field(default="", compare=False)


def _series(t: Table, idx, rest=None):
    c = t.cols
    ts = c["t_s"][idx]
    d = np.diff(ts)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = int(idx[bad[0] + 1])
        raise DataError(
            f"{t.where(i)}: t_s = {float(c['t_s'][i])!r} does not increase (previous {float(ts[bad[0]])!r}); "
            "allowed: strictly increasing within a series (sort the rows by t_s)"
        )
    lam = None
    if "lambda_rest" in c:
        lam = float(c["lambda_rest"][idx[0]])
        bad = np.flatnonzero(c["lambda_rest"][idx] != lam)
        if bad.size:
            i = int(idx[bad[0]])
            raise DataError(
                f"{t.where(i)}: lambda_rest = {float(c['lambda_rest'][i])!r} differs within the run of rest "
                f"{rest:g} s; allowed: one lambda_rest per rest time"
            )
    return RunoutSeries(
        ts,
        c["x_front_m"][idx],
        c["sigma_m"][idx] if "sigma_m" in c else None,
        rest,
        lam,
        t.scalar("weight"),
        Path(t.src).name,
    )


def _check_series_columns(t: Table):
    c = t.cols
    t.check("t_s", c["t_s"] >= 0, ">= 0 and finite [s]")
    if "sigma_m" in c:
        t.check("sigma_m", c["sigma_m"] > 0, "> 0 and finite [m]")
    if "t_rest_s" in c:
        t.check("t_rest_s", c["t_rest_s"] >= 0, ">= 0 and finite [s]")
    if "lambda_rest" in c:
        t.check("lambda_rest", c["lambda_rest"] >= 0, ">= 0 and finite [-]")


def load_runout_series(path) -> RunoutSeries:
    """A runout time series (columns t_s [s], x_front_m [m], optional sigma_m [m], weight [-];
    CSV or HDF5, :func:`read_table`)."""
    t = read_table(path, "runout series")
    _check_series_columns(t)
    return _series(t, np.arange(len(t.rows)))


def load_rest_times(path) -> list[RunoutSeries]:
    """Repeated dam breaks after rests: columns t_rest_s [s], t_s [s] (time since the release),
    x_front_m [m], optional sigma_m [m], lambda_rest [-] (the structure when the rest began;
    default the material's lambda0), weight [-].  Rows with the same t_rest_s form one run.
    Returns the runs by increasing rest time."""
    t = read_table(path, "rest times")
    _check_series_columns(t)
    tr = t.cols["t_rest_s"]
    return [_series(t, np.flatnonzero(tr == v), float(v)) for v in np.unique(tr)]


@dataclass(frozen=True)
class ShearTest:
    """One rheometer test under a piecewise-constant shear rate, started at t = 0 from the
    law's initial internal state (Coussot: lambda0).

    t_s (m,) [s] > 0, strictly increasing; gamma_dot_1_s (m,) [1/s] >= 0: the rate imposed on
    (t_{i-1}, t_i] (t_0 = 0), so a rate change takes effect at the previous row's time;
    tau_pa (m,) [Pa]: the measured shear stress at t_i, NaN for a schedule row (one that only
    sets the rate, e.g. the end of a pre-shear or of a rest: a stress at rest cannot enter a
    ln tau residual); sigma_ln (m,) [-] or None: relative standard deviation of tau.
    """

    label: str
    t_s: np.ndarray
    gamma_dot_1_s: np.ndarray
    tau_pa: np.ndarray
    sigma_ln: np.ndarray | None = None
    source: str = field(default="", compare=False)

    def __post_init__(self):
        src = f"{self.source or 'shear test'} (test {self.label})"
        t, g, tau = (np.atleast_1d(np.asarray(a, float)) for a in (self.t_s, self.gamma_dot_1_s, self.tau_pa))
        if t.ndim != 1 or g.shape != t.shape or tau.shape != t.shape:
            raise DataError(f"{src}: t_s {t.shape}, gamma_dot_1_s {g.shape}, tau_pa {tau.shape} must be equal 1-D")
        for name, a, ok, rng in (
            ("t_s", t, np.isfinite(t) & (t > 0), "> 0 and finite [s]"),
            ("gamma_dot_1_s", g, np.isfinite(g) & (g >= 0), ">= 0 and finite [1/s]"),
            ("tau_pa", tau, np.isnan(tau) | (np.isfinite(tau) & (tau > 0)), "> 0 and finite [Pa], or empty"),
        ):
            bad = np.flatnonzero(~ok)
            if bad.size:
                raise DataError(f"{src}: {name}[{bad[0]}] = {float(a[bad[0]])!r}; allowed range: {rng}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            raise DataError(f"{src}: t_s[{bad[0] + 1}] = {t[bad[0] + 1]!r} does not increase; allowed: strictly increasing")
        bad = np.flatnonzero((g == 0) & np.isfinite(tau))
        if bad.size:
            raise DataError(
                f"{src}: tau_pa[{bad[0]}] = {tau[bad[0]]!r} at gamma_dot_1_s = 0; allowed: empty (a stress at rest "
                "cannot enter a ln tau residual)"
            )
        if not np.isfinite(tau).any():
            raise DataError(f"{src}: no measured stress (every tau_pa is empty)")
        if self.sigma_ln is not None:
            s = np.broadcast_to(np.asarray(self.sigma_ln, float), t.shape)
            bad = np.flatnonzero(~(np.isfinite(s) & (s > 0)))
            if bad.size:
                raise DataError(f"{src}: sigma_ln[{bad[0]}] = {float(s[bad[0]])!r}; allowed range: > 0 and finite [-]")

    def schedule(self):
        """(step times [s], rates [1/s]) for ``mpmjax.rheometer.shear_history``: rates[j] from
        times[j] on."""
        t = np.asarray(self.t_s, float)
        g = np.asarray(self.gamma_dot_1_s, float)
        times, rates = [0.0], [float(g[0])]
        for i in range(1, t.size):
            if g[i] != g[i - 1]:
                times.append(float(t[i - 1]))
                rates.append(float(g[i]))
        return np.asarray(times), np.asarray(rates)


def load_shear_tests(path) -> tuple[list[ShearTest], float | None]:
    """Rheometer tests under piecewise-constant shear rates (columns test [-] (a number per
    test), t_s [s], gamma_dot_1_s [1/s], tau_pa [Pa] (empty: a schedule row), optional sigma_ln
    [-], weight [-]; see :class:`ShearTest`).  Returns (tests in file order, the file's weight or
    None)."""
    t = read_table(path, "shear history")
    c = t.cols
    if "sigma_ln" in c:
        t.check("sigma_ln", c["sigma_ln"] > 0, "> 0 and finite [-]")
    t.check("t_s", c["t_s"] > 0, "> 0 and finite [s] (a test starts at t = 0; a row gives the end of its rate)")
    t.check("gamma_dot_1_s", c["gamma_dot_1_s"] >= 0, ">= 0 and finite [1/s]")
    if "tau_pa" not in c:
        raise DataError(f"{t.src}: missing column 'tau_pa' [Pa]: the measured stresses")
    t.check("tau_pa", np.isnan(c["tau_pa"]) | (c["tau_pa"] > 0), "> 0 and finite [Pa], or empty (a schedule row)")
    t.check("tau_pa", np.isnan(c["tau_pa"]) | (c["gamma_dot_1_s"] > 0), "empty where gamma_dot_1_s = 0 (rest)")
    tests = []
    ids = list(dict.fromkeys(c["test"].tolist()))
    for k in ids:
        idx = np.flatnonzero(c["test"] == k)
        bad = np.flatnonzero(np.diff(c["t_s"][idx]) <= 0)
        if bad.size:
            i = int(idx[bad[0] + 1])
            raise DataError(
                f"{t.where(i)}: t_s = {float(c['t_s'][i])!r} does not increase within test {k:g}; allowed: strictly "
                "increasing (sort each test's rows by t_s)"
            )
        if not np.isfinite(c["tau_pa"][idx]).any():
            raise DataError(f"{t.where(int(idx[0]))}: test {k:g} has no measured stress (every tau_pa is empty)")
        tests.append(
            ShearTest(
                f"{k:g}",
                c["t_s"][idx],
                c["gamma_dot_1_s"][idx],
                c["tau_pa"][idx],
                c["sigma_ln"][idx] if "sigma_ln" in c else None,
                Path(t.src).name,
            )
        )
    return tests, t.scalar("weight")


def load_flow_curve(path) -> tuple[np.ndarray, np.ndarray]:
    """Rheometer flow-curve points (columns gamma_dot_1_s [1/s] > 0, tau_pa [Pa] > 0; CSV or HDF5,
    :func:`read_table`) as (shear rates, stresses)."""
    t = read_table(path, "flow curve")
    c = t.cols
    t.check("gamma_dot_1_s", c["gamma_dot_1_s"] > 0, "> 0 and finite [1/s]")
    t.check("tau_pa", c["tau_pa"] > 0, "> 0 and finite [Pa]")
    return c["gamma_dot_1_s"], c["tau_pa"]


def write_table_csv(path, columns: dict, header_comment: str = ""):
    """Write columns (name -> 1-D array; NaN written as an empty field) as CSV with ``#``
    comment lines first (state the origin of the data there)."""
    names = list(columns)
    arrs = [np.asarray(columns[k], float) for k in names]
    lines = [f"# {ln}" for ln in header_comment.splitlines()] + [",".join(names)]
    for i in range(arrs[0].size):
        lines.append(",".join("" if math.isnan(a[i]) else f"{a[i]:.8g}" for a in arrs))
    mpmjax.atomic_write_text(Path(path), "\n".join(lines) + "\n")
