"""What buys resolution across the flow depth most cheaply? (issue 14 item 6; docs/validation.md,
section "Depth resolution"; raw figures in benchmarks/accuracy/depth_resolution.jsonl).

    PYTHONPATH=. python benchmarks/accuracy/depth_resolution.py split            # grid / particle cost split
    PYTHONPATH=. python benchmarks/accuracy/depth_resolution.py run lab 0.007 3 '{"domain.hi_m": [1.5, 0.24]}'
    PYTHONPATH=. python benchmarks/accuracy/depth_resolution.py run slump 0.0125 3 '{"boundary.slip_length_m": 0.005}'
    PYTHONPATH=. python benchmarks/accuracy/depth_resolution.py table            # the markdown table

``split``: the compiled step's CPU time (``time.process_time``, compile excluded, best of 3 loops
of a short run) of the lab dam break at ppc 3 for several domain lengths at a fixed particle set,
alternating the domains in each round, so that the cost per node and per particle separate:
t_step = a N_particles + b N_nodes (least squares over the domains).

``run``: one run of ``mpmjax converge``'s case (``studies.converge.run_one``: lab to 15 s, slump to
6 s) at cell size h [m] and ppc with scene overrides; appends one JSON line: loop CPU, runout, the
deposit's thickness in cells (``RunoutGauge.max_thickness`` / h, as summary.json), the lab error
against the extrapolated reference 1.297 m and the profile's RMS difference from the finest lab run
(GIMP ppc 3 at h = 0.005 m, benchmarks/accuracy/converge.json), the slump's errors against its exact
profile (``studies.converge.slump_errors``).
"""

import json
import math
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

from mpmjax import build
from mpmjax._metrics import RunoutGauge
from mpmjax._simulate import simulate
from mpmjax.studies import converge as cv

HERE = Path(__file__).parent
JSONL = HERE / "depth_resolution.jsonl"
LAB_REFERENCE_M = 1.297  # docs/validation.md "Defaults": extrapolate of the GIMP ppc 3 series


def _finest_lab_profile():
    doc = json.loads((HERE / "converge.json").read_text())
    for r in doc["cases"]["lab"]["rows"]:
        if r["series"] == "ppc=3" and r["overrides"]["domain.cell_size_m"] == 0.005:
            return np.asarray(r["profile_m"])
    raise LookupError("no ppc 3 h = 0.005 m lab run in converge.json")


def run(case: str, h: float, ppc: int, extra: dict, label: str) -> dict:
    """One full run; the record appended to JSONL."""
    ov = {**cv.CASES[case][1], "domain.cell_size_m": h, "numerics.ppc": ppc, **extra}
    npz = Path(tempfile.mkdtemp()) / "final.npz"
    rec = cv.run_one(case, ov, npz)
    rec = {"label": label, "case": case, "h_m": h, "ppc": ppc, "overrides": extra, **rec}
    if rec["status"] == "ok":
        s = build(cv._config(case, ov))
        rec["grid_nodes"] = int(np.prod(s.scene.grid_shape))
        prof = np.asarray(rec["profile_m"])
        # thickest point of the final deposit in cells (bandwidth h, as summary.json)
        fin = np.load(npz)
        gauge = RunoutGauge.of(s.scene, s.info)
        rec["deposit_cells_across"] = gauge.max_thickness(fin["x"], fin["vol0"], fin["active"]) / h
        _errors(case, rec, prof, h)
    rec.pop("profile_m", None)
    with JSONL.open("a") as f:
        f.write(json.dumps(rec) + "\n")
    print(json.dumps(rec), flush=True)
    return rec


