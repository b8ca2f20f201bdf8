"""``mpmjax pareto``: error against run time for the lab dam break (``dambreak-lab``, BASE).

Method (also in ``docs/performance.md``, section "Error against run time (Pareto)"):

* A **reference** run at the finest affordable resolution (``--size full``: h = 0.01/4 m,
  float64) and **check** runs one and two levels coarser (h = 0.01/3 and 0.005 m, float64); the
  difference of the two finest is the estimate of the reference's own error.
* A **sweep** of the numerics, one factor at a time around the scene's defaults (cell size,
  particles per cell, shape function, transfer, CFL factor, dtype), plus the cell size crossed
  with a few of the others.
* For every run: the wall time and the process CPU time (``time.process_time``: all threads of
  the process) of the compiled time loop, excluding compilation, and the compile time; the
  runout (``mpmjax.runout`` of the final state) and its error against the reference [m, %];
  the **profile error**: RMS difference [mm] of the final free-surface height (``surface_profile``
  in 2 cm bins of x, empty bins inside the deposit interpolated, 0 outside it) against the
  reference's, over the bins wetted in either.
* A run **fails** if its final state is not finite or it lost particles (``n_lost`` > 0: they left
  the domain); a failed run is a data point with no error.  A combination the scene loader
  rejects is recorded as rejected.
* The **Pareto front** (minimise both the CPU time and the error) is computed for the runout
  error and for the profile error, among the successful runs (the reference itself excluded).

``--size full`` runs each case in a fresh Python process (so that a float64 run, which switches
on ``jax_enable_x64`` process-wide, does not change the float32 runs; and so that one process's
caches do not favour the next).  ``--size ci`` is tiny (0.3 s of simulated time, three runs
and a reference at h = 0.01 m, in one process) for the test suite.  The JSON is rewritten after
every run, so an interrupt keeps the finished runs; an existing JSON's finished runs with the
same settings are reused (``--fresh`` reruns everything).
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

from .._build import build
from .._io import _jsonable, atomic_write_text
from .._metrics import surface_profile
from .._observables import runout
from .._schema import SceneError, load_scene
from .._simulate import simulate

SCENE = "dambreak-lab"
# the settings each row records, read from the scene with the row's overrides (so a change of the
# scene's defaults shows in the table and is never mistaken for a finished row)
SETTING_KEYS = (
    "domain.cell_size_m",
    "numerics.ppc",
    "numerics.shape",
    "numerics.transfer",
    "numerics.flip_blend",
    "numerics.cfl",
    "numerics.dtype",
    "numerics.pressure",
)
PROFILE_BIN_M = 0.02  # width of the x bins of the free-surface profile [m]

F64 = {"numerics.dtype": "float64"}


def _h(h):
    return {"domain.cell_size_m": h}


# (label, overrides relative to the scene defaults)
FULL_REFERENCE = ("ref h=0.01/4 f64", {**_h(0.0025), **F64})
FULL_CASES = [
    ("check h=0.01/3 f64", {**_h(0.01 / 3), **F64}),
    ("check h=0.005 f64", {**_h(0.005), **F64}),
    ("default", {}),
    ("h=0.04", _h(0.04)),
    ("h=0.02", _h(0.02)),
    ("h=0.005", _h(0.005)),
    ("ppc=1", {"numerics.ppc": 1}),
    ("ppc=3", {"numerics.ppc": 3}),
    ("linear", {"numerics.shape": "linear"}),
    ("quadratic", {"numerics.shape": "quadratic"}),
    ("cubic", {"numerics.shape": "cubic"}),
    ("flip 0.95", {"numerics.transfer": "flip"}),
    ("pic", {"numerics.transfer": "flip", "numerics.flip_blend": 0.0}),
    ("cfl=0.2", {"numerics.cfl": 0.2}),
    ("cfl=0.6", {"numerics.cfl": 0.6}),
    ("cfl=0.8", {"numerics.cfl": 0.8}),
    ("cfl=1.0", {"numerics.cfl": 1.0}),
    ("float64", F64),
    # the cell size crossed with a few of the others
    ("h=0.02 cfl=0.8", {**_h(0.02), "numerics.cfl": 0.8}),
    ("h=0.04 cfl=0.8", {**_h(0.04), "numerics.cfl": 0.8}),
    ("h=0.005 cfl=0.8", {**_h(0.005), "numerics.cfl": 0.8}),
    ("h=0.02 ppc=3", {**_h(0.02), "numerics.ppc": 3}),
    ("h=0.04 ppc=3", {**_h(0.04), "numerics.ppc": 3}),
    ("h=0.02 quadratic", {**_h(0.02), "numerics.shape": "quadratic"}),
    ("h=0.005 quadratic", {**_h(0.005), "numerics.shape": "quadratic"}),
    ("h=0.02 cubic", {**_h(0.02), "numerics.shape": "cubic"}),
    ("h=0.02 float64", {**_h(0.02), **F64}),
    # does the particles-per-cell effect vanish with the cell size? (ppc 1 and 3 at h = 0.02, 0.005 m)
    ("h=0.02 ppc=1", {**_h(0.02), "numerics.ppc": 1}),
    ("h=0.005 ppc=1", {**_h(0.005), "numerics.ppc": 1}),
    ("h=0.005 ppc=3", {**_h(0.005), "numerics.ppc": 3}),
]
CI_REFERENCE = ("ref h=0.01", {})
CI_CASES = [
    ("h=0.04", _h(0.04)),
    ("h=0.02", _h(0.02)),
    ("h=0.02 cfl=0.8", {**_h(0.02), "numerics.cfl": 0.8}),
]
SIZES = {
    # size: (reference, cases, t_end [s], n_frames, one process per run)
    "ci": (CI_REFERENCE, CI_CASES, 0.3, 3, False),
    "full": (FULL_REFERENCE, FULL_CASES, 15.0, 60, True),
}


def profile_edges(lo: float = 0.0, hi: float = 2.0, width: float = PROFILE_BIN_M) -> np.ndarray:
    """Bin edges [m] of the common x grid of the free-surface profiles."""
    n = int(round((hi - lo) / width))
    return lo + width * np.arange(n + 1)


def filled_profile(x, active, edges, spacing_m: float) -> np.ndarray:
    """Free-surface height [m] per bin (``surface_profile``); empty bins between the first and last
    wetted bin are linearly interpolated (a coarse run leaves gaps between its particle columns),
    bins outside the deposit are 0 (the bed, y = 0)."""
    xc, top = surface_profile(x, active, edges, spacing_m)
    good = np.isfinite(top)
    out = np.zeros_like(xc)
    if good.any():
        i0, i1 = np.nonzero(good)[0][[0, -1]]
        inner = slice(i0, i1 + 1)
        out[inner] = np.interp(xc[inner], xc[good], top[good])
    return out


def profile_rms_mm(h_run, h_ref) -> float:
    """RMS difference [mm] of two filled profiles over the bins wetted (h > 0) in either."""
    a, b = np.asarray(h_run, float), np.asarray(h_ref, float)
    wet = (a > 0) | (b > 0)
    if not wet.any():
        return 0.0
    return float(1e3 * np.sqrt(np.mean((a[wet] - b[wet]) ** 2)))


def pareto_front(cost, err) -> list[bool]:
    """True for the points not dominated by another (minimising both ``cost`` and ``err``): a
    point is dominated when another is no worse in both and strictly better in one.  Points
    with a non-finite coordinate are never on the front."""
    c, e = np.asarray(cost, float), np.asarray(err, float)
    ok = np.isfinite(c) & np.isfinite(e)
    front = []
    for i in range(c.size):
        if not ok[i]:
            front.append(False)
            continue
        dom = ok & (c <= c[i]) & (e <= e[i]) & ((c < c[i]) | (e < e[i]))
        front.append(not bool(dom.any()))
    return front


def _settings(overrides: dict) -> dict:
    """The row's settings as run: the scene's values with the row's overrides."""
    try:
        cfg = load_scene(SCENE, overrides)
    except SceneError:  # a rejected row: the scene's values with what it asked for
        cfg = {**load_scene(SCENE), **overrides}
    return {k: cfg[k] for k in SETTING_KEYS if k in cfg}


