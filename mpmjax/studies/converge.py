"""``mpmjax converge``: does the answer converge as the grid is refined, and what does each
numerical setting cost and buy?  (issue 14 item 3; method and figures in docs/validation.md,
section "Convergence benchmark").

Cases (each a scene with its observable):

* ``lab``: the thesis lab dam break (``dambreak-lab``, BASE Coussot), the runout at
  ``t_end``; no exact answer, so the reference is the Richardson extrapolate of the default
  settings' finest three levels.
* ``slump``: a Bingham slump to rest on a no-slip horizontal plane against a symmetry wall
  (tau_y = 82 Pa, mu = 7 Pa s, rho = 1000 kg/m^3; the set-up of tests/test_rheology_mpm.py),
  against its exact static profile (REFERENCE.md, Coussot, Proust & Ancey 1996)
  h(x) = sqrt(k (x_f - x)), k = 2 tau_y / (rho g), with x_f from the released area A:
  A = (2/3) sqrt(k) x_f^(3/2).
* ``water``: the Cruchaga water column (``dambreak-water``) at t = 0.15 s, before the surge
  reaches the far wall; reference as for ``lab``.

Levels: the cell size halves from the case's coarsest (``LEVELS``), so that the levels are
4, 8, 16, 32 cells over the slump's initial height, 5 .. 40 over the lab block, 5.7 .. 46
over the water column.

Settings: the sweep is one factor at a time, each across every level: the case's scene
defaults; ppc 1 and 3; every other shape function; the J-bar volume averaging.  ``--ppc``,
``--shapes``, ``--volume`` and ``--levels`` narrow it.

Per run: the loop's CPU time (``time.process_time``, all threads, compile excluded) and wall
time; the headline runout (``mpmjax.free_surface_front``: thickness >= 10 % of the thickest
point, bandwidth one cell) and the farthest-particle runout; the final height profile on
fixed stations with a fixed bandwidth (``PROFILE_BANDWIDTH``, the same at every level, so
profiles of different levels are comparable).  For the slump: the relative error of the front
against x_f and the RMS error of the profile against the exact one smoothed with the same
kernel, relative to the exact height at the wall.

Per series (one setting across the levels): successive differences of the runout, their
ratio per halving, the observed order p = log2(|q_h - q_h/2| / |q_h/2 - q_h/4|) of the finest
three levels and the Richardson extrapolate q_0 = q_h/4 + (q_h/4 - q_h/2) / (2^p - 1)
(REFERENCE.md), reported only where the differences keep their sign and 0.5 <= p < 6 (below
0.5 the extrapolate lies more than 2.4 last differences away; then null and the reason).

The JSON is rewritten after every run (an interrupt keeps the finished runs, and a rerun
reuses them; ``--fresh`` reruns).  The final particle positions of every run are kept in
``OUT/bench/converge/<case>/`` (npz) so that another front definition can be evaluated later
without rerunning.
"""

from __future__ import annotations

import functools
import json
import math
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np

from .._build import build
from .._io import _jsonable, atomic_write_text
from .._metrics import RunoutGauge, surface_profile
from .._observables import FRONT_FRACTION, gaussian_kernel
from .._schema import SceneError, load_scene, validate
from .._shapes import STENCIL
from .pareto import compile_final

SHAPES = tuple(STENCIL)
PROFILE_BANDWIDTH = {"lab": 0.02, "slump": 0.025, "water": 0.01}  # [m], fixed across levels
PROFILE_STATION = 0.005  # [m]

SLUMP_TAU_Y, SLUMP_RHO, SLUMP_G, SLUMP_MU = 82.0, 1000.0, 9.81, 7.0


