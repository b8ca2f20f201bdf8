"""The frame loop of a run: the per-frame series (``Measures``), the run being stepped (``Run``)
and ``run_frames``, which steps, checks health, appends each frame to result.h5, checkpoints and
reports progress, and on an interrupt, a failed health check or a failed write closes the files
and writes the matching summary.json."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from .. import _health, _metrics
from .._io import FrameWriter, _jsonable
from .._schema import SceneError
from .._version import __version__
from .progress import Progress
from .resume import Checkpointer, resume_command
from .signals import Interrupted, Signals
from .status import OutputFailure, os_reason
from .summary import status_summary, write_summary, write_summary_anyway


class Measures:
    """The series kept per frame: runout front, farthest particle, kinetic energy."""

    def __init__(self, setup):
        self.rho = float(setup.params.material.rho)
        self.gauge = _metrics.RunoutGauge.of(setup.scene, setup.info)

    def front(self, st):
        # no active material yet (a pipe inflow before its start): both fronts are at the origin
        return self.gauge.front(st.x, st.vol0, st.active)

    def farthest(self, st):
        return self.gauge.farthest(st.x, st.active)

    def energy(self, st):
        return float(_metrics.kinetic_energy(np.asarray(st.v), np.asarray(st.vol0), np.asarray(st.active), self.rho))

    def first(self, state) -> dict:
        """The series of a new run (frame 0) and its counters."""
        return dict(
            times=[0.0],
            fronts=[self.front(state)],
            farthest=[self.farthest(state)],
            kinetic=[self.energy(state)],
            lost_reported=0,
            n_outflow=0,
            wall_s=0.0,
            mass0=float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * self.rho,
        )


@dataclass
class Run:
    """A run being stepped: where it writes, what it steps, and how far it got."""

    out: Path
    setup: object
    cfg: dict
    advance: object
    state: object
    done: int  # frames on disk
    acc: dict  # the series and counters (Measures.first), kept in the checkpoint
    measures: Measures
    checkpoints: Checkpointer
    base_summary: dict
    compile_s: float
    checkpoint_every: int
    log: object
    resumed: bool
    writer: FrameWriter | None = None


def run_frames(run: Run, sig: Signals, quiet: bool, on_frame) -> None:
    """Step the frames from ``run.done`` to the end; result.h5 is closed complete, or, on an
    interrupt, a failed health check or a failed write, closed with that status and summary.json
    says so (``Interrupted``, ``_health.RunFailure``, ``OutputFailure``).  Restores the signals."""
    sc = run.setup.scene
    start = run.done  # progress and its time estimate count this session's frames
    prog = None if quiet else Progress(sc.n_frames - start, "run" if not start else f"run (from frame {start})")
    t_run = time.perf_counter()
    wall0 = run.acc["wall_s"]
    try:
        try:
            with sig.hold():
                _open_result(run)
                # a summary.json from the start, so that a failure after the folder became unwritable can
                # still rewrite it in place (write_summary_anyway)
                write_summary_anyway(run.out / "summary.json", status_summary(run.base_summary, "running"))
            for i in range(run.done, sc.n_frames):
                _step_frame(run, i, sig, wall0, t_run)
                if prog:
                    t, front = float(run.state.t), run.acc["fronts"][-1]
                    prog.update(run.done - start, f"t = {t:7.3f} s, runout {front:.3f} m,")
                if on_frame is not None:
                    on_frame(run.done, run.state)
        except KeyboardInterrupt as e:
            raise _interrupted(run, sig, getattr(e, "signum", 2)) from None
        except _health.RunFailure as e:
            _health_failed(run, sig, e)
            raise
        except OSError as e:
            raise _output_failed(run, sig, e) from None
        except BaseException:
            if run.writer is not None:
                run.writer.close(False, status="interrupted")
            raise
        with sig.hold():
            run.writer.close(True, status="complete")
    finally:
        sig.restore()


def _open_result(run: Run) -> None:
    """``run.writer``: a new result.h5 with frame 0, or a resumed run's cut back to its checkpoint frame."""
    out, setup = run.out, run.setup
    if not run.resumed:
        run.writer = FrameWriter(out / "result.h5", setup, __version__)
        run.writer.append(run.state)
        return
    try:
        run.writer = FrameWriter(out / "result.h5", setup, __version__, keep_frames=run.done + 1)
    except (OSError, KeyError, ValueError) as e:
        raise SceneError(f"--resume {out}: {out / 'result.h5'} cannot be continued: {e}") from None


