"""Command line: ``mpmjax scenes | run | rheometer | bench | stress | records | pareto | converge | validate | study |
calibrate | design | sweep | sweep-merge``: argument parsing and dispatch only; the work is done by the
library (``mpmjax.run_scene``: ``mpmjax._driver``), ``mpmjax.rheometer``, ``mpmjax.studies`` and
``calibration``.

Exit status: 0 success, 2 invalid input (the message names the key, the value and the
allowed range; also a ``--resume`` that does not match, an ``--out`` that is a file or cannot be
created or written, a run refused by the memory estimate), 3 a run stopped by a failed health
check (NaN, absurd J, lost particles, CFL; frames already written stay readable; ``mpmjax
stress``: a case failed its criteria; ``mpmjax validate --size full``: a case missed its
tolerance), 4 a run stopped because its output could not be written (frames already written
stay readable), 130 interrupted by Ctrl-C, also while compiling (143 by SIGTERM; frames already
written stay readable and ``mpmjax run --resume DIR`` continues), 1 other errors (a bug).  Every
status but 1 comes with a one-line message, no traceback.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from calibration import cli as calcli
from calibration import design_cli

from . import rheometer
from ._driver import (
    ANIMATION_MAX_FRAMES,
    CHECKPOINT_EVERY,
    FAILED,
    OUTPUT_FAILED,
    Interrupted,
    OutputFailure,
    fail,
    run_scene,
)
from ._health import RunFailure
from ._schema import _REQ, SCHEMA, SceneError, builtin_scenes
from .studies import bench, converge, pareto, records, stress, validate
from .studies.tables import run_study


def cmd_scenes(args) -> int:
    if args.keys:
        for key, spec in SCHEMA.items():
            default = "(required)" if spec.default is _REQ else repr(spec.default)
            rng = ""
            if spec.choices:
                rng = "one of " + ", ".join(map(str, spec.choices))
            elif spec.lo is not None or spec.hi is not None:
                rng = f"{'>' if spec.lo_open else '>='} {spec.lo}" if spec.lo is not None else ""
                rng += f"{', ' if rng else ''}<= {spec.hi}" if spec.hi is not None else ""
            print(f"{key:38s} [{spec.unit}] default={default} {rng}\n    {spec.doc}")
        return 0
    for name, path in sorted(builtin_scenes().items()):
        desc = tomllib.loads(path.read_text()).get("description", "").split(". ")[0]
        print(f"{name:24s} {desc}")
    return 0


def cmd_run(args) -> int:
    if args.checkpoint_every < 0:
        return fail(f"--checkpoint-every = {args.checkpoint_every} is invalid: allowed range: >= 0 frames (0: never)")
    if args.resume:
        out = Path(args.resume)
        if args.out and Path(args.out).resolve() != out.resolve():
            return fail(f"--out {args.out} and --resume {args.resume} name different folders; give one")
    else:
        out = Path(args.out) if args.out else Path("runs") / Path(args.scene or "dambreak-lab").stem
    overrides = list(args.set or []) + ([f"numerics.devices={args.devices}"] if args.devices is not None else [])
    try:
        run_scene(
            args.scene,
            out,
            overrides or None,
            quiet=args.quiet,
            checkpoint_every=args.checkpoint_every,
            resume=bool(args.resume),
            animate=not args.no_animation,
        )
    except SceneError as e:
        return fail(str(e))
    except RunFailure as e:
        print(
            f"\nmpmjax: {e}\nframes before the failure remain readable in {out / 'result.h5'}; "
            f"summary.json has status 'failed'",
            file=sys.stderr,
        )
        return FAILED
    except OutputFailure as e:
        print(f"\nmpmjax: {e}", file=sys.stderr)
        return OUTPUT_FAILED
    except Interrupted as e:
        msg = e.message or f"interrupted: frames written so far remain readable in {out / 'result.h5'}"
        print(f"\n{msg}", file=sys.stderr)
        return 128 + e.signum
    except KeyboardInterrupt:
        print(f"\ninterrupted: frames written so far remain readable in {out / 'result.h5'}", file=sys.stderr)
        return 130
    return 0


def cmd_rheometer(args) -> int:
    return rheometer.run_from_args(args)


def cmd_bench(args) -> int:
    try:
        return bench.run_bench(args)
    except ValueError as e:
        return fail(str(e))


def cmd_study(args) -> int:
    try:
        options = {"measures": tuple(args.measure)} if args.name == "physical" and args.measure else {}
        if args.measure and args.name != "physical":
            return fail(f"--measure {args.measure[0]} is invalid: only for study physical")
        return run_study(args.name, Path(args.out), **options)
    except ValueError as e:
        return fail(str(e))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="mpmjax", description="Differentiable MPM for thixotropic mine tailings (SI units)."
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    ps = sub.add_parser("scenes", help="list the built-in scenes (or, with --keys, every scene key)")
    ps.add_argument("--keys", action="store_true", help="list every scene key with unit, default and range")
    ps.set_defaults(fn=cmd_scenes)
    pr = sub.add_parser("run", help="run a scene and write result.h5, summary.json and result.png")
    pr.add_argument(
        "scene",
        nargs="?",
        default=None,
        help="built-in scene name or TOML path (default dambreak-lab; with --resume: the checkpoint's)",
    )
    pr.add_argument("--out", help="output directory (default runs/SCENE)")
    pr.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a scene key, e.g. material.mu0_pa_s=2"
    )
    pr.add_argument(
        "--devices",
        type=int,
        metavar="N",
        help="split the run's particles over N devices (numerics.devices; on a CPU: N host devices, one per core); "
        "the grid is replicated, or cut into slabs with --set numerics.decomposition=slab",
    )
    pr.add_argument("--quiet", action="store_true", help="no progress output")
    pr.add_argument(
        "--checkpoint-every",
        type=int,
        default=CHECKPOINT_EVERY,
        metavar="N",
        help=f"write OUT/checkpoint.h5 every N frames (default {CHECKPOINT_EVERY}; 0: only on interrupt)",
    )
    pr.add_argument(
        "--resume",
        metavar="DIR",
        help="continue the interrupted run in DIR from DIR/checkpoint.h5 (same scene and --set, or none)",
    )
    pr.add_argument(
        "--no-animation",
        action="store_true",
        help=f"do not write OUT/animation.gif (by default a GIF of at most {ANIMATION_MAX_FRAMES} frames)",
    )
    pr.set_defaults(fn=cmd_run)
    prh = sub.add_parser("rheometer", help="0-D Coussot rheometer: viscosity vs time and flow curves")
    rheometer.add_arguments(prh)
    prh.set_defaults(fn=cmd_rheometer)
    pb = sub.add_parser("bench", help="measure particle-steps/s, scaling, gradient/forward time and vmap batching")
    bench.add_arguments(pb)
    pb.set_defaults(fn=cmd_bench)
    pss = sub.add_parser("stress", help="robustness cases (stiff, viscous, field scale, slope, drop, 100k steps)")
    stress.add_arguments(pss)
    pss.set_defaults(fn=stress.cmd_stress)
    prec = sub.add_parser("records", help="run the thesis's record scenes; our figures next to the thesis's (table)")
    records.add_arguments(prec)
    prec.set_defaults(fn=records.cmd_records)
    ppa = sub.add_parser("pareto", help="error against run time of the lab dam break numerics (Pareto front)")
    pareto.add_arguments(ppa)
    ppa.set_defaults(fn=pareto.cmd_pareto)
    pcv = sub.add_parser(
        "converge", help="convergence benchmark: runout against h, ppc, shape and anti-locking, with order and CPU time"
    )
    converge.add_arguments(pcv)
    pcv.set_defaults(fn=converge.cmd_converge)
    pva = sub.add_parser(
        "validate", help="validation suite: every case against its exact or experimental reference, error and CPU time"
    )
    validate.add_arguments(pva)
    pva.set_defaults(fn=validate.cmd_validate)
    pst = sub.add_parser("study", help="thesis sensitivity tables and the stiff-viscosity comparison (slow)")
    pst.add_argument("name", choices=("numerical", "physical", "stiff"))
    pst.add_argument("--out", default="studies", help="output directory")
    pst.add_argument(
        "--measure",
        action="append",
        choices=("standard", "thesis"),
        help="physical: the shear measure(s) to run (default both)",
    )
    pst.set_defaults(fn=cmd_study)
    pc = sub.add_parser("calibrate", help="fit material parameters to measured height profiles (optax, gradients)")
    calcli.add_calibrate_arguments(pc)
    pc.set_defaults(fn=calcli.cmd_calibrate)
    pdz = sub.add_parser("design", help="rank candidate measurements by the information they add (D-optimal)")
    design_cli.add_design_arguments(pdz)
    pdz.set_defaults(fn=design_cli.cmd_design)
    psw = sub.add_parser("sweep", help="run a grid of material parameters as one vmap batch (runout, time to rest)")
    calcli.add_sweep_arguments(psw)
    psw.set_defaults(fn=calcli.cmd_sweep)
    psm = sub.add_parser("sweep-merge", help="join the parts of `mpmjax sweep --shard I/N` jobs into one sweep")
    calcli.add_sweep_merge_arguments(psm)
    psm.set_defaults(fn=calcli.cmd_sweep_merge)
    args = p.parse_args(argv)
    return args.fn(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
