"""Command-line front ends: ``mpmjax calibrate`` and ``mpmjax sweep`` (registered by ``mpmjax.cli``).

Exit status: 0 success, 2 invalid input (the message names the option or key, the value and
the allowed range), 130 interrupted (what was already written stays), 1 other errors.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import mpmjax

from .data import DataError, load_profiles, load_rest_times, load_runout_series, load_shear_tests
from .distributed import (
    DistributedError,
    check_join_options,
    check_local_devices,
    is_writer,
    join,
    make_local_devices,
    parse_shard,
)
from .experiments import (
    FlowCurveExperiment,
    ProfileExperiment,
    RestTimeExperiment,
    RunoutSeriesExperiment,
    ShearHistoryExperiment,
    frames_for,
)
from .multilevel import check_levels, experiments_at_cell_size, fit_multilevel
from .params import UNITS, ParameterSet
from .profile import PROFILE_DEFINITION, check_profile_options, plot_profiles, profile_likelihood
from .sweep import FIELD_KEYS, merge_parts, parse_vary, sweep, write_part, write_sweep
from .uncertainty import REL_STD_WARN, identifiability, identifiability_lines

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


def add_distributed_arguments(p: argparse.ArgumentParser):
    """``--coordinator``, ``--num-processes``, ``--process-id``, ``--distributed``: the same on
    ``sweep`` and ``calibrate`` (``calibration.distributed``; docs/performance.md "Beyond one machine")."""
    g = p.add_argument_group(
        "beyond one machine (jax.distributed: the batch split over the devices of all processes; "
        "process 0 writes --out)"
    )
    g.add_argument(
        "--coordinator", metavar="HOST:PORT", help="address of process 0 and a free TCP port, e.g. node001:12345"
    )
    g.add_argument("--num-processes", type=int, metavar="N", help="number of processes of the job (>= 1)")
    g.add_argument("--process-id", type=int, metavar="I", help="this process's index, 0 .. N-1")
    g.add_argument(
        "--distributed",
        action="store_true",
        help="join a jax.distributed job, detecting the options not given from the cluster (Slurm srun, Open MPI)",
    )


def _join_options(args):
    """The validated ``jax.distributed`` options of ``args`` (None for a single-process run); with
    ``--devices N`` host devices are asked for (``make_local_devices``), so this must run before any
    JAX computation."""
    options = check_join_options(args.coordinator, args.num_processes, args.process_id, args.distributed)
    make_local_devices(getattr(args, "devices", None))
    return options


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
    p.add_argument(
        "--method",
        default="lm",
        choices=("lm", "lbfgs", "adam"),
        help="lm: Levenberg-Marquardt (optimistix; default: a few iterations for a least-squares fit), "
        "lbfgs or adam (optax)",
    )
    p.add_argument("--max-iter", type=int, default=50, help="maximum iterations (default 50)")
    p.add_argument("--learning-rate", type=float, default=0.05, help="Adam step in ln(parameter) (default 0.05)")
    p.add_argument(
        "--rtol",
        type=float,
        default=1e-4,
        help="stop when the loss falls by less than this (relative) over --patience iterations, and with lm "
        "also when the Gauss-Newton step predicts a relative decrease below it (default 1e-4)",
    )
    p.add_argument("--patience", type=int, default=5, help="iterations for the rtol test (default 5)")
    p.add_argument(
        "--starts",
        type=int,
        default=1,
        help="multi-start: number of starts, stepped in lockstep with one compiled model (default 1)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed of the extra starts")
    p.add_argument(
        "--gradient",
        default="auto",
        choices=("auto", "forward", "reverse"),
        help="gradient mode: forward (one tangent per parameter), reverse, or auto "
        "(forward for <= 2 parameters, measured break-even 2.7)",
    )
    p.add_argument(
        "--sigma-m", type=float, help="profile standard deviation [m] where the data give none (default 5%% of max h)"
    )
    p.add_argument("--bandwidth-m", type=float, help="kernel bandwidth of the model profile [m] (default: cell size)")
    p.add_argument("--runout-m", type=float, help="also fit a measured final runout [m]")
    p.add_argument("--runout-sigma-m", type=float, help="its standard deviation [m] (default 2 cells)")
    p.add_argument("--flow-curve", help="also fit rheometer flow-curve points: CSV with gamma_dot_1_s, tau_pa")
    p.add_argument(
        "--runout-series",
        metavar="FILE",
        help="also fit the front position against time of the same dam break: CSV/HDF5 with t_s [s], x_front_m [m] "
        "[, sigma_m [m], weight]",
    )
    p.add_argument(
        "--rest-times",
        metavar="FILE",
        help="also fit repeated releases of the scene after rests (initial structure lambda_rest + t_rest/T): "
        "CSV/HDF5 with t_rest_s [s], t_s [s], x_front_m [m] [, sigma_m [m], lambda_rest, weight]",
    )
    p.add_argument(
        "--lambda-rest",
        type=float,
        help="structure when the rests of --rest-times began [-] (default: the material's lambda0, fitted or fixed)",
    )
    p.add_argument(
        "--transient",
        metavar="FILE",
        help="also fit rheometer transients under shear-rate steps (e.g. pre-shear, rest, start-up overshoot): "
        "CSV/HDF5 with test, t_s [s], gamma_dot_1_s [1/s], tau_pa [Pa] [, sigma_ln, weight]",
    )
    p.add_argument(
        "--sigma",
        action="append",
        metavar="KIND=VALUE",
        help=f"noise level of an experiment kind where its file gives none: {', '.join(SIGMA_UNITS)} "
        f"(units: {', '.join(f'{k} {u}' for k, u in SIGMA_UNITS.items())})",
    )
    p.add_argument(
        "--weight",
        action="append",
        metavar="KIND=W",
        help=f"loss weight of an experiment kind (> 0; overrides its file's weight; default 1): "
        f"{', '.join(SIGMA_UNITS)}",
    )
    lv = p.add_mutually_exclusive_group()
    lv.add_argument(
        "--refine",
        type=int,
        default=0,
        help=f"multi-fidelity: after the fit at the scene's cell size h, continue it at h/2, h/4, ... ({MAX_REFINE} "
        "at most); the shift between levels is reported as the numerical std (default 0: one level, no numerical std)",
    )
    lv.add_argument(
        "--levels",
        metavar="H1,H2,...",
        help="multi-fidelity: the cell sizes [m] to fit at, coarse to fine, e.g. 0.02,0.01 (replaces --refine)",
    )
    p.add_argument(
        "--refine-max-iter", type=int, help="maximum iterations at each finer level (default: --max-iter)"
    )
    p.add_argument(
        "--profile",
        action="store_true",
        help="profile likelihood of each fitted parameter (re-optimising the others): 95 %% likelihood-ratio "
        "intervals in fit.json (profile_interval_95), profile_likelihood.png, and a warning where they differ "
        "from the Gauss-Newton ones by more than a factor of 2",
    )
    p.add_argument("--profile-points", type=int, default=9, help="grid points per profile (odd, default 9)")
    p.add_argument(
        "--profile-width", type=float, default=4.0, help="grid half-width in Gauss-Newton std (default 4)"
    )
    p.add_argument(
        "--profile-max-iter", type=int, default=10, help="fit iterations per profile point (default 10)"
    )
    p.add_argument("--out", default="calibration-out", help="output folder (default calibration-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    add_distributed_arguments(p)


# experiment kinds of --sigma / --weight, and the unit of each kind's sigma
SIGMA_UNITS = {
    "profiles": "m",
    "runout-series": "m",
    "rest-times": "m",
    "transient": "- (relative, in ln tau)",
    "flow-curve": "- (relative, in ln tau)",
}


def _per_kind(items, option):
    """--sigma / --weight KIND=VALUE -> {kind: value > 0}, or ValueError naming the option."""
    out = _kv(items, option)
    for k, v in out.items():
        if k not in SIGMA_UNITS:
            raise ValueError(f"{option} {k}={v:g}: unknown experiment kind {k!r}; allowed: {', '.join(SIGMA_UNITS)}")
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{option} {k}={v!r}; allowed range: > 0 and finite [{SIGMA_UNITS[k].split()[0]}]")
    return out


# --refine: at most this many halvings (each costs ~8x the previous level's run in 2D)
MAX_REFINE = 3


def _levels(args, h0):
    """Cell sizes of the fit's levels [m], coarse to fine, from --levels / --refine."""
    if args.levels is not None:
        try:
            return check_levels([v for v in args.levels.split(",") if v.strip()], "--levels")
        except ValueError as e:
            raise ValueError(f"{e} (got {args.levels!r})") from None
    if not 0 <= args.refine <= MAX_REFINE:
        raise ValueError(f"--refine = {args.refine}; allowed range: 0 .. {MAX_REFINE} (halvings of the cell size)")
    return [h0 / 2**i for i in range(args.refine + 1)]


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