def existing(npz_dir: Path, series=("ppc=3", "default", "ppc=1")) -> None:
    """Records of the convergence sweep's runs (benchmarks/accuracy/converge.json: GIMP at ppc 3, 2, 1, as
    measured there) with the same figures as ``run``; the thickness in cells from the final
    positions that sweep kept (``npz_dir`` = its OUT/bench/converge)."""
    doc = json.loads((HERE / "converge.json").read_text())
    labels = {"ppc=3": "uniform", "default": "ppc 2", "ppc=1": "ppc 1"}
    have = [json.loads(x) for x in JSONL.read_text().splitlines() if x.strip()] if JSONL.exists() else []
    done = {(r.get("case"), r.get("label"), r.get("h_m")) for r in have if r.get("source")}
    for case in ("lab", "slump"):
        for r in doc["cases"][case]["rows"]:
            if r["series"] not in series or r["status"] != "ok":
                continue
            h = r["overrides"]["domain.cell_size_m"]
            if (case, labels[r["series"]], h) in done:  # a rerun only adds what is missing
                continue
            ppc = {"ppc=3": 3, "default": 2, "ppc=1": 1}[r["series"]]
            slug = f"{r['series']}_h{h:g}".replace("=", "").replace(".", "p")
            fin = np.load(npz_dir / case / f"{slug}.npz")
            ov = {**cv.CASES[case][1], "domain.cell_size_m": h, "numerics.ppc": ppc}
            s = build(cv._config(case, ov))
            gauge = RunoutGauge.of(s.scene, s.info)
            rec = {k: r[k] for k in ("status", "n_particles", "n_steps", "cpu_s", "runout_m", "runout_farthest_m") if k in r}
            rec.update(label=labels[r["series"]], case=case, h_m=h, ppc=ppc, overrides={}, source="benchmarks/accuracy/converge.json")
            rec["grid_nodes"] = int(np.prod(s.scene.grid_shape))
            rec["deposit_cells_across"] = gauge.max_thickness(fin["x"], fin["vol0"], fin["active"]) / h
            _errors(case, rec, np.asarray(r["profile_m"]), h)
            with JSONL.open("a") as f:
                f.write(json.dumps(rec) + "\n")
            print(json.dumps(rec), flush=True)


def _errors(case: str, rec: dict, prof, h: float) -> None:
    """The case's errors (added to ``rec``): slump against its exact profile, lab against the
    reference runout and the finest run's profile."""
    if case == "slump":
        # the exact profile's stations span the full 1 m domain: a cropped run's profile is 0 beyond its box
        n_exact = int(round(1.0 / cv.PROFILE_STATION)) + 1
        rec["profile_m"] = np.pad(prof, (0, max(0, n_exact - len(prof)))).tolist()
        cv.slump_errors(rec, h)
        rec.pop("profile_m")
        return
    xs = np.arange(len(prof)) * cv.PROFILE_STATION
    rec["error_pct"] = 100.0 * (rec["runout_m"] - LAB_REFERENCE_M) / LAB_REFERENCE_M
    ref = _finest_lab_profile()
    n = min(len(ref), len(prof))
    on = xs[:n] <= LAB_REFERENCE_M  # the deposit's extent
    rec["profile_rms_vs_finest_m"] = float(np.sqrt(np.mean((prof[:n][on] - ref[:n][on]) ** 2)))
    rec["profile_rms_vs_finest_pct"] = 100.0 * rec["profile_rms_vs_finest_m"] / float(ref.max())


def split(hs=(0.01, 0.005), lengths=(2.0, 1.5, 8.0, 16.0), t_end=0.2, rounds=3) -> list:
    """Step CPU of the lab at ppc 3 for domain lengths ``lengths`` [m] (same particles)."""
    out = []
    for h in hs:
        comp = {}
        for L in lengths:
            ov = {"domain.cell_size_m": h, "numerics.ppc": 3, "time.t_end_s": t_end, "time.n_frames": 1, "domain.hi_m": [L, 0.24]}
            s = build(cv._config("lab", ov))
            f = jax.jit(lambda st, p, sc=s.scene: simulate(sc, st, p)[0]).lower(s.state, s.params).compile()
            comp[L] = (f, s)
        best = {L: math.inf for L in lengths}
        for _ in range(rounds):
            for L in lengths:
                f, s = comp[L]
                c0 = time.process_time()
                jax.block_until_ready(f(s.state, s.params).x)
                best[L] = min(best[L], time.process_time() - c0)
        rows = []
        for L in lengths:
            f, s = comp[L]
            sc = s.scene
            rows.append(
                {
                    "h_m": h,
                    "length_m": L,
                    "n_particles": sc.n_particles,
                    "grid_nodes": int(np.prod(sc.grid_shape)),
                    "n_steps": sc.n_steps,
                    "step_cpu_us": 1e6 * best[L] / sc.n_steps,
                }
            )
        # t = a Np + b Nn: Np fixed, so the slope over the nodes is b and the intercept a Np
        nn = np.array([r["grid_nodes"] for r in rows], float)
        t = np.array([r["step_cpu_us"] for r in rows])
        b, c = np.polyfit(nn, t, 1)
        for r in rows:
            r.update(us_per_node=b, particle_part_us=c, grid_share=b * r["grid_nodes"] / r["step_cpu_us"])
        out.extend(rows)
        for r in rows:
            line = {"kind": "split", **r}
            with JSONL.open("a") as fh:
                fh.write(json.dumps(line) + "\n")
            print(json.dumps(line), flush=True)
    return out


