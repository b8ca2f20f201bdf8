"""``mpmjax study NAME``: the thesis's sensitivity tables and the stiff-viscosity comparison.

These are measurements, recorded in docs/validation.md, not tests:

* ``numerical``: thesis Table 7 on the BASE lab dam break: cell size, particles per
  cell, shape function and time-step multiplier; runout at 15 s and its spread.
* ``physical``: thesis Table 8, runs BASE and 5a-10b, with the standard shear measure
  and the thesis-compatible one.
* ``stiff``: the naive explicit viscous update against the Maxwell exponential update
  on BASE: the time step each needs, the wall time, the runout.

Each writes ``study_NAME.json`` and ``study_NAME.md`` (a table) to ``--out``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

from .._build import build
from .._metrics import RunoutGauge
from .._schema import load_scene
from .._simulate import run

# Thesis Table 8 (runs 5a-10b) as overrides of the BASE scene, with the thesis's runout
# direction relative to BASE: +1 longer, -1 shorter, 0 no change (from §4.5.3 text and
# the viscosity curves; "Parameters that reduce the viscosity ... show longer runouts").
TABLE8 = [
    ("BASE", {}, None),
    ("5a", {"material.mu0_pa_s": 0.1}, +1),
    ("5b", {"material.mu0_pa_s": 1.0}, +1),
    ("6a", {"material.n": 1.5}, None),
    ("6b", {"material.n": 2.0}, None),
    ("6c", {"material.n": 3.0}, None),
    ("7a", {"material.alpha": 0.5}, -1),
    ("7b", {"material.alpha": 2.0}, +1),
    ("7c", {"material.alpha": 10.0}, +1),
    ("8a", {"material.lambda0": 1.0}, +1),
    ("8b", {"material.lambda0": 2.0}, -1),
    ("8c", {"material.lambda0": 10.0}, -1),
    ("9a", {"material.bulk_modulus_pa": 1.5e6}, 0),
    ("10a", {"material.density_kg_m3": 1200.0}, -1),
    ("10b", {"material.density_kg_m3": 3000.0}, +1),
]

# Thesis Table 7: (run, overrides); the thesis used GIMP and multiplier 0.6 as its base.
TABLE7 = [
    ("1a h=0.01", {"domain.cell_size_m": 0.01}),
    ("1b h=0.005", {"domain.cell_size_m": 0.005}),
    ("1c h=0.0033", {"domain.cell_size_m": 0.2 / 60}),
    ("2a ppc=2", {"numerics.ppc": 2}),
    ("2b ppc=3", {"numerics.ppc": 3}),
    ("2c ppc=4", {"numerics.ppc": 4}),
    ("3a cfl=0.2", {"numerics.cfl": 0.2}),
    ("3b cfl=0.9", {"numerics.cfl": 0.9}),
    ("4 linear", {"numerics.shape": "linear"}),
    ("4 gimp", {"numerics.shape": "gimp"}),
    ("4 quadratic", {"numerics.shape": "quadratic"}),
    ("4 cubic", {"numerics.shape": "cubic"}),
]


def _one(overrides: dict, scene="dambreak-lab") -> dict:
    cfg = load_scene(scene, overrides)
    s = build(cfg)
    t0 = time.perf_counter()
    final, frames = run(s.scene, s.state, s.params)
    jax.block_until_ready(final.x)
    wall = time.perf_counter() - t0
    gauge = RunoutGauge.of(s.scene, s.info)
    i1 = max(0, round(len(frames.x) / 15) - 1)  # the frame at 1 s of 15 s
    finite = bool(np.all(np.isfinite(np.asarray(final.x))))
    return {
        "overrides": overrides,
        "ppc": cfg["numerics.ppc"],
        # headline: the free-surface front (as summary.json runout_m); farthest particle secondary
        "runout_15s_m": gauge.front(final.x, final.vol0, final.active),
        "runout_farthest_15s_m": gauge.farthest(final.x, final.active),
        "runout_1s_m": gauge.front(frames.x[i1], final.vol0, frames.active[i1]),
        "n_lost": int(final.n_lost),
        "finite": finite,
        "dt_s": s.scene.dt,
        "n_steps": s.scene.n_steps,
        "n_particles": s.scene.n_particles,
        "wall_s_incl_compile": wall,
        "mu_max_reached_pa_s": float(np.max(np.asarray(final.mu))),
    }


def study_physical(out: Path, log, measures=("standard", "thesis")) -> dict:
    rows = []
    for measure in measures:
        for run_id, ov, expect in TABLE8:
            ov = dict(ov, **{"material.shear_measure": measure})
            r = _one(ov)
            r.update(run=run_id, shear_measure=measure, thesis_direction=expect)
            rows.append(r)
            log(
                f"{measure:8s} {run_id:5s} runout {r['runout_15s_m']:.3f} m lost {r['n_lost']} "
                f"({r['wall_s_incl_compile']:.0f} s)"
            )
    base = {r["shear_measure"]: r["runout_15s_m"] for r in rows if r["run"] == "BASE"}
    for r in rows:
        d = r["runout_15s_m"] - base[r["shear_measure"]]
        r["delta_vs_base_m"] = d
        r["direction"] = 0 if abs(d) < 0.01 * base[r["shear_measure"]] else int(math.copysign(1, d))
        r["matches_thesis"] = None if r["thesis_direction"] is None else r["direction"] == r["thesis_direction"]
    md = [
        "| run | change | "
        + " | ".join(f"runout {m} measure (m) | farthest particle (m) | dir" for m in measures)
        + " | thesis direction |",
        "|---|---|" + "---|---|---|" * len(measures) + "---|",
    ]
    sym = {1: "+", -1: "−", 0: "0", None: "n/a"}
    for run_id, ov, expect in TABLE8:
        ch = ", ".join(f"{k.split('.')[1]}={v:g}" for k, v in ov.items()) or "BASE"
        cells = []
        for m in measures:
            (a,) = [r for r in rows if r["run"] == run_id and r["shear_measure"] == m]
            cells.append(f"{a['runout_15s_m']:.3f} | {a['runout_farthest_15s_m']:.3f} | {sym[a['direction']]}")
        md.append(f"| {run_id} | {ch} | " + " | ".join(cells) + f" | {sym[expect]} |")
    return {"rows": rows, "markdown": "\n".join(md)}


def study_numerical(out: Path, log) -> dict:
    rows = []
    for run_id, ov in TABLE7:
        r = _one(ov)
        r.update(run=run_id)
        rows.append(r)
        log(
            f"{run_id:14s} runout {r['runout_15s_m']:.3f} m, {r['n_particles']} particles, {r['n_steps']} steps, "
            f"{r['wall_s_incl_compile']:.0f} s"
        )
    ro = np.array([r["runout_15s_m"] for r in rows])
    spread = {
        "min_m": float(ro.min()),
        "max_m": float(ro.max()),
        "mean_m": float(ro.mean()),
        "max_rel_dev_from_mean": float(np.max(np.abs(ro - ro.mean())) / ro.mean()),
    }
    md = [
        "| run | particles | steps | dt (s) | runout 15 s (m) | farthest particle (m) | wall (s, incl. compile) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['run']} | {r['n_particles']} | {r['n_steps']} | {r['dt_s']:.3g} | {r['runout_15s_m']:.3f} | "
            f"{r['runout_farthest_15s_m']:.3f} | {r['wall_s_incl_compile']:.1f} |"
        )
    md.append(
        f"\nSpread: {spread['min_m']:.3f}-{spread['max_m']:.3f} m, largest deviation from the mean "
        f"{100 * spread['max_rel_dev_from_mean']:.1f} %."
    )
    return {"rows": rows, "spread": spread, "markdown": "\n".join(md)}


def study_stiff(out: Path, log, t_end: float = 0.5) -> dict:
    """Explicit viscous update (needs dt < rho h^2/(2 d mu_max)) vs Maxwell.

    On BASE (mu_max = 5000 Pa s) over ``t_end`` s: Maxwell at the wave-speed step, the
    explicit update at its viscous limit, and Maxwell at that same small step.  The last
    row separates the Maxwell model's own error (Maxwell vs explicit at equal dt) from the
    time-step dependence of the MPM transfers (each step's grid transfer dissipates, so
    137x more steps give a shorter runout whatever the stress update).
    """
    rows = []
    cases = [("maxwell", {}), ("explicit", {}), ("maxwell at explicit dt", None)]
    for label, extra in cases:
        method = label.split()[0]
        ov = {"numerics.viscous_update": method, "time.t_end_s": t_end, "time.n_frames": 4}
        if extra is None:
            ov["numerics.dt_s"] = rows[1]["dt_s"]
        r = _one(ov)
        r.update(method=label, per_simulated_s=r["wall_s_incl_compile"] / t_end)
        rows.append(r)
        log(
            f"{label:22s} dt {r['dt_s']:.3g} s, {r['n_steps']} steps, runout({t_end:g} s) {r['runout_15s_m']:.3f} m, "
            f"{r['wall_s_incl_compile']:.1f} s"
        )
    md = [
        f"| update | dt (s) | steps | runout at {t_end:g} s (m) | wall (s) | est. wall for 15 s (s) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        md.append(
            f"| {r['method']} | {r['dt_s']:.3g} | {r['n_steps']} | {r['runout_15s_m']:.3f} | "
            f"{r['wall_s_incl_compile']:.1f} | {15 * r['per_simulated_s']:.0f} |"
        )
    return {"rows": rows, "markdown": "\n".join(md)}


STUDIES = {"physical": study_physical, "numerical": study_numerical, "stiff": study_stiff}


def run_study(name: str, out: Path, **options) -> int:
    """Run study ``name``; ``options`` go to it (``physical``: ``measures``, the shear measures)."""
    if name not in STUDIES:
        raise ValueError(f"study {name!r} is invalid: allowed values: {', '.join(STUDIES)}")
    out.mkdir(parents=True, exist_ok=True)
    res = STUDIES[name](out, lambda *a: print(*a, file=sys.stderr, flush=True), **options)
    res["meta"] = {"jax": jax.__version__, "backend": jax.default_backend()}
    (out / f"study_{name}.json").write_text(json.dumps(res, indent=2, default=str))
    (out / f"study_{name}.md").write_text(res["markdown"] + "\n")
    print(res["markdown"])
    return 0