def slump_scene() -> dict:
    """The Bingham slump: a 0.2 m x 0.2 m block against a symmetry wall at x = 0, no-slip base,
    6 s to rest (tests/test_rheology_mpm.py explains the viscosity and regularisation).  The per-particle
    pressure, as its tables were measured (and the J-bar series needs it); ``--set numerics.pressure=...``
    chooses another."""
    return {
        "name": "bingham-slump",
        "domain": {"lo_m": [0.0, 0.0], "hi_m": [1.0, 0.25], "cell_size_m": 0.0125},
        "boundary": {"x_lo": "symmetry", "x_hi": "slip", "y_lo": "noslip", "y_hi": "slip"},
        "numerics": {"shape": "gimp", "ppc": 2, "pressure": "explicit"},
        "time": {"t_end_s": 6.0, "n_frames": 12},
        "material": {
            "model": "bingham",
            "density_kg_m3": SLUMP_RHO,
            "bulk_modulus_pa": 15000.0,
            "viscosity_pa_s": SLUMP_MU,
            "yield_stress_pa": SLUMP_TAU_Y,
            "papanastasiou_m_s": 1e4,
        },
        "gravity": {"g_m_s2": SLUMP_G},
        "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.2]}],
    }


# case: (scene, {time overrides}, coarsest cell size [m], ci cell sizes)
CASES = {
    "lab": ("dambreak-lab", {"time.t_end_s": 15.0, "time.n_frames": 15}, 0.04),
    "slump": (None, {"time.t_end_s": 6.0, "time.n_frames": 12}, 0.05),
    "water": ("dambreak-water", {"time.t_end_s": 0.15, "time.n_frames": 3}, 0.02),
}
LEVELS = 4
CI = {"levels": 3, "t_end": {"lab": 0.3, "slump": 0.3, "water": 0.05}, "coarsest": {"lab": 0.04, "slump": 0.05, "water": 0.02}}


def _slump_exact(area_m2: float):
    """(x_f [m], k [m]) of the static Bingham slump holding ``area_m2`` per metre."""
    k = 2 * SLUMP_TAU_Y / (SLUMP_RHO * SLUMP_G)
    return (1.5 * area_m2 / math.sqrt(k)) ** (2.0 / 3.0), k


def case_config(case: str, overrides: dict) -> dict:
    """The validated scene of the convergence case ``case`` with the numerics ``overrides`` (key -> value)."""
    scene = CASES[case][0]
    if scene is None:
        raw = slump_scene()
        for key, val in overrides.items():
            sec, name = key.split(".", 1)
            raw.setdefault(sec, {})[name] = val
        return validate(raw)
    return load_scene(scene, overrides)


def run_one(case: str, overrides: dict, npz_path: Path | None = None) -> dict:
    """One run in this process: timings, fronts, profile (and the slump's errors); status."""
    rec: dict = {"status": "ok"}
    try:
        s = build(case_config(case, overrides))
    except SceneError as e:
        return {"status": "rejected", "reason": str(e)}
    sc = s.scene
    compiled = compile_final(s, rec)
    w0, c0 = time.perf_counter(), time.process_time()
    final = compiled(s.state, s.params)
    jax.block_until_ready(final.x)
    rec.update(wall_s=time.perf_counter() - w0, cpu_s=time.process_time() - c0)
    x = np.asarray(final.x)
    act = np.asarray(final.active, bool)
    vol0 = np.asarray(final.vol0)
    rec["n_lost"] = int(final.n_lost)
    if not np.all(np.isfinite(x[act])):
        rec.update(status="failed", reason="non-finite positions (blew up)")
        return rec
    if rec["n_lost"] > 0:
        rec.update(status="failed", reason=f"{rec['n_lost']} of {sc.n_particles} particles left the domain")
        return rec
    if npz_path is not None:
        npz_path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(npz_path, x=x, active=act, vol0=vol0, cell_size_m=sc.h)
    gauge = RunoutGauge.of(sc, s.info)
    rec["runout_m"] = gauge.front(x, vol0, act)
    rec["runout_farthest_m"] = gauge.farthest(x, act)
    rec["max_speed_m_s"] = float(np.max(np.linalg.norm(np.asarray(final.v)[act], axis=1)))
    _, hs = profile(case, x, vol0, act, sc.hi[0])
    rec["profile_m"] = hs.tolist()
    rec["area_m2"] = float(np.sum(vol0[act]))  # rest volume [m^2 per metre]: the slump's exact x_f
    if case == "slump":  # the area under its free surface against its particles' volume (voids)
        rec["occupied_area_m2"] = slump_occupied_area(x[act], vol0[act], sc.h)
        rec["volume_m2"] = float(np.sum((vol0 * np.asarray(final.J))[act]))
    return rec


