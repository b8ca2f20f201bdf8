"""``mpmjax calibrate``: its options and its handler (``calibration.run.calibrate``); also the
option parsers and the ``jax.distributed`` options that ``design`` and ``sweep`` share with it.
"""

from __future__ import annotations

import math
import sys

import jax

from calibration.coverage import SIZES as COVERAGE_SIZES
from calibration.coverage import coverage_study
from calibration.coverage import summary_lines as coverage_summary
from calibration.fit import DEFAULT_STARTS, MULTISTART_MIN_PARAMS
from calibration.run import DEFAULT_LEVEL_BUDGET_S, DEFAULT_REFINE, MAX_REFINE, SIGMA_UNITS, calibrate

from ._guard import number

TRANSFORM_CHOICES = ("log", "softplus", "linear", "identity")


def kv(items, what, conv=float) -> dict:
    """``NAME=VALUE`` options (``--init``, ``--sigma``, ...) as a dict, the values by ``conv``;
    ValueError naming the option ``what`` and the item."""
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


def names(text) -> list:
    """A comma-separated list of names (``--fit mu0,alpha``)."""
    return [s.strip() for s in text.split(",") if s.strip()]


def _bounds(text):
    if ":" not in text:
        raise ValueError("expected LO:HI, e.g. 0.1:100")
    lo, hi = (float(v) for v in text.split(":", 1))
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"allowed: finite LO < HI [SI], e.g. 0.1:100; got LO = {lo!r}, HI = {hi!r}")
    return lo, hi


def _transform(text):
    if text not in TRANSFORM_CHOICES:
        raise ValueError(f"allowed: {', '.join(TRANSFORM_CHOICES)}")
    return text


def add_distributed_arguments(p) -> None:
    """``--coordinator``, ``--num-processes``, ``--process-id``, ``--distributed``: the same on
    ``sweep`` and ``calibrate`` (``calibration.distributed``; docs/performance.md "Beyond one machine")."""
    g = p.add_argument_group(
        "beyond one machine (jax.distributed: the batch split over the devices of all processes; "
        "process 0 writes --out)"
    )
    g.add_argument(
        "--coordinator", metavar="HOST:PORT", help="address of process 0 and a free TCP port, e.g. node001:12345"
    )
    number(g, "--num-processes", type=int, lo=1, metavar="N", help="number of processes of the job (>= 1)")
    number(g, "--process-id", type=int, lo=0, metavar="I", help="this process's index, 0 .. N-1")
    g.add_argument(
        "--distributed",
        action="store_true",
        help="join a jax.distributed job, detecting the options not given from the cluster (Slurm srun, Open MPI)",
    )


def add_calibrate_arguments(p) -> None:
    p.add_argument("data", help="measured profiles: CSV (x_m, h_m [, t_s, sigma_m]) or HDF5; see docs/calibration.md")
    p.add_argument("--scene", default="dambreak-lab", help="built-in scene name or TOML path (default dambreak-lab)")
    p.add_argument(
        "--fit",
        required=True,
        help="comma-separated parameters to fit, e.g. mu0,alpha,T,n,lambda0; on a depth-averaged scene with a "
        "coulomb or voellmy terrain also friction, turbulence (its basal friction)",
    )
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
    number(p, "--max-iter", type=int, lo=1, default=50, help="maximum iterations (default 50)")
    number(p, "--learning-rate", lo=0, lo_open=True, default=0.05, help="Adam step in ln(parameter) (default 0.05)")
    number(
        p,
        "--rtol",
        lo=0,
        default=1e-4,
        help="stop when the loss falls by less than this (relative) over --patience iterations, and with lm "
        "also when the Gauss-Newton step predicts a relative decrease below it (default 1e-4)",
    )
    number(p, "--patience", type=int, lo=1, default=5, help="iterations for the rtol test (default 5)")
    number(
        p,
        "--starts",
        type=int,
        lo=1,
        help="multi-start: number of starts, stepped in lockstep with one compiled model (default "
        f"{DEFAULT_STARTS} for {MULTISTART_MIN_PARAMS} or more free parameters, else 1); fit.json lists every "
        "distinct optimum",
    )
    number(p, "--seed", type=int, lo=0, default=0, help="random seed of the extra starts")
    p.add_argument(
        "--gradient",
        default="auto",
        choices=("auto", "forward", "reverse"),
        help="gradient mode: forward (one tangent per parameter), reverse, or auto "
        "(forward for <= 2 parameters, measured break-even 2.7)",
    )
    _add_measurement_arguments(p)
    _add_level_arguments(p)


