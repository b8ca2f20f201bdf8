"""Speed and convergence of a five-parameter joint fit (issue 15 item 5; docs/calibration.md, "Speed").

A twin on a dam-break scene: height profiles at three times (kernel bandwidth two cells, 1 mm
noise) plus rheometer transients (3 % noise in ln tau): the joint twin's seven pre-sheared tests
(``calibration.synthetic.joint_shear_tests``: overshoots after rests, rate steps) and a start-up
at 1 1/s from the as-prepared structure lambda0 (without it, lambda0 stays where it started: the
profiles alone leave it in a flat valley with alpha and n), data made on the fit's own grid at
``JOINT_TRUTH`` with seeded noise, then all five Coussot parameters fitted from a start 1.5x off
(as the joint twin).  Reports wall and CPU
time, the compilation apart, iterations and model evaluations, for forward- or reverse-mode
gradients.

    python -m mpmjax.studies.fit_speed lab --gradient forward --out lab_fwd.json
    python -m mpmjax.studies.fit_speed lab --gradient reverse --max-iter 2 --out lab_rev.json
    python -m mpmjax.studies.fit_speed twin --set domain.cell_size_m=0.03 --times 0.2,0.4,0.6
    python -m mpmjax.studies.fit_speed lab --levels 0.02,0.01 --set 'numerics.dtype="float32"' --out lab_ml.json

``--levels``: multi-fidelity (``calibration.multilevel``): the data made at the finest cell size,
the fit run at each level in turn from the previous level's result; the criterion is met at the
finest.  ``total_wall_s`` / ``total_cpu_s`` then cover every level and the Gauss-Newton
uncertainty at the end.

``lab`` is the thesis lab dam break (``dambreak-lab``, h = 0.01 m, 3 x 3 particles per cell),
``twin`` the small one (``data/twin-small-dambreak.toml``); ``--set`` overrides scene keys
(float64 unless overridden).  All data are SYNTHETIC.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import mpmjax
from calibration.data import Profile, ShearTest
from calibration.experiments import ProfileExperiment, ShearHistoryExperiment, frames_for
from calibration.fit import fit
from calibration.multilevel import check_levels, fit_multilevel
from calibration.params import ParameterSet
from calibration.synthetic import JOINT_SCENE, JOINT_TRUTH, joint_shear_tests

SCENES = {
    # name: (scene, stations [m], default data times [s])
    "lab": ("dambreak-lab", np.linspace(0.0, 1.5, 61), (0.5, 1.0, 2.0)),
    "twin": (JOINT_SCENE, np.linspace(0.0, 0.9, 31), (0.2, 0.4, 0.6)),
}
KEYS = {"mu0": "material.mu0_pa_s", "alpha": "material.alpha", "T": "material.T_s", "n": "material.n",
        "lambda0": "material.lambda0"}
START = {"mu0": 4.5, "alpha": 1.0, "T": 1.2, "n": 3.0, "lambda0": 0.9}  # the joint twin's start, 1.5x off
SIGMA_M, SIGMA_LN = 0.001, 0.03


def _setup(which, overrides, times_s, cell_size_m=None):
    """The scene built for the data times (float64 unless overridden), at ``cell_size_m`` if given."""
    scene, _, t_default = SCENES[which]
    times_s = tuple(times_s or t_default)
    ov = ['numerics.dtype="float64"'] + list(overrides) + [f"{KEYS[k]}={v!r}" for k, v in JOINT_TRUTH.items()]
    if cell_size_m is not None:
        ov.append(f"domain.cell_size_m={float(cell_size_m)!r}")
    cfg0 = mpmjax.load_scene(scene, ov)
    t_end, nf = frames_for(list(times_s), cfg0["time.t_end_s"], cfg0["time.n_frames"])
    return mpmjax.build(mpmjax.load_scene(scene, ov + [f"time.t_end_s={t_end!r}", f"time.n_frames={nf}"])), times_s


def twin_experiments(which, overrides=(), times_s=None, seed=7):
    """(experiments [profiles, transients], setup): the twin's data at ``JOINT_TRUTH`` on the fit's grid."""
    _, x, _ = SCENES[which]
    setup, times_s = _setup(which, overrides, times_s)
    bw = 2 * setup.scene.h
    rng = np.random.default_rng(seed)
    pe = ProfileExperiment(setup, [Profile(x, np.ones_like(x), t) for t in times_s], bandwidth_m=bw)
    hs = [np.maximum(np.asarray(h) + SIGMA_M * rng.standard_normal(x.size), 0.0) for h in pe.model_profiles({})]
    # the joint twin's tests pre-shear, which erases lambda0; a start-up at 1 1/s from the sample
    # as prepared (the dam break's initial structure) measures it
    ta = np.geomspace(0.05, 20.0, 12)
    tests0 = joint_shear_tests() + [ShearTest("8", ta, np.ones(12), np.ones(12))]
    taus = ShearHistoryExperiment(setup.params.material, tests0).model({})
    tests = []
    for t, tau in zip(tests0, taus, strict=True):
        full = np.full(t.t_s.shape, np.nan)
        ln = np.log(np.asarray(tau, float))
        full[np.isfinite(t.tau_pa)] = np.exp(ln + SIGMA_LN * rng.standard_normal(ln.shape))
        tests.append(ShearTest(t.label, t.t_s, t.gamma_dot_1_s, full, None, "synthetic"))
    profiles = [Profile(x, h, t, np.full_like(x, SIGMA_M), "synthetic") for t, h in zip(times_s, hs, strict=True)]
    exps = [
        ProfileExperiment(setup, profiles, bandwidth_m=bw, name="profiles"),
        ShearHistoryExperiment(setup.params.material, tests, sigma_ln=SIGMA_LN, name="transients"),
    ]
    return exps, setup


def experiments_at(which, overrides, times_s, exps):
    """``h -> experiments``: the data of ``exps`` (made on the finest grid) compared with the model
    at cell size h, the kernel bandwidth kept in metres (``calibration.multilevel``)."""
    prof, shear = exps

    def make(h):
        setup, _ = _setup(which, overrides, times_s, h)
        return [ProfileExperiment(setup, prof.profiles, bandwidth_m=prof.bandwidth_m, name="profiles"), shear]

    return make


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mpmjax.studies.fit_speed", description=__doc__.split("\n")[0])
    ap.add_argument("scene", choices=sorted(SCENES))
    ap.add_argument("--gradient", default="forward", choices=("forward", "reverse"))
    ap.add_argument("--method", default="lbfgs", choices=("lbfgs", "lm", "adam"), help="calibration.fit's method")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--times", help="data times [s], comma-separated (default lab 0.5,1,2; twin 0.2,0.4,0.6)")
    ap.add_argument("--max-iter", type=int, default=40)
    ap.add_argument("--rtol", type=float, default=1e-4)
    ap.add_argument("--patience", type=int, default=3)
    ap.add_argument(
        "--levels",
        help="multi-fidelity: cell sizes [m], coarse to fine, e.g. 0.02,0.01; the data are made at the finest, "
        "the criterion is checked at every level (calibration.multilevel.fit_multilevel)",
    )
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    times = [float(t) for t in a.times.split(",")] if a.times else None
    levels = check_levels(a.levels.split(","), "--levels") if a.levels else None
    ov = list(a.set) + ([f"domain.cell_size_m={levels[-1]!r}"] if levels else [])
    c0, w0 = time.process_time(), time.perf_counter()
    exps, setup = twin_experiments(a.scene, ov, times)
    data_cpu, data_wall = time.process_time() - c0, time.perf_counter() - w0
    pset = ParameterSet.from_names(list(JOINT_TRUTH), setup.params.material, init=START)
    kw = dict(method=a.method, gradient=a.gradient, max_iter=a.max_iter, rtol=a.rtol, patience=a.patience)
    per_level = None
    if levels:
        c1, w1 = time.process_time(), time.perf_counter()
        ml = fit_multilevel(experiments_at(a.scene, a.set, times, exps), pset, levels, **kw)
        r = ml.result
        per_level = [
            {"cell_size_m": lv.cell_size_m, "n_particles": lv.n_particles, "n_steps": lv.n_steps,
             "iterations": lv.result.iterations, "converged": bool(lv.result.converged),
             "stop_reason": lv.result.reason,
             "evaluations": lv.result.evaluations, "wall_s": lv.result.wall_s, "cpu_s": lv.result.cpu_s,
             "compile_cpu_s": lv.result.compile_cpu_s, "params": lv.result.params,
             "loss_history": [float(v) for v in lv.result.history[:, 0]]}
            for lv in ml.levels
        ]
        # the whole multi-fidelity fit: every level, its compilation, and the Gauss-Newton
        # uncertainty at the finest level (which the single-level fit does not compute)
        total_cpu, total_wall = time.process_time() - c1, time.perf_counter() - w1
    else:
        r = fit(exps, pset, **kw)
        total_cpu, total_wall = r.cpu_s, r.wall_s
    sc = setup.scene
    doc = {
        "scene": a.scene, "overrides": a.set, "cell_size_m": sc.h, "n_particles": sc.n_particles,
        "n_steps": sc.n_steps, "t_end_s": sc.t_end, "dtype": str(sc.dtype), "times_s": list(exps[0].profiles and
        [p.t_s for p in exps[0].profiles]), "gradient": r.gradient, "method": a.method, "truth": JOINT_TRUTH,
        "start": START,
        "params": r.params, "error_rel": {k: r.params[k] / v - 1 for k, v in JOINT_TRUTH.items()},
        "loss_initial": r.loss_initial, "loss_final": r.loss_final, "iterations": r.iterations,
        "converged": bool(r.converged), "stop_reason": r.reason, "criterion": f"rtol {a.rtol} over {a.patience}",
        "evaluations": r.evaluations, "wall_s": r.wall_s, "cpu_s": r.cpu_s, "compile_s": r.compile_s,
        "compile_cpu_s": r.compile_cpu_s, "data_cpu_s": data_cpu, "data_wall_s": data_wall,
        "loss_history": [float(v) for v in r.history[:, 0]], "load_average": list(__import__("os").getloadavg()),
        "levels": per_level, "total_cpu_s": total_cpu, "total_wall_s": total_wall,
    }
    Path(a.out).write_text(json.dumps(doc, indent=1))
    print(json.dumps({k: doc[k] for k in ("iterations", "converged", "evaluations", "wall_s", "cpu_s", "compile_cpu_s",
                                          "total_wall_s", "total_cpu_s", "error_rel")}), file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