def slump_errors(rec: dict, h: float) -> None:
    """The slump's errors against the exact static profile (added to ``rec``): the front
    against x_f, and against the same front definition applied to the exact profile (the
    exact profile smoothed with the run's bandwidth h: what a perfect solver would read);
    the farthest particle against x_f; the profile's RMS error relative to the exact height at
    the wall, over 0.2 x_f <= x <= 0.9 x_f (``profile_err_pct``) and over x <= 0.9 x_f
    (``profile_err_with_wall_pct``).  The tip's last 10 % is the kernel's, not the solver's;
    the first 20 % is within about one deposit height of the symmetry wall, where the exact
    profile's thin-layer (lubrication) assumption h << L does not hold: every shape and ppc
    at 8 to 32 cells over the block lies 9-12 % below it there and within ~4 % beyond it
    (docs/validation.md)."""
    x_f, k = _slump_exact(rec.get("area_m2", 0.04))
    xs = np.arange(0.0, 1.0 + 0.5 * PROFILE_STATION, PROFILE_STATION)
    hs = np.asarray(rec["profile_m"])
    ex = _exact_profile_on_stations(x_f, k)
    inner = (xs >= 0.2 * x_f) & (xs <= 0.9 * x_f)
    whole = xs <= 0.9 * x_f
    # the definition on the exact profile: smoothed with bandwidth h, last crossing of 10 % of its max
    xf_def = _exact_front_by_definition(x_f, k, h)
    if "occupied_area_m2" in rec:  # the same front for the area the deposit occupies (voids included)
        xo, ko = _slump_exact(rec["occupied_area_m2"])
        rec.update(occupied_front_m=xo, occupied_front_by_definition_m=_exact_front_by_definition(xo, ko, h))
    rec.update(
        exact_front_m=x_f,
        exact_front_by_definition_m=xf_def,
        front_err_pct=100.0 * (rec["runout_m"] - x_f) / x_f,
        front_err_def_pct=100.0 * (rec["runout_m"] - xf_def) / x_f,
        farthest_err_pct=100.0 * (rec["runout_farthest_m"] - x_f) / x_f,
        profile_err_pct=float(100 * np.sqrt(np.mean((hs[inner] - ex[inner]) ** 2)) / math.sqrt(k * x_f)),
        profile_err_with_wall_pct=float(100 * np.sqrt(np.mean((hs[whole] - ex[whole]) ** 2)) / math.sqrt(k * x_f)),
    )


@functools.lru_cache(maxsize=8)
def _exact_profile_on_stations(x_f: float, k: float) -> np.ndarray:
    xs = np.arange(0.0, 1.0 + 0.5 * PROFILE_STATION, PROFILE_STATION)
    return exact_slump_profile(xs, x_f, k, PROFILE_BANDWIDTH["slump"])


@functools.lru_cache(maxsize=64)
def _exact_front_by_definition(x_f: float, k: float, h: float) -> float:
    """``free_surface_front`` (bandwidth h, 10 % of the thickest point) of the exact slump."""
    xs = np.linspace(0.0, 1.0, 2001)
    prof = exact_slump_profile(xs, x_f, k, h)
    env = np.maximum.accumulate(prof[::-1])[::-1]
    thr = FRONT_FRACTION * prof.max()
    i = int(np.nonzero(env >= thr)[0][-1])
    return float(xs[i] + (xs[1] - xs[0]) * (env[i] - thr) / (env[i] - env[i + 1]))


