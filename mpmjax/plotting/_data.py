"""What the plots read: a result (``load``), its geometry and fields (``FIELDS``,
``field_values``), frames and times, measured profiles, height profiles (``profile_at``) and the
runout series (``runout``).  No matplotlib here."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import _bodies, _metrics
from .._build import build
from .._io import frame_volumes, read_result
from .._observables import height_profile
from .._schema import _NAN_DEFAULT, _REQ, SCHEMA, SceneError


# name -> (label, unit, log colour scale)
FIELDS = {
    "mu": ("effective viscosity μ", "Pa·s", True),
    "lambda": ("structure parameter λ", "-", False),
    "speed": ("speed |v|", "m/s", False),
    "vx": ("horizontal velocity v_x", "m/s", False),
    "vz": ("vertical velocity", "m/s", False),
    "J": ("volume ratio J", "-", False),
    "displacement": ("displacement |x − x0|", "m", False),
}


def load(result) -> dict:
    """``result`` as the dict of ``read_result``: a dict is returned as is, a path to
    ``result.h5`` or to a run folder containing it is read."""
    if isinstance(result, dict):
        if not {"attrs", "frames"} <= set(result):
            raise ValueError("result: expected the dict of mpmjax._io.read_result (keys 'attrs', 'frames', ...)")
        return result
    p = Path(result)
    if p.is_dir():
        p = p / "result.h5"
    if not p.exists():
        raise FileNotFoundError(f"result: {p} does not exist (expected a result.h5 written by `mpmjax run`)")
    return read_result(p)


def _cfg(res) -> dict:
    return json.loads(res["attrs"]["scene_config_json"])


def _geometry(res) -> dict:
    """Cell size, particle spacing, runout axis and origin [m] of the run (as ``build`` defines them)."""
    cfg = _cfg(res)
    h = float(cfg["domain.cell_size_m"])
    axis = int(cfg["output.runout_axis"])
    origin = cfg["output.runout_origin_m"]
    if "runout_origin_m" in res["attrs"]:  # the origin build() derived (files from before it: derived here)
        origin = float(res["attrs"]["runout_origin_m"])
    if origin is None or (isinstance(origin, float) and math.isnan(origin)):
        starts = [_bodies.start(cfg, b, axis) for b in cfg["bodies"]]
        if cfg.get("inflow.point_m") is not None:
            starts.append(cfg["inflow.point_m"][axis])
        origin = min(starts)
    return {
        "h": h,
        "spacing": h / int(cfg["numerics.ppc"]),
        "axis": axis,
        "origin": float(origin),
        "lo": list(cfg["domain.lo_m"]),
        "hi": list(cfg["domain.hi_m"]),
        "dim": int(cfg["domain.dim"]),
        "name": cfg["name"],
    }


def _allowed(res) -> list[str]:
    fr = res["frames"]
    return [k for k in FIELDS if k != "lambda" or "lambda" in fr]


def _check_field(res, field: str):
    allowed = _allowed(res)
    if field not in allowed:
        extra = " (lambda is stored for Coussot scenes only)" if field == "lambda" else ""
        raise ValueError(f"field = {field!r} is not available{extra}; allowed: {', '.join(allowed)}")


def _frame_index(res, frame: int) -> int:
    n = res["frames"]["t_s"].shape[0]
    if not isinstance(frame, (int, np.integer)) or isinstance(frame, bool):
        raise ValueError(f"frame = {frame!r}: expected an integer frame index in -{n}..{n - 1}")
    if not -n <= int(frame) < n:
        raise ValueError(f"frame = {frame}: this result has {n} frames; allowed range -{n}..{n - 1}")
    return int(frame) % n


def field_values(result, frame: int, field: str) -> np.ndarray:
    """Values of ``field`` (see ``FIELDS``) for every particle of frame ``frame``, (n,), SI units."""
    res = load(result)
    _check_field(res, field)
    k = _frame_index(res, frame)
    fr = res["frames"]
    if field == "mu":
        return np.asarray(fr["mu_pa_s"][k], float)
    if field == "lambda":
        return np.asarray(fr["lambda"][k], float)
    if field == "J":
        return np.asarray(fr["J"][k], float)
    v = np.asarray(fr["v_m_s"][k], float)
    if field == "speed":
        return np.linalg.norm(v, axis=-1)
    if field == "vx":
        return v[:, 0]
    if field == "vz":
        return v[:, -1]
    return np.linalg.norm(np.asarray(fr["x_m"][k], float) - np.asarray(fr["x_m"][0], float), axis=-1)


def _label(res, field: str) -> str:
    name, unit, _ = FIELDS[field]
    if field == "vz":
        name = f"vertical velocity v_{'y' if res['frames']['x_m'].shape[-1] == 2 else 'z'}"
    return f"{name} [{unit}]"


def _pick_times(res, times):
    t = np.asarray(res["frames"]["t_s"], float)
    out = []
    tol = 0.5 * (t[-1] - t[0]) / max(len(t) - 1, 1) + 1e-9
    for ts in times:
        ts = float(ts)
        if not (t[0] - tol <= ts <= t[-1] + tol):
            raise ValueError(f"time {ts:g} s is outside the saved frames; allowed range {t[0]:g}..{t[-1]:g} s")
        out.append(int(np.argmin(np.abs(t - ts))))
    return out


def _data_list(data):
    """Measured data -> list of (label, t_s or None, x_m, h_m, sigma_m or None)."""
    if data is None:
        return []
    if hasattr(data, "x_m") or (isinstance(data, tuple) and len(data) == 2 and np.ndim(data[0]) == 1):
        data = [data]
    out = []
    for i, d in enumerate(data):
        if hasattr(d, "x_m") and hasattr(d, "h_m"):
            lab = "measured" + ("" if d.t_s is None else f" t = {d.t_s:g} s")
            out.append((lab, d.t_s, np.asarray(d.x_m, float), np.asarray(d.h_m, float), d.sigma_m))
            continue
        try:
            xd, hd = (np.asarray(a, float) for a in d)
        except (TypeError, ValueError):
            raise ValueError(
                f"data[{i}]: expected a calibration.data.Profile or an (x_m, h_m) pair of 1-D arrays [m]"
            ) from None
        if xd.ndim != 1 or xd.shape != hd.shape:
            raise ValueError(f"data[{i}]: x_m has shape {xd.shape} and h_m {hd.shape}; expected equal 1-D arrays [m]")
        out.append((f"measured {i}", None, xd, hd, None))
    return out


def profile_at(result, frame: int, *, method: str = "surface", x_m=None, bandwidth_m=None):
    """Height profile of one frame along the runout axis: (x [m], h [m]).

    ``method="surface"``: ``mpmjax._metrics.surface_profile`` (highest active particle plus
    half a particle spacing per cell-wide bin; nan where empty), an elevation [m].
    ``method="kernel"`` (2D): ``mpmjax.height_profile`` at ``x_m``
    (default: 201 stations over the domain) with bandwidth ``bandwidth_m`` (default one
    cell), the depth-integrated thickness that ``mpmjax calibrate`` fits, using rest volumes.
    """
    res = load(result)
    k = _frame_index(res, frame)
    g = _geometry(res)
    fr = res["frames"]
    x, act = np.asarray(fr["x_m"][k], float), fr["active"][k].astype(bool)
    ax_ = g["axis"]
    if method == "surface":
        if x_m is None:
            edges = np.arange(g["lo"][ax_], g["hi"][ax_] + 0.5 * g["h"], g["h"])
        else:
            xs = np.asarray(x_m, float)
            mid = 0.5 * (xs[1:] + xs[:-1])
            edges = np.concatenate([[xs[0] - (mid[0] - xs[0])], mid, [xs[-1] + (xs[-1] - mid[-1])]])
        if not act.any():
            xc = 0.5 * (edges[1:] + edges[:-1])
            return xc, np.full(xc.shape, np.nan)
        return _metrics.surface_profile(x, act, edges, g["spacing"], axis=ax_)
    if method == "kernel":
        if g["dim"] != 2:
            raise ValueError(f"method = 'kernel' is for 2D results; this one is {g['dim']}D (allowed: 'surface')")

        xs = np.linspace(g["lo"][ax_], g["hi"][ax_], 201) if x_m is None else np.asarray(x_m, float)
        bw = g["h"] if bandwidth_m is None else float(bandwidth_m)
        if not bw > 0:
            raise ValueError(f"bandwidth_m = {bandwidth_m}; allowed: > 0 [m]")
        hp = height_profile(
            jnp.asarray(x), jnp.asarray(frame_volumes(res)[k]), jnp.asarray(act), jnp.asarray(xs), bandwidth=bw
        )
        return xs, np.asarray(hp, float)
    raise ValueError(f"method = {method!r}; allowed: 'surface', 'kernel'")


def _plan_scene(res):
    """The built scene of a depth-averaged run, rebuilt from its saved configuration (the DEM's heights
    travel in it), so that its runout reads the step's own depth on the cells as summary.json's does;
    None for a full-model run.  Keys added to the schema after the file was written take their
    defaults (but ``numerics.split_levels`` and ``numerics.depth_layers``, whose defaults became 1 and 16
    later: such a file ran without them); the NaN defaults saved as null are NaN again.  A float64 run is
    rebuilt in float32 where float64 is off in this process (rebuilding must not switch it on; the front
    moves by float32 rounding only).  Where the saved scene cannot be rebuilt (a mesh body's file moved), None, with a
    warning: the columns are then binned by position as before 2026-12-06."""
    saved = _cfg(res)
    if saved.get("model.formulation") != "depth-averaged":
        return None
    cfg = {k: spec.default for k, spec in SCHEMA.items() if spec.default is not _REQ}
    cfg.update(saved)
    if "numerics.split_levels" not in saved:  # written before column splitting existed: a run without it
        cfg["numerics.split_levels"] = 0
    if "numerics.depth_layers" not in saved:  # written before the layers existed: one value per column
        cfg["numerics.depth_layers"] = 1
    for k in _NAN_DEFAULT:
        if cfg.get(k) is None:
            cfg[k] = math.nan
    if cfg.get("numerics.dtype") == "float64" and not jax.config.jax_enable_x64:
        cfg["numerics.dtype"] = "float32"
    try:
        return build(cfg).scene
    except (SceneError, OSError, KeyError, ValueError) as e:
        warnings.warn(
            f"the depth-averaged run's scene could not be rebuilt from result.h5 ({e}); its runout is read from "
            "the columns binned by position, not the step's depth",
            stacklevel=3,
        )
        return None


def _gauge(res) -> _metrics.RunoutGauge:
    g = _geometry(res)
    return _metrics.RunoutGauge(
        dim=g["dim"], axis=g["axis"], origin=g["origin"], cell=g["h"], spacing=g["spacing"], lo=tuple(g["lo"]),
        hi=tuple(g["hi"]), plan=_plan_scene(res),
    )


def runout(result, *, farthest: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(times [s], runout [m]) of every saved frame, as summary.json defines it (docs/output.md
    "Runout"): the free-surface front, or with ``farthest`` the farthest particle (0 where no
    material is active yet)."""
    res = load(result)
    gauge = _gauge(res)
    fr = res["frames"]
    act = fr["active"].astype(bool)
    vols = frame_volumes(res).astype(np.float32)
    if farthest:
        front = [gauge.farthest(x, a) for x, a in zip(fr["x_m"], act)]
    else:
        front = [gauge.front(x, v, a) for x, v, a in zip(fr["x_m"], vols, act)]
    return np.asarray(fr["t_s"], float), np.asarray(front, float)