def _step_frame(run: Run, i: int, sig: Signals, wall0: float, t_run: float) -> None:
    """Frame ``i`` -> ``i + 1``: step, check health, append to result.h5 and the series (with
    signals held), checkpoint every ``checkpoint_every`` frames, note particles lost."""
    setup, cfg, acc, m = run.setup, run.cfg, run.acc, run.measures
    sc, state = setup.scene, run.state
    new = run.advance(i, state, setup.params)
    jax.block_until_ready(new.x)
    probs, outflow = _health.check(sc, cfg, state, new)
    if probs:
        raise _health.failure(sc, setup.params, cfg, state, new, probs, i + 1, log=run.log)
    with sig.hold():
        run.writer.append(new)
        run.state, run.done = state, done = new, i + 1
        acc["times"].append(done * sc.steps_per_frame * sc.dt)
        acc["fronts"].append(m.front(state))
        acc["farthest"].append(m.farthest(state))
        acc["kinetic"].append(m.energy(state))
        acc["n_outflow"] += int(len(outflow))
        acc["wall_s"] = wall0 + time.perf_counter() - t_run
        if run.checkpoint_every and done % run.checkpoint_every == 0 and done < sc.n_frames:
            run.checkpoints.write(state, done, acc, run.advance)
    lost = int(state.n_lost)
    if lost > acc["lost_reported"]:
        run.log(
            f"\nnote: {lost - acc['lost_reported']} particle(s) left the domain through an open face by "
            f"t = {float(state.t):.3f} s (frame {done}); they were deactivated and are counted in "
            "summary.json n_lost"
        )
        acc["lost_reported"] = lost


def _interrupted(run: Run, sig: Signals, signum: int) -> Interrupted:
    """SIGINT/SIGTERM during the frames: checkpoint the state, close result.h5 as interrupted,
    summary.json says how to resume."""
    out, sc, done, state = run.out, run.setup.scene, run.done, run.state
    sig.depth += 1  # a second Ctrl-C while the files are closed is only recorded
    if run.writer is not None and done > run.checkpoints.last:
        run.checkpoints.write(state, done, run.acc, run.advance)
    if run.writer is not None:
        run.writer.close(False, status="interrupted")
    msg = (
        f"interrupted at frame {done}/{sc.n_frames} (t = {float(state.t):.4g} s): frames 0..{done} remain "
        f"readable in {out / 'result.h5'}; the state is saved in {run.checkpoints.path}. Resume with: "
        f"{resume_command(out)}"
    )
    write_summary(
        out / "summary.json", status_summary(run.base_summary, "interrupted", frames_written=done, message=msg)
    )
    return Interrupted(signum, msg)


def _health_failed(run: Run, sig: Signals, e: _health.RunFailure) -> None:
    """A failed health check: result.h5 closed as failed, summary.json with the failure."""
    sig.depth += 1
    run.writer.close(False, status="failed", error=str(e))
    doc = status_summary(
        run.base_summary,
        "failed",
        error=str(e),
        failure=e.info,
        frames_written=run.done,
        times_s=run.acc["times"],
        runout_m=run.acc["fronts"],
    )
    write_summary(run.out / "summary.json", _jsonable(doc))


def _output_failed(run: Run, sig: Signals, e: OSError) -> OutputFailure:
    """Writing failed (the folder became unwritable, the disk is full): result.h5 is marked failed
    where it can still be written, and summary.json gets what was written."""
    out, sc, done, w = run.out, run.setup.scene, run.done, run.writer
    sig.depth += 1
    reason = (
        f"writing the output in {out} failed after frame {done}/{sc.n_frames} "
        f"(t = {float(run.state.t):.4g} s): {os_reason(e)}"
    )
    marked = False
    if w is not None:
        with contextlib.suppress(Exception):
            w.close(False, status="failed", error=reason)
            marked = True
    doc = status_summary(
        run.base_summary,
        "failed",
        error=reason,
        failure={"kind": "output", "message": reason, "frame": done},
        frames_written=done if w is not None else 0,
        times_s=run.acc["times"],
        runout_m=run.acc["fronts"],
    )
    wrote = write_summary_anyway(out / "summary.json", doc)
    kept = (
        f"frames 0..{done} remain readable in {out / 'result.h5'}"
        + (" (status 'failed')" if marked else " (its status could not be set)")
        if w is not None
        else "no frame was written"
    )
    last = run.checkpoints.last
    resume = (
        f"; after fixing the folder, resume from the checkpoint at frame {last}: {resume_command(out)}"
        if last >= 0 and run.checkpoints.path.is_file()
        else ""
    )
    return OutputFailure(
        f"{reason}. {kept}; summary.json " + ("has status 'failed'" if wrote else "could not be written") + resume
    )