def _scene_overrides(args, times_s, init):
    """(scene config, overrides) for ``args.scene`` with ``args.set``: frames aligned to the data
    times ``times_s`` [s] (unless the user set time.t_end_s or time.n_frames) and the scene's
    material keys set to ``init`` (so range errors name the scene key)."""
    overrides = list(args.set or [])
    keys = {o.split("=", 1)[0].strip() for o in overrides}
    cfg0 = mpmjax.load_scene(args.scene, overrides)
    if not ({"time.t_end_s", "time.n_frames"} & keys):
        t_end, nf = frames_for(list(times_s), cfg0["time.t_end_s"], cfg0["time.n_frames"])
        overrides += [f"time.t_end_s={t_end!r}", f"time.n_frames={nf}"]
    for k, v in init.items():
        if k in FIELD_KEYS:
            overrides.append(f"{FIELD_KEYS[k]}={v!r}")  # validated as a scene value (range errors name the key)
    return cfg0, overrides


def calibrate(args) -> dict:
    """Run a calibration from parsed arguments; returns the fit.json document."""
    out = Path(args.out)
    join(_join_options(args))  # before any JAX computation; nothing for a single-process run
    writer = is_writer()  # only process 0 writes --out and prints progress
    log = (lambda *a: None) if args.quiet or not writer else (lambda *a: print(*a, file=sys.stderr))
    profiles = load_profiles(args.data)
    sigmas = _per_kind(args.sigma, "--sigma")
    weights = _per_kind(args.weight, "--weight")
    if args.sigma_m is not None:
        if "profiles" in sigmas:
            raise ValueError("--sigma-m and --sigma profiles=... both given; give one")
        sigmas["profiles"] = args.sigma_m
    series = load_runout_series(args.runout_series) if args.runout_series else None
    rests = load_rest_times(args.rest_times) if args.rest_times else None
    shear = load_shear_tests(args.transient) if args.transient else None
    if args.lambda_rest is not None and not (np.isfinite(args.lambda_rest) and args.lambda_rest >= 0):
        raise ValueError(f"--lambda-rest = {args.lambda_rest!r}; allowed range: >= 0 and finite [-]")
    data_times = [p.t_s for p in profiles] + (list(series.t_s) if series else [])
    data_times += [float(t) for r in rests or [] for t in r.t_s]
    names = [s.strip() for s in args.fit.split(",") if s.strip()]
    if not names:
        raise ValueError("--fit: name at least one parameter, e.g. --fit mu0,n")
    if args.method == "lm" and args.gradient == "reverse":  # refused before any scene is built
        raise ValueError(
            "--gradient reverse is invalid with --method lm; allowed: forward or auto (the Jacobian of the "
            "residuals is computed in forward mode, one tangent per parameter), or --method lbfgs / adam"
        )
    init = _kv(args.init, "--init")
    cfg0, overrides = _scene_overrides(args, data_times, init)
    if args.profile:
        check_profile_options(args.profile_points, args.profile_width, args.profile_max_iter, "--profile-")
    if args.refine_max_iter is not None and args.refine_max_iter < 1:
        raise ValueError(f"--refine-max-iter = {args.refine_max_iter}; allowed range: integer >= 1")
    levels = _levels(args, float(cfg0["domain.cell_size_m"]))
    overrides = [o for o in overrides if o.split("=", 1)[0].strip() != "domain.cell_size_m"]
    cfgs = []
    for h in levels:
        try:
            cfgs.append(mpmjax.load_scene(args.scene, overrides + [f"domain.cell_size_m={h!r}"]))
        except mpmjax.SceneError as e:
            raise ValueError(f"--levels / --refine: cell size {h:g} m: {e}") from None
    cfg = cfgs[0]
    setup = mpmjax.build(cfg)
    pset = ParameterSet.from_names(
        names,
        setup.params.material,
        init=init,
        bounds=_kv(args.bounds, "--bounds", _bounds),
        transforms=_kv(args.transform, "--transform", _transform),
    )
    # the observable is the same at every level: bandwidth and runout sigma fixed in metres
    bandwidth_m = args.bandwidth_m if args.bandwidth_m is not None else levels[0]
    runout_sigma_m = args.runout_sigma_m if args.runout_sigma_m is not None else 2 * levels[0]
    flow = _load_flow_curve(args.flow_curve) if args.flow_curve else None

    def weight(kind, from_file=None):
        return weights.get(kind, from_file if from_file is not None else 1.0)

    def make(st):
        exps = [
            ProfileExperiment(
                st,
                profiles,
                bandwidth_m=bandwidth_m,
                sigma_m=sigmas.get("profiles"),
                runout_m=args.runout_m,
                runout_sigma_m=runout_sigma_m,
                weight=weight("profiles"),
                name=Path(args.data).name,
            )
        ]
        if series is not None:
            exps.append(
                RunoutSeriesExperiment(
                    st,
                    series.t_s,
                    series.x_front_m,
                    sigma_m=series.sigma_m if series.sigma_m is not None else sigmas.get("runout-series", runout_sigma_m),
                    sigma_known=series.sigma_m is not None or "runout-series" in sigmas,
                    bandwidth_m=bandwidth_m,
                    weight=weight("runout-series", series.weight),
                    name=Path(args.runout_series).name,
                )
            )
        if rests is not None:
            lam = {r.lambda_rest for r in rests} - {None}
            if len(lam) > 1 or (lam and args.lambda_rest is not None):
                raise ValueError(
                    f"{args.rest_times}: lambda_rest differs between rest times ({sorted(lam)}) or is given both in the "
                    "file and by --lambda-rest; allowed: one value"
                )
            exps.append(
                RestTimeExperiment(
                    st,
                    [(r.rest_time_s, r.t_s, r.x_front_m, r.sigma_m) for r in rests],
                    sigma_m=sigmas.get("rest-times", runout_sigma_m),
                    sigma_known=all(r.sigma_m is not None for r in rests) or "rest-times" in sigmas,
                    bandwidth_m=bandwidth_m,
                    lambda_rest=next(iter(lam), args.lambda_rest),
                    weight=weight("rest-times", rests[0].weight),
                    name=Path(args.rest_times).name,
                )
            )
        if shear is not None:
            exps.append(
                ShearHistoryExperiment(
                    st.params.material,
                    shear[0],
                    sigma_ln=sigmas.get("transient"),
                    weight=weight("transient", shear[1]),
                    name=Path(args.transient).name,
                )
            )
        if flow is not None:
            exps.append(
                FlowCurveExperiment(
                    st.params.material,
                    *flow,
                    sigma_ln=sigmas.get("flow-curve"),
                    weight=weight("flow-curve"),
                    name=Path(args.flow_curve).name,
                )
            )
        return exps

    build_at = experiments_at_cell_size(args.scene, overrides, make)

    def make_experiments(h):
        return make(setup) if h == levels[0] else build_at(h)

    if writer:
        out.mkdir(parents=True, exist_ok=True)

    def on_level(i, h, exps):
        sc = exps[0].setup.scene
        log(
            f"calibrate: level {i + 1}/{len(levels)}: scene {cfg['name']} at h = {h:g} m ({sc.n_particles} particles, "
            f"{sc.n_steps} steps of {sc.dt:.3g} s to t = {sc.t_end:g} s), {len(profiles)} profile(s) from "
            f"{args.data}, fitting {', '.join(pset.free)} with {args.method}"
            + (f", {args.starts} start(s)" if i == 0 else ", from the previous level's result")
        )

    def progress(level, h, it, max_iter, losses, best, running):
        if not writer:
            return
        if not args.quiet:
            vals = ", ".join(f"{k}={v:.4g}" for k, v in best.items())
            lv = f" level {level + 1}/{len(levels)}" if len(levels) > 1 else ""
            print(f"calibrate:{lv} iteration {it}/{max_iter} loss {float(np.min(losses)):.4e} {vals}", file=sys.stderr)
        mpmjax.atomic_write_text(
            out / "fit_progress.json",
            json.dumps(
                {"level": level, "cell_size_m": h, "iteration": it, "loss": float(np.min(losses)), "params": best,
                 "complete": False},
                indent=1,
            ),
        )

    t0 = time.perf_counter()
    ml = fit_multilevel(
        make_experiments,
        pset,
        levels,
        max_iter=args.max_iter,
        refine_max_iter=args.refine_max_iter,
        n_starts=args.starts,
        progress=progress,
        on_level=on_level,
        method=args.method,
        learning_rate=args.learning_rate,
        rtol=args.rtol,
        patience=args.patience,
        seed=args.seed,
        gradient=args.gradient,
    )
    res, unc, exps, comb = ml.result, ml.uncertainty, ml.experiments, ml.combined
    wall = time.perf_counter() - t0
    warnings = list(unc.warnings)
    for k in comb["poorly_identified"]:
        if k not in unc.poorly_identified:
            warnings.append(
                f"{k} is poorly identified: its total relative standard deviation {comb['rel_std'][k]:.3g} exceeds "
                f"{REL_STD_WARN:g} (numerical {comb['std_numerical'][k]:.3g}, "
                f"statistical {comb['std_statistical'][k]:.3g})"
            )
    if ml.numerical is None:
        warnings.append(
            "numerical (discretisation) uncertainty not estimated: one level; the std is statistical only and "
            "misses the grid's resolution bias (rerun with --refine 1 or --levels)"
        )
    profiles_lr = None
    if args.profile:
        log(f"calibrate: profile likelihood of {', '.join(pset.free)} ({args.profile_points} points each)")
        profiles_lr = profile_likelihood(
            exps, pset, res.params, unc, n_points=args.profile_points, width_sigma=args.profile_width,
            max_iter=args.profile_max_iter,
        )
        warnings += [p.warning for p in profiles_lr.values() if p.warning]
    for w in warnings:
        log(f"calibrate: warning: {w}")
    finest = f"domain.cell_size_m={levels[-1]!r}"
    doc = {
        "params": res.params,
        "std": comb["std"],
        "std_statistical": comb["std_statistical"],
        "std_numerical": comb["std_numerical"],
        "rel_std": comb["rel_std"],
        "poorly_identified": comb["poorly_identified"],
        "std_definition": (
            "std = sqrt(std_statistical^2 + std_numerical^2); std_statistical: Gauss-Newton at the finest level; "
            "std_numerical: |shift| of the fitted value between the last two levels, or with three levels where "
            "the observed order allows, |finest - Richardson extrapolate| (numerical_uncertainty.method); null "
            "with one level"
        ),
        "numerical_uncertainty": None if ml.numerical is None else ml.numerical.as_dict(),
        "levels": [
            {
                "cell_size_m": lv.cell_size_m,
                "n_particles": lv.n_particles,
                "n_steps": lv.n_steps,
                "params": lv.result.params,
                "loss_initial": lv.result.loss_initial,
                "loss_final": lv.result.loss_final,
                "iterations": lv.result.iterations,
                "converged": bool(lv.result.converged),
                "stop_reason": lv.result.reason,
                "wall_s": lv.result.wall_s,
                "cpu_s": lv.result.cpu_s,
                "evaluations": lv.result.evaluations,
                "loss_history": [float(v) for v in lv.result.history.min(axis=1)],
            }
            for lv in ml.levels
        ],
        "loss_initial": ml.levels[0].result.loss_initial,
        "loss_final": res.loss_final,
        "iterations": res.iterations,
        "wall_s": wall,
        "converged": bool(res.converged),
        "stop_reason": res.reason,
        "units": {k: UNITS.get(k, "SI") for k in pset.specs},
        "initial": {k: pset.specs[k].init for k in pset.free},
        "fixed": {k: s.init for k, s in pset.specs.items() if s.fixed},
        "specs": pset.bounds_table(),
        "uncertainty": {**unc.as_dict(), "warnings": warnings},
        "identifiability": identifiability(unc),
        "experiments": [
            {
                "name": e.name,
                "kind": type(e).__name__,
                "weight": e.weight,
                "n_residuals": e.n_residuals,
                "sigma_known": bool(e.sigma_known),
                "noise_scale": s,
            }
            for e, s in zip(exps, unc.noise_scale, strict=True)
        ],
        "loss_definition": "sum over experiments of weight * mean(((model - data) / sigma)^2), dimensionless",
        "loss_history": [float(v) for v in res.history.min(axis=1)],
        "method": args.method,
        "gradient": res.gradient,
        "starts": ml.levels[0].result.starts,
        "finals": ml.levels[0].result.finals,
        "final_losses": [float(v) for v in ml.levels[0].result.final_losses],
        "best_start": ml.levels[0].result.best_start,
        "compile_s": res.compile_s,
        "n_processes": jax.process_count(),
        "n_devices": jax.device_count(),
        "cpu_s": res.cpu_s,
        "compile_cpu_s": res.compile_cpu_s,
        "evaluations": res.evaluations,
        "scene": cfg["name"],
        "scene_overrides": overrides
        + [finest]
        + [f"{FIELD_KEYS[k]}={v!r}" for k, v in res.params.items() if k in FIELD_KEYS],
        "bandwidth_m": bandwidth_m,
        "data": str(args.data),
        "profile_times_s": [p.t_s for p in profiles],
        "frame_time_offsets_s": list(exps[0].time_offsets_s),
        "sigma_known": exps[0].sigma_known,
        "code_version": mpmjax.__version__,
    }
    if profiles_lr is not None:
        doc["profile_interval_95"] = {k: list(p.interval_95) for k, p in profiles_lr.items()}
        doc["profile_likelihood"] = {
            "definition": PROFILE_DEFINITION,
            **{k: p.as_dict(UNITS.get(k, "SI")) for k, p in profiles_lr.items()},
        }
    if not writer:
        return doc
    if profiles_lr is not None:
        plot_profiles(
            profiles_lr, out / "profile_likelihood.png", {k: UNITS.get(k, "SI") for k in pset.free},
            {k: pset.specs[k].transform for k in pset.free},
        )
    mpmjax.atomic_write_text(out / "fit.json", json.dumps(doc, indent=1))
    (out / "fit_progress.json").unlink(missing_ok=True)
    _plots(out, exps[0], pset, ml, profiles, doc)
    for lv in ml.levels:
        r = lv.result
        log(
            f"calibrate: h = {lv.cell_size_m:g} m: loss {r.loss_initial:.4g} -> {r.loss_final:.4g} in {r.iterations} "
            f"iterations ({'converged: ' + r.reason if r.converged else 'not converged'}), "
            + ", ".join(f"{k} = {v:.5g}" for k, v in r.params.items())
        )
    log(f"calibrate: {wall:.1f} s; at h = {levels[-1]:g} m:")
    for line in summary_lines(doc) + identifiability_lines(doc["identifiability"]):
        log(line)
    log(
        f"wrote {out / 'fit.json'}, {out / 'fit_profiles.png'}, {out / 'loss_history.png'}"
        + (f", {out / 'profile_likelihood.png'}" if profiles_lr is not None else "")
    )
    return doc