def compile_final(s, rec: dict):
    """The run of the built setup ``s`` to its final state, compiled; records the particle and
    step counts and the compile wall and CPU times in ``rec`` (shared with ``studies.converge``)."""
    sc = s.scene
    rec.update(n_particles=sc.n_particles, n_steps=sc.n_steps, dt_s=sc.dt)
    f = jax.jit(lambda st, p: simulate(sc, st, p)[0])
    w0, c0 = time.perf_counter(), time.process_time()
    compiled = f.lower(s.state, s.params).compile()
    rec.update(compile_wall_s=time.perf_counter() - w0, compile_cpu_s=time.process_time() - c0)
    return compiled


def run_case(overrides: dict, t_end: float, n_frames: int, edges) -> dict:
    """One run in this process: timings, runout [m], filled profile [m] on ``edges``, status."""
    ov = {**overrides, "time.t_end_s": t_end, "time.n_frames": n_frames}
    rec = {"status": "ok"}
    try:
        s = build(load_scene(SCENE, ov))
    except SceneError as e:
        return {"status": "rejected", "reason": str(e)}
    sc = s.scene
    compiled = compile_final(s, rec)
    walls, cpus = [], []
    while True:  # a loop shorter than 2 s is repeated (best of up to 3) to tame the noise
        w0, c0 = time.perf_counter(), time.process_time()
        final = compiled(s.state, s.params)
        jax.block_until_ready(final.x)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
        if walls[-1] > 2.0 or len(walls) == 3:
            break
    rec.update(wall_s=min(walls), cpu_s=min(cpus), repetitions=len(walls))
    x = np.asarray(final.x, float)
    act = np.asarray(final.active, bool)
    n_lost = int(final.n_lost)
    spacing = s.info["particle_spacing_m"]
    rec["n_lost"] = n_lost
    if not np.all(np.isfinite(x[act])):
        rec.update(status="failed", reason="non-finite positions (blew up)")
        return rec
    if n_lost > 0:
        rec.update(status="failed", reason=f"{n_lost} of {sc.n_particles} particles left the domain")
        return rec
    rec["runout_m"] = float(runout(x, act, s.info["runout_axis"], s.info["runout_origin_m"], spacing))
    rec["profile_m"] = filled_profile(x, act, edges, spacing).tolist()
    return rec


