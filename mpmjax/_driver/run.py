"""``run_scene``: a run from the scene to its files, in order: vet the output folder, read the
checkpoint of a resumed run, load and check the scene, refuse a run that cannot fit, build,
lock the folder, compile, step the frames (``loop``), write the outputs (``outputs``)."""

from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

from .._build import build, start_warnings
from .._io import config_hash
from .._received import scope
from .._schema import load_scene
from .._shard import use_devices
from .advance import compile_advance, make_advance
from .folder import OutputLock, check_output_folder, make_output_folder
from .loop import Measures, Run, run_frames
from .memory import check_memory
from .outputs import finish
from .resume import (
    CHECKPOINT_EVERY,
    CHECKPOINT_NAME,
    Checkpointer,
    check_checkpoint,
    check_same_scene,
    read_for_resume,
    restore,
    resume_command,
)
from .signals import Interrupted, Signals, check
from .status import OutputFailure, os_reason
from .summary import base_summary, status_summary, write_summary_anyway


def run_scene(
    scene: str | None,
    out: Path,
    overrides: list[str] | None,
    quiet: bool = False,
    checkpoint_every: int = CHECKPOINT_EVERY,
    resume: bool = False,
    on_frame=None,
    animate: bool = False,
    staged: bool = True,
) -> dict:
    """Run a scene frame by frame, writing result.h5, summary.json and result.png to ``out``
    (3D scenes also plan_view.h5, plan_view.png and sections.png; with ``animate=True``
    animation.gif: ``mpmjax run`` does that by default, the Python default is False).

    Every ``checkpoint_every`` frames (0: never) the full state is written to
    ``out/checkpoint.h5`` (atomically), and again when the run is interrupted.  With
    ``resume=True`` the run continues from that checkpoint: ``result.h5`` is cut back to the
    checkpoint frame and continued, and the results equal those of an uninterrupted run bit
    for bit.  ``scene``/``overrides`` may then be ``None`` (taken from the checkpoint); if
    given they must describe the same validated scene.

    After each frame the state is checked (``mpmjax._health``); a failed check closes the
    files (frames written so far stay readable; summary.json gets ``status: failed``) and
    raises ``RunFailure`` naming the step, the time, the particle and the likely cause.
    ``on_frame(frame, state)``, if given, is called after each frame is on disk.
    ``staged=False`` steps the whole particle buffer in every frame (with a pipe inflow the
    default steps only the released part; the results agree to float rounding, and a resumed
    staged run is bit for bit the uninterrupted one).

    Returns the summary dict.  Raises ``SceneError`` on invalid input (including a
    checkpoint that does not match the scene) and ``Interrupted`` (a ``KeyboardInterrupt``)
    on SIGINT/SIGTERM after closing the files and writing the checkpoint.

    The folder is locked for the whole run (``OutputLock``): a second run into it raises
    ``OutputBusy`` (a ``SceneError``) before it creates or truncates anything.
    """
    lock = OutputLock(Path(out))
    try:
        with scope():  # a signal noted in this run does not stop the next one in this process
            return _run_scene(scene, out, overrides, quiet, checkpoint_every, resume, on_frame, animate, staged, lock)
    finally:
        lock.release()


def _run_scene(scene, out, overrides, quiet, checkpoint_every, resume, on_frame, animate, staged, lock) -> dict:
    """``run_scene`` with the folder's ``lock`` (released by the caller)."""
    out = Path(out)
    try:
        ckpt, scene, overrides, source, cfg, chash, setup = _load(scene, out, overrides, resume, lock)
    except KeyboardInterrupt as e:
        # before the driver's own handler (the scene loaded and built, nothing written): say so
        note = f"interrupted before the run started: nothing in {out} was written or changed"
        raise Interrupted(getattr(e, "signum", signal.SIGINT), note) from None
    log = (lambda *a: None) if quiet else (lambda *a: print(*a, file=sys.stderr))
    sig = Signals()  # from here Ctrl-C / SIGTERM raise Interrupted (while compiling: once the compiler returns)
    try:
        check()  # one dropped between the check above and the handler
        run = _prepare(out, setup, cfg, ckpt, chash, source, overrides, staged, checkpoint_every, log)
    except KeyboardInterrupt as e:
        sig.restore()
        kept = (
            f"the checkpoint in {out / CHECKPOINT_NAME} is unchanged; resume with: {resume_command(out)}"
            if ckpt is not None
            else f"no result in {out} was written or changed"
        )
        raise Interrupted(getattr(e, "signum", signal.SIGINT), f"interrupted while compiling: {kept}") from None
    except BaseException:
        sig.restore()
        raise
    run_frames(run, sig, quiet, on_frame)
    try:
        return finish(run, animate, quiet)
    except OSError as e:
        reason = f"the run is complete in {out / 'result.h5'}, but writing its other outputs failed: {os_reason(e)}"
        doc = status_summary(run.base_summary, "complete", complete=True, error=reason)
        wrote = write_summary_anyway(out / "summary.json", doc)
        said = "has the run facts and this message" if wrote else "could not be written"
        raise OutputFailure(f"{reason}; summary.json {said}") from None