def _fmt(v):
    return "inf" if v is None else f"{v:.3g}"


def summary_lines(doc) -> list:
    """The fitted values with total, statistical and numerical std, the Richardson
    extrapolates and the poorly identified names: the printed summary (also the text of
    fit_profiles.png)."""
    num = doc.get("numerical_uncertainty")
    out = []
    for k, v in doc["params"].items():
        s = (
            f"  {k} = {v:.5g} +- {_fmt(doc['std'][k])} [{doc['units'].get(k, 'SI')}] "
            f"(statistical {_fmt(doc['std_statistical'][k])}"
        )
        if num is None:
            s += ", numerical not estimated)"
        else:
            how = {"shift": "shift", "richardson": "Richardson estimate"}[num["method"][k]]
            s += f", numerical {_fmt(doc['std_numerical'][k])} from the {how})"
        if k in doc["poorly_identified"]:
            s += "  POORLY IDENTIFIED"
        out.append(s)
    for k, p in doc.get("profile_likelihood", {}).items():
        if k == "definition":
            continue
        lo, hi = (_fmt(v) for v in p["profile_interval_95"])
        glo, ghi = (_fmt(v) for v in p["gauss_newton_interval_95"])
        out.append(
            f"  {k}: 95 % profile-likelihood interval {lo} .. {hi}, Gauss-Newton {glo} .. {ghi}"
            + ("  DISAGREE (factor > 2)" if p["warning"] else "")
        )
    if num is not None:
        for k, r in num["richardson"].items():
            if r["extrapolated"] is not None:
                out.append(f"  Richardson: {k} -> {r['extrapolated']:.5g} (h -> 0, observed order {r['order']:.2f})")
            else:
                out.append(f"  Richardson: {k} not extrapolated: {r['why_not']}")
    return out