def _run_isolated(overrides: dict, t_end: float, n_frames: int, edges) -> dict:
    """``run_case`` in a fresh Python process (its own jax_enable_x64 and caches)."""
    arg = json.dumps({"overrides": overrides, "t_end": t_end, "n_frames": n_frames, "edges": list(edges)})
    p = subprocess.run(
        [sys.executable, "-m", "mpmjax.studies.pareto", arg], capture_output=True, text=True, env=dict(os.environ)
    )
    lines = p.stdout.strip().splitlines()
    if p.returncode != 0 or not lines:
        tail = (p.stderr or "").strip().splitlines()[-3:]
        return {"status": "failed", "reason": f"process exit {p.returncode}: {' | '.join(tail)}"}
    return json.loads(lines[-1])


def _errors(rec: dict, ref: dict) -> None:
    if rec.get("status") != "ok" or ref.get("status") != "ok":
        return
    d = rec["runout_m"] - ref["runout_m"]
    rec["runout_err_m"] = abs(d)
    rec["runout_signed_err_m"] = d
    rec["runout_err_pct"] = 100.0 * abs(d) / ref["runout_m"]
    rec["profile_rms_mm"] = profile_rms_mm(rec["profile_m"], ref["profile_m"])


def _mark_fronts(rows: list[dict]) -> None:
    pts = [r for r in rows if r.get("status") == "ok" and not r.get("is_reference")]
    for key, err in (("front_runout", "runout_err_m"), ("front_profile", "profile_rms_mm")):
        flags = pareto_front([r["cpu_s"] for r in pts], [r[err] for r in pts])
        for r in rows:
            r[key] = False
        for r, f in zip(pts, flags):
            r[key] = bool(f)


def _fmt(v, spec):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, spec)


HEADER = (
    f"{'case':18s} {'h (m)':>7s} {'ppc':>3s} {'shape':9s} {'transfer':8s} {'cfl':>4s} {'dtype':7s} "
    f"{'parts':>6s} {'steps':>6s} {'wall s':>7s} {'cpu s':>7s} {'comp s':>6s} {'runout m':>8s} "
    f"{'err m':>7s} {'err %':>6s} {'prof mm':>7s} status"
)


def _transfer(st: dict) -> str:
    if st["numerics.transfer"] == "apic":
        return "apic"
    b = st.get("numerics.flip_blend", 0.95)
    return "pic" if b == 0.0 else f"flip{b:g}"


