"""Command-line front ends: ``mpmjax calibrate`` and ``mpmjax sweep`` (registered by ``mpmjax.cli``).

Exit status: 0 success, 2 invalid input (the message names the option or key, the value and
the allowed range), 130 interrupted (what was already written stays), 1 other errors.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

import mpmjax

from .data import DataError, load_profiles
from .experiments import FlowCurveExperiment, ProfileExperiment, frames_for
from .fit import fit
from .params import UNITS, ParameterSet
from .sweep import FIELD_KEYS, parse_vary, sweep, write_sweep
from .uncertainty import gauss_newton

USAGE_ERROR = 2
TRANSFORM_CHOICES = ("log", "softplus", "linear", "identity")


def _kv(items, what, conv=float):
    out = {}
    for it in items or []:
        if "=" not in it:
            raise ValueError(f"{what} {it!r}: expected NAME=VALUE")
        k, v = it.split("=", 1)
        k = k.strip()
        try:
            out[k] = conv(v.strip())
        except ValueError as e:
            raise ValueError(f"{what} {it!r}: {e}") from None
    return out


def _bounds(text):
    if ":" not in text:
        raise ValueError("expected LO:HI, e.g. 0.1:100")
    lo, hi = text.split(":", 1)
    return float(lo), float(hi)


def _transform(text):
    if text not in TRANSFORM_CHOICES:
        raise ValueError(f"allowed: {', '.join(TRANSFORM_CHOICES)}")
    return text


def add_calibrate_arguments(p: argparse.ArgumentParser):
    p.add_argument("data", help="measured profiles: CSV (x_m, h_m [, t_s, sigma_m]) or HDF5; see docs/calibration.md")
    p.add_argument("--scene", default="dambreak-lab", help="built-in scene name or TOML path (default dambreak-lab)")
    p.add_argument("--fit", required=True, help="comma-separated parameters to fit, e.g. mu0,alpha,T,n,lambda0")
    p.add_argument(
        "--init",
        action="append",
        metavar="NAME=VALUE",
        help="initial value [SI] (a parameter not in --fit is fixed at it)",
    )
    p.add_argument(
        "--bounds", action="append", metavar="NAME=LO:HI", help="bounds [SI] (default: wide physical ranges)"
    )
    p.add_argument(
        "--transform", action="append", metavar="NAME=KIND", help="log (default), softplus, linear, identity"
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="scene override, e.g. domain.cell_size_m=0.02")
    p.add_argument("--method", default="lbfgs", choices=("lbfgs", "adam"), help="optax optimiser (default lbfgs)")
    p.add_argument("--max-iter", type=int, default=50, help="maximum iterations (default 50)")
    p.add_argument("--learning-rate", type=float, default=0.05, help="Adam step in ln(parameter) (default 0.05)")
    p.add_argument(
        "--rtol", type=float, default=1e-4, help="stop when the loss falls by less than this over --patience iterations"
    )
    p.add_argument("--patience", type=int, default=5, help="iterations for the rtol test (default 5)")
    p.add_argument(
        "--starts", type=int, default=1, help="multi-start: number of starts run as one vmap batch (default 1)"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed of the extra starts")
    p.add_argument(
        "--gradient",
        default="auto",
        choices=("auto", "forward", "reverse"),
        help="gradient mode: forward (one tangent per parameter), reverse, or auto (forward for <= 8 parameters)",
    )
    p.add_argument(
        "--sigma-m", type=float, help="profile standard deviation [m] where the data give none (default 5%% of max h)"
    )
    p.add_argument("--bandwidth-m", type=float, help="kernel bandwidth of the model profile [m] (default: cell size)")
    p.add_argument("--runout-m", type=float, help="also fit a measured final runout [m]")
    p.add_argument("--runout-sigma-m", type=float, help="its standard deviation [m] (default 2 cells)")
    p.add_argument("--flow-curve", help="also fit rheometer flow-curve points: CSV with gamma_dot_1_s, tau_pa")
    p.add_argument("--out", default="calibration-out", help="output folder (default calibration-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def _load_flow_curve(path):
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    rows = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    head = [c.strip() for c in rows[0].split(",")]
    if sorted(head) != ["gamma_dot_1_s", "tau_pa"]:
        raise DataError(f"{path}: columns {head}; expected gamma_dot_1_s, tau_pa")
    try:
        a = np.asarray([[float(v) for v in r.split(",")] for r in rows[1:]])
    except ValueError as e:
        raise DataError(f"{path}: {e}") from None
    return a[:, head.index("gamma_dot_1_s")], a[:, head.index("tau_pa")]


def calibrate(args) -> dict:
    """Run a calibration from parsed arguments; returns the fit.json document."""
    out = Path(args.out)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    profiles = load_profiles(args.data)
    names = [s.strip() for s in args.fit.split(",") if s.strip()]
    if not names:
        raise ValueError("--fit: name at least one parameter, e.g. --fit mu0,n")
    overrides = list(args.set or [])
    keys = {o.split("=", 1)[0].strip() for o in overrides}
    cfg0 = mpmjax.load_scene(args.scene, overrides)
    if not ({"time.t_end_s", "time.n_frames"} & keys):
        t_end, nf = frames_for([p.t_s for p in profiles], cfg0["time.t_end_s"], cfg0["time.n_frames"])
        overrides += [f"time.t_end_s={t_end!r}", f"time.n_frames={nf}"]
    init = _kv(args.init, "--init")
    for k, v in init.items():
        if k in FIELD_KEYS:
            overrides.append(f"{FIELD_KEYS[k]}={v!r}")  # validated as a scene value (range errors name the key)
    cfg = mpmjax.load_scene(args.scene, overrides)
    setup = mpmjax.build(cfg)
    pset = ParameterSet.from_names(
        names,
        setup.params.material,
        init=init,
        bounds=_kv(args.bounds, "--bounds", _bounds),
        transforms=_kv(args.transform, "--transform", _transform),
    )
    exps = [
        ProfileExperiment(
            setup,
            profiles,
            bandwidth_m=args.bandwidth_m,
            sigma_m=args.sigma_m,
            runout_m=args.runout_m,
            runout_sigma_m=args.runout_sigma_m,
            name=Path(args.data).name,
        )
    ]
    if args.flow_curve:
        g, tau = _load_flow_curve(args.flow_curve)
        exps.append(FlowCurveExperiment(setup.params.material, g, tau, name=Path(args.flow_curve).name))
    out.mkdir(parents=True, exist_ok=True)
    sc = setup.scene
    log(
        f"calibrate: scene {cfg['name']} ({sc.n_particles} particles, {sc.n_steps} steps of {sc.dt:.3g} s to "
        f"t = {sc.t_end:g} s), {len(profiles)} profile(s) from {args.data}, fitting {', '.join(pset.free)} "
        f"with {args.method}, {args.starts} start(s)"
    )

    def progress(it, max_iter, losses, best, running):
        if not args.quiet:
            vals = ", ".join(f"{k}={v:.4g}" for k, v in best.items())
            print(f"calibrate: iteration {it}/{max_iter} loss {float(np.min(losses)):.4e} {vals}", file=sys.stderr)
        mpmjax.atomic_write_text(
            out / "fit_progress.json",
            json.dumps({"iteration": it, "loss": float(np.min(losses)), "params": best, "complete": False}, indent=1),
        )

    t0 = time.perf_counter()
    res = fit(
        exps,
        pset,
        method=args.method,
        max_iter=args.max_iter,
        learning_rate=args.learning_rate,
        rtol=args.rtol,
        patience=args.patience,
        n_starts=args.starts,
        seed=args.seed,
        progress=progress,
        gradient=args.gradient,
    )
    unc = gauss_newton(exps, pset, res.params)
    wall = time.perf_counter() - t0
    for w in unc.warnings:
        log(f"calibrate: warning: {w}")
    doc = {
        "params": res.params,
        "std": {k: (float(s) if math.isfinite(s) else None) for k, s in zip(unc.names, unc.std, strict=True)},
        "loss_initial": res.loss_initial,
        "loss_final": res.loss_final,
        "iterations": res.iterations,
        "wall_s": wall,
        "converged": bool(res.converged),
        "stop_reason": res.reason,
        "units": {k: UNITS.get(k, "SI") for k in pset.specs},
        "initial": {k: pset.specs[k].init for k in pset.free},
        "fixed": {k: s.init for k, s in pset.specs.items() if s.fixed},
        "specs": pset.bounds_table(),
        "uncertainty": unc.as_dict(),
        "loss_definition": "sum over experiments of weight * mean(((model - data) / sigma)^2), dimensionless",
        "loss_history": [float(v) for v in res.history.min(axis=1)],
        "method": args.method,
        "gradient": res.gradient,
        "starts": res.starts,
        "finals": res.finals,
        "final_losses": [float(v) for v in res.final_losses],
        "best_start": res.best_start,
        "compile_s": res.compile_s,
        "scene": cfg["name"],
        "scene_overrides": overrides + [f"{FIELD_KEYS[k]}={v!r}" for k, v in res.params.items() if k in FIELD_KEYS],
        "data": str(args.data),
        "profile_times_s": [p.t_s for p in profiles],
        "frame_time_offsets_s": list(exps[0].time_offsets_s),
        "sigma_known": exps[0].sigma_known,
        "code_version": mpmjax.__version__,
    }
    mpmjax.atomic_write_text(out / "fit.json", json.dumps(doc, indent=1))
    (out / "fit_progress.json").unlink(missing_ok=True)
    _plots(out, exps[0], pset, res, profiles)
    log(
        f"calibrate: loss {res.loss_initial:.4g} -> {res.loss_final:.4g} in {res.iterations} iterations "
        f"({'converged: ' + res.reason if res.converged else 'not converged'}), {wall:.1f} s"
    )
    for k in unc.names:
        s = doc["std"][k]
        log(f"  {k} = {res.params[k]:.5g} +- {s if s is not None else float('inf'):.3g} [{UNITS.get(k, 'SI')}]")
    log(f"wrote {out / 'fit.json'}, {out / 'fit_profiles.png'}, {out / 'loss_history.png'}")
    return doc


def _plots(out, exp, pset, res, profiles):
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    init = {k: pset.specs[k].init for k in pset.free}
    h_init = [np.asarray(h) for h in exp.model_profiles(pset.values(init))]
    h_fit = [np.asarray(h) for h in exp.model_profiles(pset.values(res.params))]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, p in enumerate(profiles):
        c = colors[i % len(colors)]
        lab = "final" if p.t_s is None else f"t = {p.t_s:g} s"
        if p.sigma_m is not None:
            ax.errorbar(p.x_m, p.h_m, yerr=p.sigma_m, fmt="o", ms=3, color=c, label=f"data {lab}")
        else:
            ax.plot(p.x_m, p.h_m, "o", ms=3, color=c, label=f"data {lab}")
        ax.plot(p.x_m, h_fit[i], "-", color=c, label=f"fitted {lab}")
        ax.plot(p.x_m, h_init[i], ":", color=c, lw=1, label=f"initial guess {lab}" if i == 0 else None)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("height h [m]")
    ax.set_title(", ".join(f"{k} = {v:.4g}" for k, v in res.params.items()), fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "fit_profiles.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    ax.semilogy(np.arange(res.history.shape[0]), res.history, lw=1)
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss (dimensionless)")
    ax.set_title(f"loss {res.loss_initial:.3g} -> {res.loss_final:.3g}")
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(out / "loss_history.png", dpi=110)
    plt.close(fig)


def add_sweep_arguments(p: argparse.ArgumentParser):
    p.add_argument("scene", nargs="?", default="dambreak-lab", help="built-in scene name or TOML path")
    p.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="NAME=V1,V2,...",
        help="material parameter and its values [SI], e.g. n=1.5,2,2.5,3; repeat for a grid",
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="scene override, e.g. time.t_end_s=5")
    p.add_argument("--chunk", type=int, help="cases per vmap batch (default: as many as fit in a quarter of memory)")
    p.add_argument("--out", default="sweep-out", help="output folder (default sweep-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def run_sweep(args) -> dict:
    vary = parse_vary(args.vary)
    res = sweep(args.scene, vary, overrides=args.set, chunk=args.chunk, progress=not args.quiet)
    paths = write_sweep(res, args.out)
    if not args.quiet:
        names = list(vary)
        print(
            " ".join(f"{k:>10s}" for k in names) + f" {'runout [m]':>11s} {'rest [s]':>9s} {'lost':>5s}",
            file=sys.stderr,
        )
        for i, c in enumerate(res["cases"]):
            print(
                " ".join(f"{c[k]:10.4g}" for k in names)
                + f" {res['final_runout_m'][i]:11.4f} {res['time_to_rest_s'][i]:9.3g} {int(res['n_lost'][i]):5d}",
                file=sys.stderr,
            )
        print(
            f"sweep: {len(res['cases'])} cases in batches of {res['chunk']} on {res['n_devices']} device(s), "
            f"{res['wall_s']:.1f} s; wrote {', '.join(str(p) for p in paths)}",
            file=sys.stderr,
        )
    return res


def _guard(fn, args) -> int:
    try:
        fn(args)
    except (mpmjax.SceneError, DataError, ValueError) as e:
        print(f"mpmjax: error: {e}", file=sys.stderr)
        return USAGE_ERROR
    except KeyboardInterrupt:
        print(f"\ninterrupted: files already written in {args.out} are kept", file=sys.stderr)
        return 130
    return 0


def cmd_calibrate(args) -> int:
    return _guard(calibrate, args)


def cmd_sweep(args) -> int:
    return _guard(run_sweep, args)