def deposit_packing(x, J, vol0, cell_m: float) -> float:
    """How densely a 2D deposit's particles are packed against what their J says [-]: the volume
    per area, Sigma J V0 / bin area, averaged over square bins of two cells whose left, right and
    upper neighbours hold particles (the interior and the bottom row; bins at the free surface
    and the tip are partly empty and left out).  1 where the particles are spaced as their J
    says; above 1 they have closed up without J registering it (overpacking,
    benchmarks/accuracy/ppc_probe.md).  ``x`` (n, 2) [m], ``J`` (n,), ``vol0`` (n,) [m^2], active only."""
    b = 2.0 * cell_m
    ix, iy = np.floor(x[:, 0] / b).astype(int), np.floor(x[:, 1] / b).astype(int)
    vol = np.zeros((ix.max() + 2, iy.max() + 2))
    vol_j = np.zeros_like(vol)
    np.add.at(vol, (ix, iy), vol0)
    np.add.at(vol_j, (ix, iy), vol0 * J)
    occ = vol > 0
    inner = np.zeros_like(occ)
    inner[1:-1, :-1] = occ[1:-1, :-1] & occ[2:, :-1] & occ[:-2, :-1] & occ[1:-1, 1:]
    return float(np.mean(vol_j[inner] / b**2))


def occupied_area(x, cell_m: float, spacing: float) -> float:
    """Area under a 2D deposit's free surface [m^2 per metre] from x = 0: columns of width ``cell_m``, each up to its
    top particle plus half the particle ``spacing`` (``_metrics.surface_profile``).  ``x`` (n, 2) [m], active only."""
    n_bins = int(np.floor(np.max(x[:, 0]) / cell_m)) + 1
    _, top = surface_profile(x, np.ones(len(x), bool), cell_m * np.arange(n_bins + 1), spacing)
    return float(np.nansum(top) * cell_m)


def static_slump_lattice(x_f: float, k: float, spacing: float) -> np.ndarray:
    """Particles on a square lattice of ``spacing`` [m] filling the static slump profile H^2 = k (x_f - x),
    0 < x < x_f: what a perfect deposit's particles would be, for reading a measure's own bias."""
    xs = (np.arange(int(x_f / spacing) + 1) + 0.5) * spacing
    ys = (np.arange(int(math.sqrt(k * x_f) / spacing) + 1) + 0.5) * spacing
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    keep = Y**2 < k * (x_f - X)
    return np.stack([X[keep], Y[keep]], 1)


def slump_occupied_area(x, vol0, cell_m: float) -> float:
    """``occupied_area`` of a slump's deposit with the measure's own bias removed: divided by what it reads on
    the static profile holding the same rest area, filled at the particles' spacing (``static_slump_lattice``;
    1.008 at 16 cells over the block, 1.002 at 64, ppc 2).  Issue 31's "no voids" compares it with Sigma J V0."""
    spacing = float(np.sqrt(np.median(vol0)))
    x_f, k = _slump_exact(float(np.sum(vol0)))
    bias = occupied_area(static_slump_lattice(x_f, k, spacing), cell_m, spacing) / (2.0 / 3.0 * x_f * math.sqrt(k * x_f))
    return occupied_area(x, cell_m, spacing) / bias


def profile(case: str, x, vol0, active, x_hi: float):
    """(stations [m], height [m]) of the final deposit: rest-volume kernel profile with the
    case's fixed bandwidth (numpy; the same definition as ``mpmjax.height_profile``)."""
    xs = np.arange(0.0, x_hi + 0.5 * PROFILE_STATION, PROFILE_STATION)
    a = np.asarray(active, bool)
    v = np.where(a, vol0, 0.0)
    K = np.asarray(gaussian_kernel(xs[:, None] - np.where(a, x[:, 0], 0.0)[None, :], PROFILE_BANDWIDTH[case]))
    return xs, K @ v


def exact_slump_profile(xs, x_f: float, k: float, bandwidth: float):
    """The static slump h = sqrt(k (x_f - x)) on [0, x_f], mirrored about the symmetry wall
    x = 0 and smoothed with the Gaussian kernel of ``bandwidth`` (as the runs' profiles are)."""
    u = np.linspace(-x_f, x_f, 4001)
    hu = np.sqrt(np.clip(k * (x_f - np.abs(u)), 0.0, None))
    du = u[1] - u[0]
    K = np.asarray(gaussian_kernel(xs[:, None] - u[None, :], bandwidth))
    return K @ hu * du


