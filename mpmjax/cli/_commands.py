"""The command table: every ``mpmjax`` command with its help line, the function that adds its
options, its handler, and what its exit-status messages say (``_status``).  The one place that
lists the commands; each command's options stand next to its handler, in the module named here."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable

from . import _calibrate, _design, _rheometer, _run, _studies, _sweep, _validate
from ._guard import program_exit
from ._status import run_command


@dataclasses.dataclass(frozen=True)
class Command:
    """One ``mpmjax`` command.  ``invalid``: exception classes that count as invalid input (exit
    status 2) besides those of ``_status.STATUSES``; ``interrupted`` / ``failed``: the line printed
    on an interrupt (130, or 128 + the signal) / after a failed health check's message (3), saying
    what was kept, formatted with the parsed options (``{out}``); ``output`` / ``out_default``:
    how the shared hardening (``_guard``) vets and locks ``--out`` before the handler runs."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    handler: Callable[[argparse.Namespace], int]
    invalid: tuple[type[Exception], ...] = ()
    interrupted: str = "interrupted"
    failed: str = ""
    output: str = ""  # what --out names: "folder" (probed and locked) or "file" (probed); "": neither (_guard)
    out_default: str = ""  # the option whose value --out defaults to (sweep-merge: the parts' folder)


_KEPT = "interrupted: files already written in {out} are kept"
_RERUN = "interrupted: the {} finished so far remain in the JSON; rerun to continue"

COMMANDS = (
    Command(
        "scenes",
        "list the built-in scenes (or, with --keys, every scene key)",
        _run.add_scenes_arguments,
        _run.cmd_scenes,
    ),
    Command(
        "run",
        "run a scene and write result.h5, summary.json and result.png",
        _run.add_run_arguments,
        _run.cmd_run,
        interrupted="interrupted: frames written so far remain readable in {out}/result.h5",
        failed="frames before the failure remain readable in {out}/result.h5; summary.json has status 'failed'",
    ),
    Command(
        "rheometer",
        "0-D Coussot rheometer: viscosity vs time and flow curves",
        _rheometer.add_rheometer_arguments,
        _rheometer.cmd_rheometer,
        output="folder",
    ),
    Command(
        "bench",
        "measure particle-steps/s, scaling, gradient/forward time and vmap batching",
        _studies.add_bench_arguments,
        _studies.cmd_bench,
        invalid=(ValueError,),
        output="file",
    ),
    Command(
        "stress",
        "robustness cases (stiff, viscous, field scale, slope, drop, 100k steps)",
        _studies.add_stress_arguments,
        _studies.cmd_stress,
        invalid=(ValueError,),
        interrupted="interrupted: finished cases remain in {out}",
        output="file",
    ),
    Command(
        "records",
        "run the thesis's record scenes; our figures next to the thesis's (table)",
        _studies.add_records_arguments,
        _studies.cmd_records,
        invalid=(ValueError,),
        failed="the records measured before it are in {out}/records.md",
        output="folder",
    ),
    Command(
        "pareto",
        "error against run time of the lab dam break numerics (Pareto front)",
        _studies.add_pareto_arguments,
        _studies.cmd_pareto,
        interrupted="interrupted: the runs finished so far remain in the JSON",
        output="folder",
    ),
    Command(
        "converge",
        "convergence benchmark: runout against h, ppc, shape and anti-locking, with order and CPU time",
        _validate.add_converge_arguments,
        _validate.cmd_converge,
        interrupted=_RERUN.format("runs"),
        output="folder",
    ),
    Command(
        "validate",
        "validation suite: every case against its exact or experimental reference, error and CPU time",
        _validate.add_validate_arguments,
        _validate.cmd_validate,
        interrupted=_RERUN.format("cases"),
        output="folder",
    ),
    Command(
        "study",
        "thesis sensitivity tables and the stiff-viscosity comparison (slow)",
        _studies.add_study_arguments,
        _studies.cmd_study,
        invalid=(ValueError,),
        output="folder",
    ),
    Command(
        "calibrate",
        "fit material parameters to measured height profiles (optax, gradients)",
        _calibrate.add_calibrate_arguments,
        _calibrate.cmd_calibrate,
        invalid=(ValueError,),
        interrupted=_KEPT,
        output="folder",
    ),
    Command(
        "calibrate-coverage",
        "coverage study: fit N synthetic twins with the defaults; how often the intervals hold the truth",
        _calibrate.add_coverage_arguments,
        _calibrate.cmd_coverage,
        invalid=(ValueError,),
        interrupted=_KEPT,
        output="folder",
    ),
    Command(
        "design",
        "rank candidate measurements by the information they add (D-optimal)",
        _design.add_design_arguments,
        _design.cmd_design,
        invalid=(ValueError,),
        interrupted=_KEPT,
        output="folder",
    ),
    Command(
        "sweep",
        "run a grid of material (or basal friction) parameters as one vmap batch (runout, time to rest)",
        _sweep.add_sweep_arguments,
        _sweep.cmd_sweep,
        invalid=(ValueError,),
        interrupted=_KEPT,
        output="folder",
    ),
    Command(
        "sweep-merge",
        "join the parts of `mpmjax sweep --shard I/N` jobs into one sweep",
        _sweep.add_sweep_merge_arguments,
        _sweep.cmd_sweep_merge,
        invalid=(ValueError,),
        interrupted=_KEPT,
        output="folder",
        out_default="parts",
    ),
)


def make_parser() -> argparse.ArgumentParser:
    """The ``mpmjax`` parser: one subcommand per row of ``COMMANDS``, in their order."""
    p = argparse.ArgumentParser(
        prog="mpmjax", description="Differentiable MPM for thixotropic mine tailings (SI units)."
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    for command in COMMANDS:
        sp = sub.add_parser(command.name, help=command.help)
        command.add_arguments(sp)
        sp.set_defaults(command=command)
    return p


def main(argv=None) -> int:
    """``mpmjax ARGS``: parse, run the command's handler, return its exit status (``_status``).
    Without ``argv`` (the ``mpmjax`` program) an interrupted command ends the process itself and a
    signal the main thread cannot see in time is acted on by the watchdog (``_guard.program_exit``,
    ``_guard.Watchdog``); with ``argv`` (from Python) the status is returned."""
    program = argv is None
    args = make_parser().parse_args(argv)
    status = run_command(args.command, args, program=program)
    return program_exit(status) if program else status
