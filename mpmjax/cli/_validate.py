"""``mpmjax converge`` and ``mpmjax validate``: their options and handlers (``mpmjax.studies.converge``
and ``mpmjax.studies.validate``); both take ``--set numerics.KEY=VALUE`` for every run."""

from __future__ import annotations

import sys

from pathlib import Path

from .._schema import SceneError, parse_override
from ..studies import converge, validate
from ._guard import number
from ._status import FAILED, UsageError
from ._studies import make_folders


def _numerics_overrides(items, why: str = "") -> dict:
    """``--set numerics.KEY=VALUE`` items as key -> TOML value (as ``run --set`` reads them)."""
    base = {}
    for item in items:
        key, sep, _ = item.partition("=")
        if not sep or not key.strip().startswith("numerics."):
            raise UsageError(f"--set {item} is invalid: allowed: numerics.KEY=VALUE{why}")
        key, base[key] = parse_override(item)
    return base


def add_converge_arguments(p) -> None:
    p.add_argument("--size", choices=("ci", "full"), default="full", help="ci: tiny (seconds); full: the measurement")
    p.add_argument(
        "--case", nargs="+", choices=sorted(converge.CASES), default=["lab", "slump", "water"], dest="cases"
    )
    number(
        p,
        "--levels",
        type=int,
        lo=2,
        hi=6,
        default=None,
        help=f"number of cell sizes, halving (default {converge.LEVELS}; ci 3)"
    )
    number(p, "--ppc", nargs="+", type=int, lo=1, hi=4, default=[1, 2, 3], help="particles per cell per axis to sweep")
    p.add_argument(
        "--shapes", nargs="+", choices=converge.SHAPES, default=list(converge.SHAPES), help="shape functions to sweep"
    )
    p.add_argument("--volume", nargs="+", choices=("none", "jbar"), default=["none", "jbar"], dest="volumes")
    p.add_argument("--out", default="converge", help="output folder: writes OUT/bench/converge.* and OUT/img/")
    p.add_argument("--fresh", action="store_true", help="rerun every case (default: reuse finished runs in the JSON)")
    p.add_argument(
        "--report-only", action="store_true", help="re-analyse OUT/bench/converge.json as it stands; run nothing"
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scene override for every run (e.g. numerics.shape=quadratic_bm: the series then vary around it)",
    )


def cmd_converge(args) -> int:
    if args.report_only:
        try:
            converge.report(args.out)
        except (OSError, ValueError, KeyError) as e:
            where = Path(args.out) / "bench" / "converge.json"
            raise UsageError(f"--report-only: {where} cannot be read: {e}") from None
        return 0
    make_folders(args.out)
    base = _numerics_overrides(args.set)
    for case in args.cases:
        try:
            converge.case_config(case, base)
        except SceneError as e:
            raise UsageError(f"--set: {e}") from None
    converge.run_converge(
        tuple(args.cases),
        base=base,
        size=args.size,
        out=args.out,
        levels=args.levels,
        ppcs=tuple(args.ppc),
        shapes=tuple(args.shapes),
        volumes=tuple(args.volumes),
        fresh=args.fresh,
    )
    return 0


def add_validate_arguments(p) -> None:
    p.add_argument(
        "--case",
        nargs="+",
        choices=list(validate.CASES),
        default=None,
        dest="cases",
        metavar="NAME",
        help=f"cases to run (default all): {', '.join(validate.CASES)}",
    )
    p.add_argument(
        "--size",
        choices=("ci", "full"),
        default="full",
        help="ci: coarse and short (seconds per case; records errors, claims no pass); full: the measurement",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="numerics override for every case, e.g. numerics.pressure=explicit (repeatable)",
    )
    p.add_argument("--out", default="validate", help="output folder: OUT/validate.json and OUT/validate.png")
    p.add_argument(
        "--fresh",
        action="store_true",
        help="rerun every case (default: reuse finished cases in the JSON whose scene, reference and tolerance are "
        "unchanged)",
    )


def cmd_validate(args) -> int:
    """0, or ``FAILED`` (3) when a case of ``--size full`` missed its tolerance."""
    base = _numerics_overrides(args.set, " (the suite's physics and references are fixed)")
    cases = args.cases or list(validate.CASES)
    refused = {}
    for name in cases:
        try:
            validate.CASES[name].cfgs(args.size, base)
        except SceneError as e:
            refused[name] = e
    if len(refused) == len(cases):  # a bad key or value, or one that no asked-for case takes
        name, e = next(iter(refused.items()))
        raise UsageError(f"--set (case {name}): {e}") from None
    for name, e in refused.items():  # a key of the other formulation (the depth-averaged cases refuse the full
        # model's volume options and the full-model cases the depth-averaged keys): recorded as rejected, not run
        print(f"mpmjax: note: case {name} does not take --set {' '.join(args.set)} ({e}); recorded as rejected",
              file=sys.stderr)
    make_folders(args.out, ("",))
    doc = validate.run_validate(cases, size=args.size, out=args.out, base=base, fresh=args.fresh)
    return FAILED if any(r.get("pass") is False for r in doc["cases"].values()) else 0