def series_settings(shapes, ppcs, volumes, defaults: dict) -> list[tuple[str, dict]]:
    """(label, numerics overrides) of the one-factor-at-a-time series."""
    out = [("default", {})]
    for p in ppcs:
        if p != defaults["ppc"]:
            out.append((f"ppc={p}", {"numerics.ppc": p}))
    for s in shapes:
        if s != defaults["shape"]:
            out.append((s, {"numerics.shape": s}))
    for v in volumes:
        if v != defaults["volume"]:
            out.append((f"volume={v}", {"numerics.volume_averaging": v}))
    return out


def richardson(q) -> dict:
    """Observed order and extrapolate of a sequence at cell sizes halving (REFERENCE.md)."""
    q = [float(v) for v in q]
    d = [abs(q[i + 1] - q[i]) for i in range(len(q) - 1)]
    ratios = [d[i] / d[i + 1] if d[i + 1] > 0 else math.inf for i in range(len(d) - 1)]
    out: dict = {"differences": d, "ratios": ratios, "order": None, "extrapolate": None, "reason": None}
    if len(q) < 3:
        out["reason"] = "fewer than 3 levels"
        return out
    a, b, c = q[-3:]
    if abs(c - b) == 0 or abs(b - a) == 0:
        out["reason"] = "two equal levels"
        return out
    p = math.log2(abs(b - a) / abs(c - b))
    out["order"] = p
    if (b - a) * (c - b) < 0:
        out["reason"] = "differences change sign (oscillating, not monotone)"
    elif not 0.5 <= p < 6:
        # below 0.5 the extrapolation adds more than 2.4x the last difference: not trusted
        out["reason"] = f"observed order {p:.2f} outside [0.5, 6): not in the asymptotic range"
    else:
        out["extrapolate"] = c + (c - b) / (2**p - 1)
    return out


def analyse(doc: dict) -> dict:
    """Per case: each series' convergence, the reference, each run's error, the ppc spread per
    level and the acceptance figures of issue 14 item 3."""
    res: dict = {}
    for case, crow in doc["cases"].items():
        hs = crow["levels_m"]
        series: dict = {}
        for r in crow["rows"]:
            series.setdefault(r["series"], {})[r["level"]] = r
        conv = {}
        for name, runs in series.items():
            ok = [runs.get(i) for i in range(len(hs))]
            if all(r is not None and r.get("status") == "ok" for r in ok):
                conv[name] = {
                    "runout": richardson([r["runout_m"] for r in ok]),
                    "farthest": richardson([r["runout_farthest_m"] for r in ok]),
                }
        if case == "slump":
            ref = None  # the exact solution: each run carries its own errors
        else:
            dflt = conv.get("default", {}).get("runout", {})
            ref = dflt.get("extrapolate")
            if ref is None and "default" in series and len(series["default"]) == len(hs):
                ref = series["default"][len(hs) - 1]["runout_m"]  # the finest default run, said so below
        spread = {}
        ppc_series = [n for n in series if n == "default" or n.startswith("ppc=")]
        for i, h in enumerate(hs):
            vals = [series[n][i]["runout_m"] for n in ppc_series if i in series[n] and series[n][i].get("status") == "ok"]
            far = [
                series[n][i]["runout_farthest_m"]
                for n in ppc_series
                if i in series[n] and series[n][i].get("status") == "ok"
            ]
            if len(vals) >= 2:
                spread[f"{h:g}"] = {
                    "n_ppc": len(vals),
                    "runout_pct": 100 * (max(vals) - min(vals)) / np.mean(vals),
                    "farthest_pct": 100 * (max(far) - min(far)) / np.mean(far),
                }
        for r in crow["rows"]:
            if r.get("status") != "ok":
                continue
            if case == "slump":
                slump_errors(r, hs[r["level"]])
                r["error_pct"] = abs(r["front_err_pct"])
            elif ref is not None:
                r["error_pct"] = 100 * abs(r["runout_m"] - ref) / ref
        res[case] = {
            "convergence": conv,
            "reference_m": ref,
            "reference_kind": (
                "exact static profile"
                if case == "slump"
                else (
                    "Richardson extrapolate of the default series"
                    if conv.get("default", {}).get("runout", {}).get("extrapolate") is not None
                    else "finest default run (no convergent extrapolate)"
                )
            ),
            "ppc_spread": spread,
        }
    return res