def _plots(out, exp, pset, ml, profiles, doc):
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = ml.result
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
    hs = " -> ".join(f"{lv.cell_size_m:g}" for lv in ml.levels)
    ax.set_title(f"fitted at h = {hs} m: value +- total std (statistical, numerical)", fontsize=9)
    ax.text(
        0.99, 0.97, "\n".join(ln.strip() for ln in summary_lines(doc)), transform=ax.transAxes, ha="right", va="top",
        fontsize=6.5, family="monospace", bbox={"boxstyle": "round", "fc": "white", "alpha": 0.85},
    )
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "fit_profiles.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    it0 = 0
    for lv in ml.levels:
        hist = lv.result.history
        ax.semilogy(it0 + np.arange(hist.shape[0]), hist, lw=1, label=f"h = {lv.cell_size_m:g} m")
        it0 += hist.shape[0] - 1
    ax.set_xlabel("iteration (all levels)")
    ax.set_ylabel("loss (dimensionless)")
    ax.set_title(f"loss {ml.levels[0].result.loss_initial:.3g} -> {res.loss_final:.3g}")
    if len(ml.levels) > 1:
        ax.legend(fontsize=7)
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
    p.add_argument(
        "--devices",
        type=int,
        metavar="N",
        help="on a CPU: make N host devices, one per core, and split the batch over them (default 1; on 2 cores "
        "a sweep of 16 cases ran 1.3-1.5x faster); the batch always uses every device the process has",
    )
    add_distributed_arguments(p)
    p.add_argument(
        "--shard",
        metavar="I/N",
        help="independent job I of N (e.g. a job array): run the I-th of N shares of the cases and write "
        "OUT/part-I-of-N.npz; `mpmjax sweep-merge OUT` joins the parts",
    )