def _load(scene, out: Path, overrides, resume: bool, lock) -> tuple:
    """Vet the folder, read a resumed run's checkpoint, load, check and build the scene, then create
    and lock the folder: ``(checkpoint, scene, overrides, source, cfg, config hash, setup)``."""
    ckpt = None
    check_output_folder(out)  # an existing file, an uncreatable or unwritable folder: exit 2, before building
    if resume:
        ckpt = read_for_resume(out, lock)
        meta = ckpt[3]
        if scene is None:
            scene, overrides = meta["scene_source"], meta["overrides"]
        overrides = overrides or []
    if scene is None:
        scene = "dambreak-lab"
    overrides = list(overrides or [])
    source = str(Path(scene).resolve()) if Path(scene).is_file() else str(scene)
    cfg = load_scene(scene, overrides)
    chash = config_hash(cfg)
    if ckpt is not None:
        check_same_scene(out, ckpt, cfg, chash, source, overrides)
    use_devices(cfg["numerics.devices"])  # first: on a CPU, host devices can be made only before JAX starts
    check_memory(cfg)  # before anything is built: a run that cannot fit is refused (exit 2)
    setup = build(cfg)
    if ckpt is not None:
        check_checkpoint(out, ckpt, setup)  # its frame and array shapes, before the state is used
    # a signal whose exception was dropped while the scene was built (a jax gc callback drops it:
    # mpmjax._received): stop before the folder is touched
    check(f"interrupted before the run started: nothing in {out} was written or changed")
    make_output_folder(out)
    lock.acquire()  # before anything in the folder is created or truncated
    return ckpt, scene, overrides, source, cfg, chash, setup


def _prepare(out, setup, cfg, ckpt, chash, source, overrides, staged, checkpoint_every, log) -> Run:
    """Log the scene and its warnings, compile the frame advance, and set up the run from frame 0
    or from the checkpoint ``ckpt``."""
    sc, info = setup.scene, setup.info
    log(
        f"scene {cfg['name']}: {sc.dim}D, {sc.n_particles} particles, grid {sc.grid_shape}, h = {sc.h} m, "
        f"dt = {sc.dt:.3g} s (wave limit {info['dt_wave_s']:.3g} s, viscous limit {info['dt_viscous_s']:.3g} s, "
        f"{sc.viscous_update} viscous update), {sc.n_steps} steps to t = {sc.t_end:g} s"
    )
    # thin bodies, a time step forced far below its limit, runs of > 1e6 steps (issue 17 item 5);
    # kept in summary.json "warnings" (the final deposit's resolution is added at the end)
    warnings = start_warnings(setup)
    for wtext in warnings:
        log(f"warning: {wtext}")
    t0 = time.perf_counter()
    advance = make_advance(setup, cfg, staged)
    sizes = compile_advance(advance, int(ckpt[1]) if ckpt is not None else 0)
    compile_s = time.perf_counter() - t0
    what = "column splitting's spare slots staged" if getattr(advance, "split_sizes", ()) else "pipe pool staged"
    staged_note = (
        f" ({what}: frames step the first {', '.join(map(str, sizes))} of {sc.n_particles} particles)"
        if sizes and sizes != [sc.n_particles]  # none: resumed at the last frame, to write the outputs
        else ""
    )
    log(f"compiled in {compile_s:.1f} s{staged_note}")
    measures = Measures(setup)
    if ckpt is None:
        state, done, acc = setup.state, 0, measures.first(setup.state)
        (out / CHECKPOINT_NAME).unlink(missing_ok=True)  # a stale checkpoint of an earlier run here
    else:
        state, done, acc = restore(ckpt, out, advance, sc.n_frames, log)
    checkpoints = Checkpointer(
        out / CHECKPOINT_NAME, chash, source, overrides, cfg, last=done if ckpt is not None else -1
    )
    return Run(
        out=out,
        setup=setup,
        cfg=cfg,
        advance=advance,
        state=state,
        done=done,
        acc=acc,
        measures=measures,
        checkpoints=checkpoints,
        base_summary=base_summary(cfg, source, overrides, setup, warnings),
        compile_s=compile_s,
        checkpoint_every=checkpoint_every,
        log=log,
        resumed=ckpt is not None,
    )