def _fmt(v, spec):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


def markdown(doc: dict) -> str:
    """Tables for docs/validation.md: runs, series convergence, ppc spread."""
    out = []
    for case, crow in doc["cases"].items():
        an = doc["analysis"].get(case, {})
        out.append(f"\n#### {case}: {crow['description']}\n")
        out.append(
            "| series | h (m) | particles | steps | loop CPU (s) | runout (m) | farthest (m) | error (%) "
            + ("| front vs exact x_f (%) | vs exact by definition (%) | profile RMS, 0.2-0.9 x_f (%) | with the wall region (%) " if case == "slump" else "")
            + "| status |"
        )
        out.append("|" + "---|" * (13 if case == "slump" else 9))
        for r in crow["rows"]:
            extra = (
                f"| {_fmt(r.get('front_err_pct'), '+.2f')} | {_fmt(r.get('front_err_def_pct'), '+.2f')} "
                f"| {_fmt(r.get('profile_err_pct'), '.2f')} | {_fmt(r.get('profile_err_with_wall_pct'), '.2f')} "
                if case == "slump"
                else ""
            )
            out.append(
                f"| {r['series']} | {crow['levels_m'][r['level']]:g} | {_fmt(r.get('n_particles'), 'd')} "
                f"| {_fmt(r.get('n_steps'), 'd')} | {_fmt(r.get('cpu_s'), '.2f')} | {_fmt(r.get('runout_m'), '.4f')} "
                f"| {_fmt(r.get('runout_farthest_m'), '.4f')} | {_fmt(r.get('error_pct'), '.2f')} {extra}"
                f"| {r['status']}{': ' + r['reason'] if r.get('reason') else ''} |"
            )
        out.append(
            f"\nReference: {_fmt(an.get('reference_m'), '.4f')} m ({an.get('reference_kind')}).\n\n"
            "| series | runout differences per halving (m) | ratios | order p | extrapolate (m) "
            "| farthest: ratios | farthest: p | farthest: extrapolate (m) |\n|---|---|---|---|---|---|---|---|"
        )
        for name, c in an.get("convergence", {}).items():
            ru, fa = c["runout"], c["farthest"]
            out.append(
                f"| {name} | {', '.join(format(d, '.4f') for d in ru['differences'])} "
                f"| {', '.join(format(x, '.2f') for x in ru['ratios'])} | {_fmt(ru['order'], '.2f')} "
                f"| {_fmt(ru['extrapolate'], '.4f')}{' (' + ru['reason'] + ')' if ru['reason'] else ''} "
                f"| {', '.join(format(x, '.2f') for x in fa['ratios'])} | {_fmt(fa['order'], '.2f')} "
                f"| {_fmt(fa['extrapolate'], '.4f')} |"
            )
        if an.get("ppc_spread"):
            out.append("\n| h (m) | ppc runs | runout spread (%) | farthest-particle spread (%) |\n|---|---|---|---|")
            for h, sp in an["ppc_spread"].items():
                out.append(f"| {h} | {sp['n_ppc']} | {sp['runout_pct']:.2f} | {sp['farthest_pct']:.2f} |")
    return "\n".join(out)