def add_sweep_merge_arguments(p: argparse.ArgumentParser):
    p.add_argument("parts", help="folder of the part-I-of-N.npz files of `mpmjax sweep --shard I/N`")
    p.add_argument("--out", help="output folder of sweep.csv, sweep.json and the plots (default: the parts' folder)")
    p.add_argument("--quiet", action="store_true", help="no summary output")


def _print_sweep(res, paths, how):
    names = list(res["vary"])
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
    print(f"sweep: {len(res['cases'])} cases {how}; wrote {', '.join(str(p) for p in paths)}", file=sys.stderr)


def run_sweep(args) -> dict:
    options = _join_options(args)
    shard = parse_shard(args.shard) if args.shard is not None else None
    if shard is not None and options is not None:
        raise DistributedError(
            "--shard and --coordinator / --num-processes / --process-id / --distributed both given; allowed: one "
            "(--shard: independent jobs merged by `mpmjax sweep-merge`; the others: one jax.distributed job)"
        )
    vary = parse_vary(args.vary)
    join(options)  # before any JAX computation; nothing for a single-process run
    check_local_devices(args.devices)
    writer = is_writer()
    res = sweep(args.scene, vary, overrides=args.set, chunk=args.chunk, progress=not args.quiet, shard=shard)
    how = (
        f"in batches of {res['chunk']} on {res['n_devices']} device(s) of {res['n_processes']} process(es), "
        f"{res['wall_s']:.1f} s"
    )
    if shard is not None:
        path = write_part(res, args.out)
        if not args.quiet:
            ci = res["case_index"]
            share = f"cases {ci[0]} .. {ci[-1]}" if len(ci) else "no case"
            _print_sweep(res, [path], f"(job {shard[0]} of {shard[1]}: {share} of {res['n_cases']}) {how}")
        return res
    if not writer:  # the other processes of a distributed job leave --out to process 0
        return res
    paths = write_sweep(res, args.out)
    if not args.quiet:
        _print_sweep(res, paths, how)
    return res


def run_sweep_merge(args) -> dict:
    res = merge_parts(args.parts)
    paths = write_sweep(res, args.out or args.parts)
    if not args.quiet:
        _print_sweep(res, paths, f"from {res['parts']} part(s), {res['wall_s']:.1f} s of wall time in all")
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


def cmd_sweep_merge(args) -> int:
    if args.out is None:
        args.out = args.parts
    return _guard(run_sweep_merge, args)