def row_line(r: dict) -> str:
    st = r["settings"]
    fr = ("R" if r.get("front_runout") else "") + ("P" if r.get("front_profile") else "")
    status = r["status"] + (f" ({r['reason']})" if r.get("reason") else "") + (f" front:{fr}" if fr else "")
    return (
        f"{r['label']:18s} {st['domain.cell_size_m']:7.4f} {st['numerics.ppc']:3d} {st['numerics.shape']:9s} "
        f"{_transfer(st):8s} {st['numerics.cfl']:4.2f} {st['numerics.dtype']:7s} "
        f"{_fmt(r.get('n_particles'), '6d')} {_fmt(r.get('n_steps'), '6d')} {_fmt(r.get('wall_s'), '7.2f')} "
        f"{_fmt(r.get('cpu_s'), '7.2f')} {_fmt(r.get('compile_wall_s'), '6.1f')} {_fmt(r.get('runout_m'), '8.4f')} "
        f"{_fmt(r.get('runout_err_m'), '7.4f')} {_fmt(r.get('runout_err_pct'), '6.2f')} "
        f"{_fmt(r.get('profile_rms_mm'), '7.2f')} {status}"
    )


def markdown(rows: list[dict]) -> str:
    out = [
        "| case | h (m) | ppc | shape | transfer | cfl | dtype | particles | steps | loop wall (s) | loop CPU (s) "
        "| compile (s) | runout (m) | runout error (m) | (%) | profile RMS (mm) | front | status |",
        "|" + "---|" * 18,
    ]
    for r in rows:
        st = r["settings"]
        fr = ", ".join(n for k, n in (("front_runout", "runout"), ("front_profile", "profile")) if r.get(k))
        out.append(
            f"| {r['label']} | {st['domain.cell_size_m']:.4g} | {st['numerics.ppc']} | {st['numerics.shape']} "
            f"| {_transfer(st)} | {st['numerics.cfl']:g} | {st['numerics.dtype']} | {_fmt(r.get('n_particles'), 'd')} "
            f"| {_fmt(r.get('n_steps'), 'd')} | {_fmt(r.get('wall_s'), '.2f')} | {_fmt(r.get('cpu_s'), '.2f')} "
            f"| {_fmt(r.get('compile_wall_s'), '.1f')} | {_fmt(r.get('runout_m'), '.4f')} "
            f"| {_fmt(r.get('runout_err_m'), '.4f')} | {_fmt(r.get('runout_err_pct'), '.2f')} "
            f"| {_fmt(r.get('profile_rms_mm'), '.2f')} | {fr} | {r['status']}"
            + (f": {r['reason']}" if r.get("reason") else "")
            + " |"
        )
    return "\n".join(out)


