"""``mpmjax sweep`` and ``mpmjax sweep-merge``: their options and handlers
(``calibration.sweep.run_sweep`` and ``merge_sweep``)."""

from __future__ import annotations

from calibration.distributed import parse_shard
from calibration.sweep import merge_sweep, parse_vary, run_sweep

from ._calibrate import add_distributed_arguments
from ._guard import number


def add_sweep_arguments(p) -> None:
    p.add_argument("scene", nargs="?", default="dambreak-lab", help="built-in scene name or TOML path")
    p.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="NAME=V1,V2,...",
        help="material parameter (or friction / turbulence: the basal friction of a depth-averaged scene on a "
        "coulomb or voellmy terrain) and its values [SI], e.g. n=1.5,2,2.5,3; repeat for a grid",
    )
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="scene override, e.g. time.t_end_s=5")
    number(p, "--chunk", type=int, lo=1, help="cases per vmap batch (default: as many as fit in a quarter of memory)")
    p.add_argument("--out", default="sweep-out", help="output folder (default sweep-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the interrupted sweep in --out: run only the cases not finished (kept in "
        "OUT/sweep-partial.npz); the same command without --resume also continues it",
    )
    number(
        p,
        "--devices",
        type=int,
        lo=1,
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


def add_sweep_merge_arguments(p) -> None:
    p.add_argument("parts", help="folder of the part-I-of-N.npz files of `mpmjax sweep --shard I/N`")
    p.add_argument("--out", help="output folder of sweep.csv, sweep.json and the plots (default: the parts' folder)")
    p.add_argument("--quiet", action="store_true", help="no summary output")


def cmd_sweep(args) -> int:
    run_sweep(
        args.scene,
        parse_vary(args.vary),
        overrides=args.set,
        chunk=args.chunk,
        out=args.out,
        quiet=args.quiet,
        devices=args.devices,
        shard=parse_shard(args.shard) if args.shard is not None else None,
        coordinator=args.coordinator,
        num_processes=args.num_processes,
        process_id=args.process_id,
        distributed=args.distributed,
        resume=args.resume,
    )
    return 0


def cmd_sweep_merge(args) -> int:
    if args.out is None:
        args.out = args.parts  # also for the interrupt message of the command table
    merge_sweep(args.parts, args.out, quiet=args.quiet)
    return 0
