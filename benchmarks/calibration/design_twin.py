"""Experiment design shown on a twin (docs/calibration.md, "Experiment design: the twin").

Start from dam-break height profiles alone, fit, ask ``calibration.design`` what to measure next,
make that measurement (synthetic, like the profiles), refit with both, and compare every
parameter's Gauss-Newton std before and after with the design's prediction.

All data are SYNTHETIC (made by the simulator at the truth below, plus seeded noise).  Scene:
data/twin-small-dambreak.toml at h = 0.03 m to t = 0.6 s; profiles at 0.3 and 0.6 s, 46 stations,
1 mm noise, made at the fit's own cell size (so the design question is not mixed with the
resolution bias of docs/calibration.md "Numerical uncertainty").

    PYTHONPATH=. python benchmarks/calibration/design_twin.py [OUT_JSON]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import mpmjax  # noqa: E402
from calibration.design import (  # noqa: E402
    AfterRest,
    ProfileRequest,
    design,
    profile_candidates,
    rheometer_candidate,
    table_lines,
)
from calibration.experiments import ProfileExperiment, TransientExperiment  # noqa: E402
from calibration.fit import fit  # noqa: E402
from calibration.params import ParameterSet  # noqa: E402
from calibration.synthetic import synthetic_profiles  # noqa: E402
from calibration.uncertainty import gauss_newton  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
TRUTH = {"mu0": 4.0, "alpha": 1.0, "T": 0.5, "n": 2.5, "lambda0": 1.5}
START = {"mu0": 6.0, "alpha": 1.5, "T": 0.35, "n": 2.5, "lambda0": 1.5}
FIT = ("mu0", "alpha", "T", "lambda0")  # n fixed at the truth: see the docs
SCENE = ["domain.cell_size_m=0.03", "time.t_end_s=0.6"]
SIGMA_M, SIGMA_LN = 0.001, 0.05


def synthetic_transient(cand, truth_mat, seed):
    """The candidate's measurement made at the truth: mu(t) + 5 % seeded noise (after its rest)."""
    s = cand.spec
    e = rheometer_candidate(truth_mat, s["rates_1_s"], t_end_s=s["t_end_s"], n_times=s["n_times"],
                            sigma_ln=s["sigma_ln"])
    inner = e.experiment
    lam = TRUTH["lambda0"] + s["rest_s"] / TRUTH["T"]
    mu = np.asarray(inner.model({"lambda0": lam}))
    mu = mu * np.exp(SIGMA_LN * np.random.default_rng(seed).standard_normal(mu.shape))
    exp = TransientExperiment(truth_mat, np.asarray(inner._t), np.asarray(inner._g), mu, sigma_ln=SIGMA_LN,
                              name=cand.label)
    if s["rest_s"]:
        return AfterRest(exp, s["rest_s"], truth_mat)
    return exp


def main(out=None):
    t0 = time.process_time()
    profs, setup = synthetic_profiles(TWIN, SCENE, (0.3, 0.6), np.linspace(0.0, 0.9, 46),
                                      sigma_m=SIGMA_M, seed=7, bandwidth_m=0.04)
    mat = setup.params.material
    exp = ProfileExperiment(setup, profs, bandwidth_m=0.04, name="profiles 0.3, 0.6 s")
    ps = ParameterSet.from_names(list(FIT), mat, init={k: START[k] for k in FIT})
    r0 = fit([exp], ps, max_iter=12, rtol=1e-5, patience=2, progress=False)
    u0 = gauss_newton([exp], ps, r0.params)
    t_fit0 = time.process_time() - t0
    print(f"profiles alone: {r0.params} loss {r0.loss_final:.4g} ({r0.iterations} it, {r0.reason}), "
          f"std {dict(zip(u0.names, u0.std))}, {t_fit0:.0f} s CPU")
    rheo = mpmjax.rheometer.make_params(law="coussot", **{k: float(getattr(mat, k)) for k in TRUTH})
    est_rheo = mpmjax.rheometer.make_params(law="coussot", **{**TRUTH, **r0.params})
    reqs = [ProfileRequest(t, 0.03, SIGMA_M) for t in (0.15, 0.45, 0.6)]
    t1 = time.process_time()
    cands = profile_candidates(setup, reqs, bandwidth_m=0.04, runout_sigma_m=0.03)
    cands += profile_candidates(setup, [ProfileRequest(0.6, 0.03, SIGMA_M)], bandwidth_m=0.04, rest_s=10.0)
    cands += [rheometer_candidate(est_rheo, [g], t_end_s=20.0, n_times=15, sigma_ln=SIGMA_LN, rest_s=r)
              for g in (0.3, 3.0) for r in (0.0, 10.0)]
    res = design([exp], ps, r0.params, cands)
    t_design = time.process_time() - t1
    lines = table_lines(res)
    print("\n".join(lines))
    best = cands[res.ranking[0]]
    if best.kind != "transient":
        raise SystemExit(f"top candidate {best.label} is not a rheometer transient: extend this script")
    new = synthetic_transient(best, rheo, seed=8)
    ps1 = ParameterSet.from_names(list(FIT), mat, init=r0.params)
    t2 = time.process_time()
    r1 = fit([exp, new], ps1, max_iter=12, rtol=1e-5, patience=2, progress=False)
    u1 = gauss_newton([exp, new], ps1, r1.params)
    t_fit1 = time.process_time() - t2
    k0 = res.ranking[0]
    doc = {
        "synthetic": True,
        "truth": TRUTH, "start": START, "fitted": list(FIT), "scene": TWIN, "overrides": SCENE,
        "profiles_alone": {"params": r0.params, "std": dict(zip(u0.names, map(float, u0.std))),
                           "loss": r0.loss_final, "iterations": r0.iterations, "cpu_s": t_fit0},
        "design_table": lines, "design_cpu_s": t_design,
        "top_candidate": {"label": best.label, "spec": best.spec, "gain_nats": float(res.gains[k0]),
                          "predicted_std": {k: float(s * res.theta[i]) for i, (k, s) in
                                            enumerate(zip(res.names, res.std_after[k0]))}},
        "refit": {"params": r1.params, "std": dict(zip(u1.names, map(float, u1.std))), "loss": r1.loss_final,
                  "iterations": r1.iterations, "cpu_s": t_fit1},
        "total_cpu_s": time.process_time() - t0,
    }
    print(json.dumps(doc, indent=1))
    if out:
        Path(out).write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else None)
