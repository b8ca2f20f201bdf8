"""Probes of the particles-per-cell dependence of the runout (issue 14; benchmarks/accuracy/ppc_probe.md).

    PYTHONPATH=. python benchmarks/accuracy/ppc_probe.py slump 0.0125 1,3 '{"numerics.grid_density_cap": 0.05}'
    PYTHONPATH=. python benchmarks/accuracy/ppc_probe.py lab 0.02 1,2,3 '{}'

One JSON line per run.  slump: the scene of ``mpmjax converge --case slump`` with the overrides,
its front per frame, the error against the exact x_f, and the overpacking of the deposit at the end: Sigma J V0
over the area under the free surface (top particle + half a spacing in bins of 2h; about 0.93 for a
deposit packed as its J says, because the top of a sloping bin over-reads its mean height) and the
volume per area in interior bins of 2h per frame (``studies.converge.deposit_packing``: 1 for a
packing that matches J).  lab: ``dambreak-lab`` to 15 s, the same figures but the exact front.
CPU times are the compiled loop's.
"""

import json
import sys
import time

import jax
import numpy as np

from mpmjax import build
from mpmjax._metrics import RunoutGauge, surface_profile
from mpmjax._simulate import simulate
from mpmjax.studies import converge as cv


def area_ratio(x, J, vol0, h, ppc):
    """Sigma J V0 / area under the free surface (top particle + spacing/2, bins of 2h)."""
    w = 2.0 * h
    edges = np.arange(0.0, x[:, 0].max() + w, w)
    _, top = surface_profile(x, np.ones(len(x), bool), edges, h / ppc)
    return float((J * vol0).sum() / (np.nansum(top) * w))


def probe(case, h, ppc, extra, n_frames=12):
    """One run of ``case`` (``slump`` or ``lab``) at cell size h [m] and ppc, with the overrides."""
    t_end = {"slump": 6.0, "lab": 15.0}[case]
    ov = {"time.t_end_s": t_end, "domain.cell_size_m": h, "numerics.ppc": ppc, "time.n_frames": n_frames, **extra}
    s = build(cv._config(case, ov))
    sc = s.scene
    compiled = jax.jit(lambda st, p: simulate(sc, st, p)).lower(s.state, s.params).compile()
    c0 = time.process_time()
    final, fr = compiled(s.state, s.params)
    jax.block_until_ready(final.x)
    cpu = time.process_time() - c0
    gauge = RunoutGauge.of(sc, s.info)
    vol0, act = np.asarray(final.vol0), np.asarray(final.active, bool)
    fronts = [gauge.front(np.asarray(fr.x[i]), vol0, act) for i in range(n_frames)]
    x, J = np.asarray(final.x), np.asarray(final.J)
    tau = np.asarray(final.tau)
    rec = {
        "case": case, "h": h, "ppc": ppc, "overrides": extra, "cpu_s": round(cpu, 2), "steps": sc.n_steps,
        "n_lost": int(final.n_lost), "front_m": round(fronts[-1], 4),
        "fronts_m": [round(f, 3) for f in fronts],
        "area_ratio": round(area_ratio(x, J, vol0, h, ppc), 3),
        "deposit_packing": [
            round(cv.deposit_packing(np.asarray(fr.x[i]), np.asarray(fr.J[i]), vol0, h), 3) for i in range(n_frames)
        ],
        "max_speed_m_s": float(np.max(np.abs(np.asarray(final.v)))),
    }  # fmt: skip
    if case == "slump":
        x_f, _ = cv._slump_exact(float(vol0.sum()))
        tau_ratio = np.sqrt(0.5 * np.sum(tau * tau, axis=(1, 2))) / cv.SLUMP_TAU_Y
        rec.update(
            front_err_pct=round(100 * (fronts[-1] - x_f) / x_f, 2),
            tau_over_tau_y_mean=round(float(tau_ratio.mean()), 2),
        )
    return rec


if __name__ == "__main__":
    case, h = sys.argv[1], float(sys.argv[2])
    extra = json.loads(sys.argv[4]) if len(sys.argv) > 4 else {}
    for p in (int(a) for a in sys.argv[3].split(",")):
        print(json.dumps(probe(case, h, p, extra)), flush=True)
