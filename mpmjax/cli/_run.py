"""``mpmjax scenes`` and ``mpmjax run``: their options and handlers (the run is ``mpmjax.run_scene``)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from .._driver import ANIMATION_MAX_FRAMES, CHECKPOINT_EVERY, run_scene
from .._schema import SCHEMA, builtin_scenes
from .._schema.reference import default_label
from ._guard import number
from ._status import UsageError


def add_scenes_arguments(p) -> None:
    p.add_argument("--keys", action="store_true", help="list every scene key with unit, default and range")


def cmd_scenes(args) -> int:
    if args.keys:
        for key, spec in SCHEMA.items():
            default = default_label(spec) or repr(spec.default)
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


def add_run_arguments(p) -> None:
    p.add_argument(
        "scene",
        nargs="?",
        default=None,
        help="built-in scene name or TOML path (default dambreak-lab; with --resume: the checkpoint's)",
    )
    p.add_argument("--out", help="output directory (default runs/SCENE)")
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a scene key, e.g. material.mu0_pa_s=2"
    )
    number(
        p,
        "--devices",
        type=int,
        lo=1,
        metavar="N",
        help="split the run's particles over N devices (numerics.devices; on a CPU: N host devices, one per core); "
        "the grid is replicated, or cut into slabs with --set numerics.decomposition=slab",
    )
    p.add_argument("--quiet", action="store_true", help="no progress output")
    number(
        p,
        "--checkpoint-every",
        type=int,
        lo=0,
        default=CHECKPOINT_EVERY,
        metavar="N",
        help=f"write OUT/checkpoint.h5 every N frames (default {CHECKPOINT_EVERY}; 0: only on interrupt)",
    )
    p.add_argument(
        "--resume",
        metavar="DIR",
        help="continue the interrupted run in DIR from DIR/checkpoint.h5 (same scene and --set, or none)",
    )
    p.add_argument(
        "--no-animation",
        action="store_true",
        help=f"do not write OUT/animation.gif (by default a GIF of at most {ANIMATION_MAX_FRAMES} frames)",
    )


def _out_folder(args) -> Path:
    """The run's folder: ``--resume DIR``, else ``--out``, else runs/SCENE."""
    if args.resume:
        out = Path(args.resume)
        if args.out and Path(args.out).resolve() != out.resolve():
            raise UsageError(f"--out {args.out} and --resume {args.resume} name different folders; give one")
        return out
    return Path(args.out) if args.out else Path("runs") / Path(args.scene or "dambreak-lab").stem


def cmd_run(args) -> int:
    args.out = _out_folder(args)  # the interrupt and failure messages of the command table name it
    overrides = list(args.set or []) + ([f"numerics.devices={args.devices}"] if args.devices is not None else [])
    run_scene(
        args.scene,
        args.out,
        overrides or None,
        quiet=args.quiet,
        checkpoint_every=args.checkpoint_every,
        resume=bool(args.resume),
        animate=not args.no_animation,
    )
    return 0
