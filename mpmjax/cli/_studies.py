"""``mpmjax bench | stress | records | pareto | study``: their options and handlers (the studies
of ``mpmjax.studies``; ``converge`` and ``validate`` are in ``_validate``)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..studies import bench, pareto, records, stress
from ..studies.tables import run_study
from ._guard import number
from ._status import FAILED, UsageError


def _log(*a) -> None:
    print(*a, file=sys.stderr)


def add_bench_arguments(p) -> None:
    p.add_argument("--out", default="bench.json", help="JSON file to write")
    number(p, "--steps", type=int, lo=1, default=2000, help="steps per measurement (default scene, mpm88)")
    p.add_argument("--dtype", default="float32", choices=("float32", "float64"), help="default scene, mpm88, grad")
    number(p, "--reps", type=int, lo=1, default=3, help="timed repetitions per measurement, the best kept")
    p.add_argument("--quick", action="store_true", help="tiny sizes and step counts (tests; not a benchmark)")
    p.add_argument(
        "--large", action="store_true", help="add 1e6 particles to the scaling runs (minutes per point on 2 cores)"
    )
    p.add_argument(
        "--only",
        default=",".join(bench.SECTIONS),
        help=f"comma-separated sections to run, of {', '.join(bench.SECTIONS)} (default: all)",
    )


def cmd_bench(args) -> int:
    return bench.run_bench(
        args.out,
        steps=args.steps,
        dtype=args.dtype,
        reps=args.reps,
        quick=args.quick,
        large=args.large,
        only=args.only,
    )


def add_stress_arguments(p) -> None:
    p.add_argument(
        "--size", default="ci", choices=("ci", "full"), help="ci: coarse, about a minute; full: the docs run"
    )
    p.add_argument("--case", action="append", choices=stress.CASE_NAMES, help="run only this case (repeatable)")
    p.add_argument("--out", default="stress.json", help="JSON file to write (rewritten after each case)")


def cmd_stress(args) -> int:
    """0 when every case passes, ``FAILED`` (3) when one fails a criterion.  At the thesis's
    kappa = 15 kPa, ``slope-30deg`` and ``drop-1m`` exceed the volume bound (too fast for that
    kappa), and at ``--size ci`` so do ``alpha-10`` and ``steps-100k`` (their deposit is under 2.2
    cells thick); docs/performance.md measures both, so a run of all cases exits 3."""
    recs = stress.run_stress(args.size, args.case, Path(args.out), _log)
    print(stress.format_table(recs))
    print(f"wrote {args.out}")
    failed = [r["case"] for r in recs if not r["passed"]]
    if failed:
        print(
            f"mpmjax stress: {len(failed)} of {len(recs)} case(s) failed a criterion: {', '.join(failed)} "
            "(docs/performance.md explains the known ones)",
            file=sys.stderr,
        )
        return FAILED
    return 0


def add_records_arguments(p) -> None:
    p.add_argument(
        "names", nargs="*", metavar="NAME", help=f"records to run (default all: {', '.join(records.RECORD_NAMES)})"
    )
    p.add_argument(
        "--size",
        default="full",
        help="full: each scene's default resolution (slow: the field scenes take minutes to hours); "
        "ci: coarse, short runs that check the pipeline (figures not comparable with the thesis)",
    )
    p.add_argument("--out", default="records", help="output directory (records.json, records.md, one folder per run)")


def cmd_records(args) -> int:
    if args.size not in records.SCALE_SIZES:
        raise UsageError(f"--size {args.size!r} is invalid: allowed ci, full")
    bad = [n for n in args.names if n not in records.RECORD_NAMES]
    if bad:
        raise UsageError(f"record {bad[0]!r} is invalid: allowed {', '.join(records.RECORD_NAMES)}")
    doc = records.run_records(args.names, args.size, Path(args.out), log=_log, progress=True)
    print(records.markdown(doc))
    return 0


def add_pareto_arguments(p) -> None:
    p.add_argument(
        "--size", choices=sorted(pareto.SIZES), default="ci", help="ci: tiny (seconds); full: the measurement"
    )
    p.add_argument("--out", default="pareto", help="output folder: writes OUT/bench/*.json and OUT/img/*.png")
    p.add_argument("--fresh", action="store_true", help="rerun every case (default: reuse finished runs in the JSON)")


def make_folders(out, subs=("bench", "img")) -> None:
    """Create ``out``/SUB for each of ``subs`` (a study's output folders; ``""``: ``out`` itself), or
    raise ``UsageError`` naming ``--out``."""
    for sub in subs:
        try:
            (Path(out) / sub).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UsageError(f"--out {out} is invalid: cannot create {Path(out) / sub}: {e}") from None


def cmd_pareto(args) -> int:
    make_folders(args.out)
    pareto.run_pareto(args.size, args.out, fresh=args.fresh)
    return 0


def add_study_arguments(p) -> None:
    p.add_argument("name", choices=("numerical", "physical", "stiff"))
    p.add_argument("--out", default="studies", help="output directory")
    p.add_argument(
        "--measure",
        action="append",
        choices=("standard", "thesis"),
        help="physical: the shear measure(s) to run (default both)",
    )


def cmd_study(args) -> int:
    if args.measure and args.name != "physical":
        raise UsageError(f"--measure {args.measure[0]} is invalid: only for study physical")
    options = {"measures": tuple(args.measure)} if args.name == "physical" and args.measure else {}
    return run_study(args.name, Path(args.out), **options)