def _add_measurement_arguments(p) -> None:
    """The measurements besides the profiles, their noise levels and weights."""
    number(
        p,
        "--sigma-m",
        lo=0,
        lo_open=True,
        unit="m",
        help="profile standard deviation [m] where the data give none (default 5%% of max h)",
    )
    number(
        p,
        "--bandwidth-m",
        lo=0,
        lo_open=True,
        unit="m",
        help="kernel bandwidth of the model profile [m] (default: cell size)",
    )
    number(p, "--runout-m", lo=0, unit="m", help="also fit a measured final runout [m]")
    number(p, "--runout-sigma-m", lo=0, lo_open=True, unit="m", help="its standard deviation [m] (default 2 cells)")
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
    number(
        p,
        "--lambda-rest",
        lo=0,
        unit="-",
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


def _add_level_arguments(p) -> None:
    """Multi-fidelity levels, the profile likelihood, the output and the distributed options."""
    lv = p.add_mutually_exclusive_group()
    lv.add_argument(
        "--refine",
        type=int,
        help=f"multi-fidelity: after the fit at the scene's cell size h, continue it at h/2, h/4, ... ({MAX_REFINE} "
        f"at most); the change between levels gives the numerical std (default {DEFAULT_REFINE}: two levels; "
        "0: one level, no numerical std)",
    )
    lv.add_argument(
        "--levels",
        metavar="N|H1,H2,...",
        help="multi-fidelity: a number of levels (1: the fast one-level fit, whose resolution bias is not "
        "estimated) or the cell sizes [m] to fit at, coarse to fine, e.g. 0.02,0.01 (replaces --refine; default: "
        "two levels, the scene's cell size h and h/2)",
    )
    number(p, "--refine-max-iter", type=int, lo=1, help="maximum iterations at each finer level (default: --max-iter)")
    number(
        p,
        "--level-budget-s",
        lo=0,
        lo_open=True,
        unit="s",
        help="a finer level estimated to take longer than this [s] is announced with its cost before it starts "
        f"(default {DEFAULT_LEVEL_BUDGET_S:g})",
    )
    p.add_argument(
        "--profile",
        action="store_true",
        help="profile likelihood of each fitted parameter (re-optimising the others): 95 %% likelihood-ratio "
        "intervals in fit.json (profile_interval_95), profile_likelihood.png, and a warning where they differ "
        "from the Gauss-Newton ones by more than a factor of 2",
    )
    p.add_argument("--profile-points", type=int, default=9, help="grid points per profile (odd, default 9)")
    p.add_argument("--profile-width", type=float, default=4.0, help="grid half-width in Gauss-Newton std (default 4)")
    p.add_argument("--profile-max-iter", type=int, default=10, help="fit iterations per profile point (default 10)")
    p.add_argument("--out", default="calibration-out", help="output folder (default calibration-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    add_distributed_arguments(p)


def cmd_calibrate(args) -> int:
    """``mpmjax calibrate``: the parsed options as a ``calibrate`` call."""
    calibrate(
        args.data,
        fit=names(args.fit),
        scene=args.scene,
        init=kv(args.init, "--init"),
        bounds=kv(args.bounds, "--bounds", _bounds),
        transforms=kv(args.transform, "--transform", _transform),
        overrides=args.set,
        method=args.method,
        max_iter=args.max_iter,
        learning_rate=args.learning_rate,
        rtol=args.rtol,
        patience=args.patience,
        starts=args.starts,
        seed=args.seed,
        gradient=args.gradient,
        sigma_m=args.sigma_m,
        bandwidth_m=args.bandwidth_m,
        runout_m=args.runout_m,
        runout_sigma_m=args.runout_sigma_m,
        flow_curve=args.flow_curve,
        runout_series=args.runout_series,
        rest_times=args.rest_times,
        lambda_rest=args.lambda_rest,
        transient=args.transient,
        sigmas=kv(args.sigma, "--sigma"),
        weights=kv(args.weight, "--weight"),
        refine=args.refine,
        levels=args.levels,
        refine_max_iter=args.refine_max_iter,
        level_budget_s=args.level_budget_s,
        profile=args.profile,
        profile_points=args.profile_points,
        profile_width=args.profile_width,
        profile_max_iter=args.profile_max_iter,
        out=args.out,
        quiet=args.quiet,
        coordinator=args.coordinator,
        num_processes=args.num_processes,
        process_id=args.process_id,
        distributed=args.distributed,
    )
    return 0


def add_coverage_arguments(p) -> None:
    """``mpmjax calibrate-coverage``: the coverage study of ``calibration.coverage``."""
    number(p, "--twins", type=int, lo=1, default=2, help="number of twins (default 2)")
    p.add_argument("--fit", default="mu0", help="comma-separated parameters (default mu0)")
    p.add_argument("--size", default="ci", choices=sorted(COVERAGE_SIZES), help="study size (default ci)")
    p.add_argument("--levels", help="passed to calibrate (default: its default, two levels)")
    number(p, "--data-refine", type=int, lo=2, hi=8, default=2,
           help="the twins' data are made on the fit's first cell size divided by this (default 2: the finer "
                "level's own grid; 4: a grid finer than either level, so that the finer level's resolution error "
                "is real; docs/calibration-coverage.md)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the twins' parameters and noise")
    p.add_argument("--out", default="coverage-out", help="output folder (default coverage-out)")


def cmd_coverage(args) -> int:
    """Run the coverage study (float64, as the fits' tests) and print its summary."""
    jax.config.update("jax_enable_x64", True)
    kw = {} if args.levels is None else {"levels": args.levels}
    doc = coverage_study(
        args.twins, fit=[s for s in args.fit.split(",") if s], size=args.size, seed=args.seed, out=args.out,
        data_refine=args.data_refine, **kw
    )
    for ln in coverage_summary(doc):
        print(ln, file=sys.stderr)
    return 0