def plot(rows: list[dict], path: Path, title: str) -> None:
    # matplotlib only when a plot is made (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts = [r for r in rows if r.get("status") == "ok" and not r.get("is_reference")]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    panels = (
        ("runout_err_m", "front_runout", "runout error at the final time (m)"),
        ("profile_rms_mm", "front_profile", "free-surface profile RMS error (mm)"),
    )
    for ax, (key, fkey, ylabel) in zip(axes, panels):
        c = np.array([r["cpu_s"] for r in pts])
        e = np.array([max(r[key], 1e-6) for r in pts])  # a log axis cannot show an exact 0
        on = np.array([r[fkey] for r in pts])
        ax.scatter(c[~on], e[~on], c="0.55", s=22, label="dominated")
        ax.scatter(c[on], e[on], c="tab:red", s=40, zorder=3, label="Pareto front")
        order = np.argsort(c[on])
        ax.step(c[on][order], e[on][order], where="post", c="tab:red", lw=1, alpha=0.6)
        for r, ci, ei in zip(pts, c, e):
            ax.annotate(r["label"], (ci, ei), fontsize=6.5, xytext=(3, 2), textcoords="offset points")
            if r["label"] == "default":
                ax.scatter([ci], [ei], marker="*", s=160, facecolors="none", edgecolors="k", zorder=4)
        chk = [r for r in pts if r["label"].startswith("check")]
        if chk and chk[0][key] > 0:
            ax.axhline(chk[0][key], ls="--", c="tab:blue", lw=1, label="reference error estimate (check level)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time loop CPU time (s, process_time, excl. compile)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, loc="best", framealpha=0.6)
    bad = [r["label"] for r in rows if r.get("status") != "ok"]
    fig.suptitle(title + (f"\nnot plotted (failed/rejected): {', '.join(bad)}" if bad else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_pareto(size: str = "ci", out: Path | str = "docs", fresh: bool = False, log=None) -> dict:
    """Run the sweep; write ``OUT/bench/pareto_dambreak_lab.json`` (after every run) and
    ``OUT/img/pareto_dambreak_lab.png``.  Returns the JSON document."""
    if log is None:

        def log(msg):
            print(msg, flush=True)

    if size not in SIZES:
        raise ValueError(f"--size {size!r} is invalid; allowed: {sorted(SIZES)}")
    reference, cases, t_end, n_frames, isolate = SIZES[size]
    out = Path(out)
    (out / "bench").mkdir(parents=True, exist_ok=True)
    (out / "img").mkdir(parents=True, exist_ok=True)
    jpath = out / "bench" / "pareto_dambreak_lab.json"
    ppath = out / "img" / "pareto_dambreak_lab.png"
    edges = profile_edges()
    old = {}
    if jpath.exists() and not fresh:
        try:
            prev = json.loads(jpath.read_text())
            if prev.get("size") == size and prev.get("t_end_s") == t_end:
                old = {json.dumps(r.get("settings"), sort_keys=True): r for r in prev.get("rows", [])}
        except (OSError, ValueError, KeyError):
            old = {}
    doc = {
        "scene": SCENE,
        "size": size,
        "t_end_s": t_end,
        "n_frames": n_frames,
        "profile_bin_m": PROFILE_BIN_M,
        "profile_x_edges_m": edges.tolist(),
        "reference": reference[0],
        "meta": {
            "python": platform.python_version(),
            "machine": platform.machine(),
            "cpu_count": os.cpu_count(),
            "started_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
            "one_process_per_run": isolate,
        },
        "rows": [],
    }
    log(f"pareto --size {size}: {SCENE}, t_end = {t_end} s, {len(cases) + 1} runs, reference {reference[0]}")
    log(HEADER)
    ref = None
    for i, (label, ov) in enumerate([reference, *cases]):
        settings = _settings(ov)
        key = json.dumps(_jsonable(settings), sort_keys=True)
        if key in old and old[key].get("status") in ("ok", "failed", "rejected") and "cpu_s" in old[key]:
            rec = dict(old[key])
            rec["reused"] = True
        else:
            rec = (_run_isolated if isolate else run_case)(ov, t_end, n_frames, edges)
        rec.update(label=label, overrides=ov, settings=settings, is_reference=(i == 0))
        if i == 0:
            ref = rec
            if rec["status"] != "ok":
                raise RuntimeError(f"the reference run failed: {rec.get('reason')}")
        _errors(rec, ref)
        doc["rows"].append(rec)
        _mark_fronts(doc["rows"])
        doc["markdown"] = markdown(doc["rows"])
        atomic_write_text(jpath, json.dumps(_jsonable(doc), indent=1))
        log(row_line(rec) + (" (reused)" if rec.get("reused") else ""))
    log("\nfinal table (front: R runout, P profile)\n" + HEADER)
    for r in doc["rows"]:
        log(row_line(r))
    doc["meta"]["finished_utc"] = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
    atomic_write_text(jpath, json.dumps(_jsonable(doc), indent=1))
    plot(doc["rows"], ppath, f"{SCENE} (BASE), t = {t_end:g} s: error vs CPU time, reference {reference[0]}")
    log("\nPareto front (runout error vs CPU time): " + ", ".join(r["label"] for r in doc["rows"] if r["front_runout"]))
    log("Pareto front (profile error vs CPU time): " + ", ".join(r["label"] for r in doc["rows"] if r["front_profile"]))
    log(f"wrote {jpath} and {ppath}")
    return doc



if __name__ == "__main__":  # one isolated run: python -m mpmjax.studies.pareto '{"overrides": ...}'
    a = json.loads(sys.argv[1])
    r = run_case(a["overrides"], a["t_end"], a["n_frames"], np.asarray(a["edges"]))
    print(json.dumps(_jsonable(r)))