def plot(doc: dict, path: Path) -> None:
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = list(doc["cases"])
    # one colour per series across every panel (a series' rows may be missing from a case)
    colour = {}
    for case in cases:
        for r in doc["cases"][case]["rows"]:
            colour.setdefault(r["series"], f"C{len(colour) % 10}")
    fig, axes = plt.subplots(2, len(cases), figsize=(5.2 * len(cases), 8.4), squeeze=False)
    for j, case in enumerate(cases):
        crow, an = doc["cases"][case], doc["analysis"].get(case, {})
        hs = crow["levels_m"]
        ax, axe = axes[0, j], axes[1, j]
        for name in dict.fromkeys(r["series"] for r in crow["rows"]):
            rows = sorted((r for r in crow["rows"] if r["series"] == name and r.get("status") == "ok"), key=lambda r: r["level"])
            if not rows:
                continue
            c = colour[name]
            ax.plot([hs[r["level"]] for r in rows], [r["runout_m"] for r in rows], "-o", c=c, ms=4, label=name)
            ax.plot([hs[r["level"]] for r in rows], [r["runout_farthest_m"] for r in rows], ":", c=c, lw=1)
            pts = [(r["cpu_s"], r["error_pct"]) for r in rows if r.get("error_pct") is not None]
            if pts:
                axe.plot(*zip(*pts), "-o", c=c, ms=4, label=name)
        if an.get("reference_m") is not None:
            ax.axhline(an["reference_m"], c="k", lw=1, ls="--", label="reference")
        ax.set_xscale("log", base=2)
        ax.set_xlabel("cell size h [m]")
        ax.set_ylabel("runout [m] (solid: free-surface front; dotted: farthest particle)")
        ax.set_title(f"{case}: runout against h", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6.5)
        axe.set_xscale("log")
        axe.set_yscale("log")
        axe.set_xlabel("time loop CPU time [s]")
        axe.set_ylabel("runout error [%]" + (" vs exact x_f" if case == "slump" else " vs reference"))
        axe.set_title(f"{case}: error against CPU time", fontsize=9)
        axe.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run_meta() -> dict:
    """Where and when a study ran: Python, machine, cores, jax, start time (UTC)."""
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "started_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
    }