def table() -> str:
    rows = [json.loads(s) for s in JSONL.read_text().splitlines() if s.strip()]
    out = []
    # the split: per h, the longest loops measured (a first probe of 0.1 s per loop was noisier)
    spl = [r for r in rows if r.get("kind") == "split"]
    longest = {r["h_m"]: max(q["n_steps"] for q in spl if q["h_m"] == r["h_m"]) for r in spl}
    sp = {(r["h_m"], r["length_m"]): r for r in spl if r["n_steps"] == longest[r["h_m"]]}
    if sp:
        out.append("| h (m) | domain length (m) | particles | grid nodes | step CPU (µs) | fit: per node (µs) | fit: per particle (µs) | grid share |")
        out.append("|---|---|---|---|---|---|---|---|")
        for (h, L), r in sorted(sp.items(), key=lambda kv: (-kv[0][0], kv[0][1])):
            out.append(
                f"| {h:g} | {L:g} | {r['n_particles']} | {r['grid_nodes']} | {r['step_cpu_us']:.0f} | {r['us_per_node']:.4f} "
                f"| {r['particle_part_us'] / r['n_particles']:.3f} | {100 * r['grid_share']:.1f} % |"
            )
        out.append("")
    for case in ("lab", "slump"):
        order = ["uniform", "cropped", "ppc 4", "navier b=0.5h", "navier b=0.25h", "navier b=1.0h", "ppc 2", "ppc 1"]
        rank = {lab: i for i, lab in enumerate(order)}
        last = {}  # a repeated run: the last one
        for r in rows:
            if r.get("case") == case and r.get("status") == "ok":
                lab = "uniform" if r["label"] == "navier b=0h" else r["label"]  # slip length 0 is the default
                last[(lab, r["h_m"], r["ppc"])] = dict(r, label=lab)
        sel = sorted(last.values(), key=lambda r: (rank.get(r["label"].split(" 0.")[0].split(" 1.")[0], 99), -r["h_m"]))
        sel = [dict(r, label=r["label"] + (" (sweep)" if r.get("source") else "")) for r in sel]
        if not sel:
            continue
        if case == "lab":
            out.append("| candidate | h (m) | ppc | nodes | particles | loop CPU (s) | cells across | runout (m) | vs 1.297 m (%) | profile RMS vs finest (%) |")
            out.append("|---|---|---|---|---|---|---|---|---|---|")
            for r in sel:
                out.append(
                    f"| {r['label']} | {r['h_m']:g} | {r['ppc']} | {r.get('grid_nodes', '-')} | {r.get('n_particles', '-')} "
                    f"| {r.get('cpu_s', float('nan')):.1f} | {r.get('deposit_cells_across', float('nan')):.2f} "
                    f"| {r.get('runout_m', float('nan')):.4f} | {r.get('error_pct', float('nan')):+.2f} "
                    f"| {r.get('profile_rms_vs_finest_pct', float('nan')):.2f} |"
                )
        else:
            out.append("| candidate | h (m) | ppc | particles | loop CPU (s) | cells across | front (m) | vs exact x_f (%) | profile RMS (%) |")
            out.append("|---|---|---|---|---|---|---|---|---|")
            for r in sel:
                out.append(
                    f"| {r['label']} | {r['h_m']:g} | {r['ppc']} | {r.get('n_particles', '-')} | {r.get('cpu_s', float('nan')):.1f} "
                    f"| {r.get('deposit_cells_across', float('nan')):.2f} | {r.get('runout_m', float('nan')):.4f} "
                    f"| {r.get('front_err_pct', float('nan')):+.2f} | {r.get('profile_err_pct', float('nan')):.2f} |"
                )
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "split":
        split()
    elif cmd == "run":
        case, h, ppc = sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
        extra = json.loads(sys.argv[5]) if len(sys.argv) > 5 else {}
        label = sys.argv[6] if len(sys.argv) > 6 else "uniform"
        run(case, h, ppc, extra, label)
    elif cmd == "existing":
        existing(Path(sys.argv[2]))
    elif cmd == "table":
        print(table())
    else:
        raise SystemExit(f"unknown command {cmd!r}; allowed: split, run, table")