def run_converge(
    cases=("lab", "slump", "water"),
    *,
    size: str = "full",
    out: Path | str = "docs",
    levels: int | None = None,
    ppcs=(1, 2, 3),
    shapes=SHAPES,
    volumes=("none", "jbar"),
    fresh: bool = False,
    base: dict | None = None,
    log=None,
) -> dict:
    """Run the sweep (``base``: scene overrides applied to every run, e.g. another default shape); write ``OUT/bench/converge.json`` (after every run), ``OUT/img/converge.png``
    and ``OUT/bench/converge.md``.  Returns the JSON document."""
    if log is None:

        def log(msg):
            print(msg, flush=True)

    if size not in ("ci", "full"):
        raise ValueError(f"size = {size!r}; allowed: ci, full")
    for c in cases:
        if c not in CASES:
            raise ValueError(f"case {c!r}; allowed: {', '.join(CASES)}")
    out = Path(out)
    (out / "bench").mkdir(parents=True, exist_ok=True)
    (out / "img").mkdir(parents=True, exist_ok=True)
    jpath, ppath, mpath = out / "bench" / "converge.json", out / "img" / "converge.png", out / "bench" / "converge.md"
    old = {}
    if jpath.exists() and not fresh:
        try:
            prev = json.loads(jpath.read_text())
            if prev.get("size") == size:
                for case, crow in prev.get("cases", {}).items():
                    for r in crow.get("rows", []):
                        old[(case, json.dumps(r["overrides"], sort_keys=True))] = r
        except (OSError, ValueError, KeyError):
            old = {}
    n_levels = levels or (CI["levels"] if size == "ci" else LEVELS)
    doc: dict = {
        "size": size,
        "meta": run_meta(),
        "profile_station_m": PROFILE_STATION,
        "profile_bandwidth_m": PROFILE_BANDWIDTH,
        "cases": {},
        "analysis": {},
    }
    for case in cases:
        scene, time_ov, coarsest = CASES[case]
        if size == "ci":
            coarsest = CI["coarsest"][case]
            time_ov = {"time.t_end_s": CI["t_end"][case], "time.n_frames": 1}
        hs = [coarsest / 2**i for i in range(n_levels)]
        cfg0 = case_config(case, dict(base or {}))
        defaults = {
            "ppc": cfg0["numerics.ppc"],
            "shape": cfg0["numerics.shape"],
            "volume": cfg0["numerics.volume_averaging"],
        }
        settings = series_settings(shapes, ppcs, volumes, defaults)
        desc = {
            "lab": "thesis lab dam break (BASE Coussot), runout at 15 s",
            "slump": "Bingham slump to rest (tau_y 82 Pa), against the exact static profile",
            "water": "water column (Cruchaga), front at 0.15 s",
        }[case]
        crow = {"description": desc, "levels_m": hs, "defaults": defaults, "base": base or {}, "time": time_ov, "rows": []}
        doc["cases"][case] = crow
        # finished runs of this case that this invocation does not repeat (a narrower --shapes or
        # --ppc than last time) stay in the JSON, so that narrowing a rerun loses nothing
        planned = {
            json.dumps({**(base or {}), **time_ov, **ov, "domain.cell_size_m": h}, sort_keys=True)
            for _, ov in settings
            for h in hs
        }
        for (c, k), r in old.items():
            h = r.get("overrides", {}).get("domain.cell_size_m")
            if c == case and k not in planned and h in hs and r.get("series") is not None:
                crow["rows"].append(dict(r, level=hs.index(h), reused=True))
        log(f"\n{case}: {desc}; h = {', '.join(format(h, 'g') for h in hs)} m; {len(settings)} series")
        for name, ov in settings:
            for i, h in enumerate(hs):
                overrides = {**(base or {}), **time_ov, **ov, "domain.cell_size_m": h}
                key = (case, json.dumps(overrides, sort_keys=True))
                if key in old and old[key].get("status") in ("ok", "failed", "rejected"):
                    rec = dict(old[key], reused=True)
                else:
                    slug = f"{name}_h{h:g}".replace("=", "").replace(".", "p")
                    rec = run_one(case, overrides, out / "bench" / "converge" / case / f"{slug}.npz")
                rec.update(series=name, level=i, overrides=overrides)
                crow["rows"].append(rec)
                doc["analysis"] = analyse(doc)
                atomic_write_text(jpath, json.dumps(_jsonable(doc), indent=1))
                log(
                    f"  {name:14s} h={h:<8g} {rec['status']:8s} cpu {_fmt(rec.get('cpu_s'), '8.2f')} s  runout "
                    f"{_fmt(rec.get('runout_m'), '.4f')} m  farthest {_fmt(rec.get('runout_farthest_m'), '.4f')} m"
                    + (" (reused)" if rec.get("reused") else "")
                    + (f"  {rec.get('reason')}" if rec.get("reason") else "")
                )
    doc["analysis"] = analyse(doc)
    doc["meta"]["finished_utc"] = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
    doc["markdown"] = markdown(doc)
    atomic_write_text(jpath, json.dumps(_jsonable(doc), indent=1))
    atomic_write_text(mpath, doc["markdown"] + "\n")
    plot(doc, ppath)
    log(doc["markdown"])
    log(f"\nwrote {jpath}, {mpath} and {ppath}")
    return doc


def report(out: Path | str = "converge", log=None) -> dict:
    """Re-analyse ``OUT/bench/converge.json`` as it stands (an interrupted or partial sweep
    included) and rewrite its tables and plot, without running anything."""
    out = Path(out)
    jpath = out / "bench" / "converge.json"
    doc = json.loads(jpath.read_text())
    doc["analysis"] = analyse(doc)
    doc["markdown"] = markdown(doc)
    atomic_write_text(jpath, json.dumps(_jsonable(doc), indent=1))
    atomic_write_text(out / "bench" / "converge.md", doc["markdown"] + "\n")
    (out / "img").mkdir(parents=True, exist_ok=True)
    plot(doc, out / "img" / "converge.png")
    (log or print)(doc["markdown"])
    return doc
