"""The files of a complete run besides result.h5: result.xdmf, summary.json, the pictures
(result.png; 3D: plan_view.h5, plan_view.png, sections.png; hazard maps; animation.gif), and the
closing lines on stderr (``finish``)."""

from __future__ import annotations

from pathlib import Path

from .. import _hazard, _metrics, _slump, plotting
from .._io import read_result
from .._xdmf import write_xdmf
from .loop import Run
from .progress import Progress
from .resume import CHECKPOINT_NAME, resume_command
from .signals import Interrupted, Signals, check
from .summary import complete_summary, status_summary, write_summary, write_summary_anyway

ANIMATION_MAX_FRAMES = 30  # images in animation.gif (evenly spaced over the saved frames)
ANIMATION_DPI = 60  # animation.gif resolution (an 8 x 3.2 in figure: 480 x 192 pixels)


def _write_animation(res, out: Path, dim: int, quiet: bool) -> Path:
    """animation.gif of a finished run: particles coloured by viscosity (log scale), side view
    in 2D, plan view in 3D; at most ANIMATION_MAX_FRAMES images; progress on stderr."""
    n = min(int(res["frames"]["t_s"].shape[0]), ANIMATION_MAX_FRAMES)
    prog = None if quiet else Progress(n, "animation")
    return plotting.animate(
        res,
        out / "animation.gif",
        "mu",
        view="plan" if dim == 3 else "side",
        dpi=ANIMATION_DPI,
        max_frames=ANIMATION_MAX_FRAMES,
        progress=None if prog is None else (lambda i, _n: prog.update(min(i + 1, n))),
    )


HAZARD_FILES = "hazard maps (hazard_profile.csv / hazard_*)"  # their names are known once written


def finish(run: Run, animate: bool, quiet: bool) -> dict:
    """After the last frame: write result.xdmf, the pictures (and the 3D plan-view maps, the
    hazard maps) and summary.json; returns the summary.

    Until every output is written the folder keeps a checkpoint of the final frame (so that
    ``mpmjax run --resume`` writes missing outputs without stepping a frame) and summary.json
    says ``writing outputs`` with ``outputs_missing``; status ``complete`` comes last.  A signal
    meanwhile (``Interrupted``; also one whose exception was dropped: ``_received``) stops the
    outputs: the one under way is removed, summary.json gets status ``interrupted``, ``complete``
    false and ``outputs_missing``, and the message says so (issue 35: it used to say ``complete``
    without the pictures)."""
    out, setup, cfg, state, advance, log = run.out, run.setup, run.cfg, run.state, run.advance, run.log
    sc = setup.scene
    hazard = isinstance(advance, _hazard.HazardAdvance)  # output.hazard_maps (mpmjax._hazard, docs/output.md)
    c: dict = {}  # what the steps compute for the later ones: summary, res (result.h5 read back), maps
    pv = out / "plan_view.h5"

    def measure():
        c["gauge"] = _metrics.RunoutGauge.of(sc, setup.info)
        c["summary"], c["closing_warnings"] = complete_summary(
            run.base_summary, setup, state, run.acc, advance.schedule, run.compile_s, c["gauge"]
        )
        c["res"] = read_result(out / "result.h5")
        c["maps"] = _hazard.final_maps(advance.maps, state, advance.grid) if hazard else None
        if cfg["output.slump_test"]:  # slump height, spread and Pashias yield stress: mpmjax._slump, docs/slump-test.md
            c["summary"]["slump_test"] = _slump.summary(c["res"])

    def write_hazard():
        c["summary"]["hazard"] = _hazard.write_hazard(out, cfg, advance.grid, c["maps"])
        return c["summary"]["hazard"]["files"]

    steps = [([], measure), (["result.xdmf"], lambda: write_xdmf(out / "result.h5"))]  # xdmf: ParaView / VisIt
    if sc.dim == 3:
        # lobe width, plan-view maps (plan_view.h5) and the channel metric: mpmjax._metrics, docs/output.md
        steps.append((["plan_view.h5"], lambda: c["summary"].update(
            _metrics.plan_view_summary(c["res"], pv, plan=sc if sc.formulation == "depth-averaged" else None)
        )))
    if hazard:
        steps.append(([HAZARD_FILES], write_hazard))
    steps.append((["summary.json"], lambda: _write_progress(out, c["summary"], steps, at["step"])))
    png = out / "result.png"
    steps.append((["result.png"], lambda: plotting.plot_result(png, c["res"], c["summary"], cfg["name"])))
    if hazard:
        hpng = out / "hazard_maps.png"
        steps.append(
            (["hazard_maps.png"], lambda: plotting.plot_hazard_maps(hpng, cfg, advance.grid, c["maps"], c["summary"]))
        )
    if sc.dim == 3:
        steps.append(
            (["plan_view.png", "sections.png"], lambda: plotting.plot_3d_overview(c["res"], pv, c["summary"], out))
        )
    if animate:
        steps.append((["animation.gif"], lambda: _write_animation(c["res"], out, sc.dim, quiet)))

    sig = Signals()  # SIGINT / SIGTERM raise Interrupted, held while a checkpoint or summary.json is written
    written = ["result.h5"]
    at = {"step": 0}
    try:
        with sig.hold():
            run.checkpoints.write(state, run.done, run.acc, advance)  # --resume writes the outputs from here
        for i, (files, write) in enumerate(steps):
            at["step"] = i
            check()  # a signal whose exception was dropped (mpmjax._received)
            got = write()
            written += got if files == [HAZARD_FILES] else [f for f in files if f not in written]
        at["step"] = len(steps)
        check()
        with sig.hold():
            write_summary(out / "summary.json", c["summary"])  # status complete: every output is there
            (out / CHECKPOINT_NAME).unlink(missing_ok=True)  # complete: nothing left to resume
    except (Exception, KeyboardInterrupt) as e:
        ki = _interrupt_in(e)
        if ki is None:
            raise
        raise _outputs_interrupted(run, sig, getattr(ki, "signum", 2), steps, at["step"]) from None
    finally:
        sig.restore()
    summary = c["summary"]
    log(f"wrote {', '.join(str(out / f) for f in written)}")
    _log_closing(log, summary, sc, c["gauge"], c["closing_warnings"])
    return summary


def _interrupt_in(e: BaseException) -> KeyboardInterrupt | None:
    """The interrupt behind ``e``: itself, or one that was being handled when ``e`` was raised (a
    writer's cleanup that fails on the half-made file: matplotlib's GIF writer raises IndexError
    from its ``finish`` when Ctrl-C cut the first image short)."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def _write_progress(out: Path, summary: dict, steps: list, now: int) -> None:
    """summary.json while the pictures are written: the complete run's metrics, status ``writing
    outputs``, ``complete`` false and the outputs still to come (what a killed process leaves)."""
    later = [f for files, _ in steps[now + 1 :] for f in files]
    write_summary(out / "summary.json", dict(summary, status="writing outputs", outputs_missing=later, complete=False))


def _outputs_interrupted(run: Run, sig, signum: int, steps: list, now: int) -> Interrupted:
    """A signal while the outputs were written: the half-written one removed (and later ones left
    by an earlier run into this folder), summary.json ``interrupted`` with ``outputs_missing``; the
    checkpoint of the final frame is kept for ``--resume``."""
    out = run.out
    sig.depth += 1  # a second signal while summary.json is written is only recorded
    missing = [f for files, _ in steps[now:] for f in files if f != "summary.json"]
    for f in missing:
        if f != HAZARD_FILES:
            (out / f).unlink(missing_ok=True)  # half written, or an earlier run's: not this run's
    resume = resume_command(out)
    what = ", ".join(missing) + (" and summary.json's metrics" if now == 0 else "")
    reason = (
        f"interrupted while the outputs were written: the run is complete in {out / 'result.h5'}, but {what} "
        f"{'is' if len(missing) == 1 and now else 'are'} missing; write them with: {resume}"
    )
    doc = status_summary(
        run.base_summary,
        "interrupted",
        error=reason,
        outputs_missing=missing,
        frames_written=run.done,
        times_s=run.acc["times"],
        runout_m=run.acc["fronts"],
    )
    wrote = write_summary_anyway(out / "summary.json", doc)
    return Interrupted(signum, reason + ("" if wrote else "; summary.json could not be written"))


def _log_closing(log, summary: dict, sc, gauge, closing_warnings: list) -> None:
    """The closing lines on stderr: 3D channels, the warnings of the run's end, a wall-capped runout, the runout."""
    if sc.dim == 3:
        ch = summary["channels"]
        log(
            f"lobe width {summary['lobe_width_m']} m (thickness > {summary['lobe_width_threshold_m']:g} m); "
            f"channels: {'yes, from t = ' + format(ch['first_time_s'], 'g') + ' s' if ch['detected'] else 'no'}"
        )
    if "slump_test" in summary:
        st = summary["slump_test"]
        back = st["yield_stress_back_calculated_pa"]
        log(
            f"slump test: slump {1e3 * st['slump_m']:.1f} mm of {1e3 * st['initial_height_m']:.1f} mm, spread "
            f"{1e3 * st['spread_diameter_m']:.1f} mm; yield stress back-calculated (Pashias) "
            + (f"{back:.4g} Pa" if back is not None else "n/a")
            + (f", input {st['yield_stress_input_pa']:.4g} Pa" if st["yield_stress_input_pa"] is not None else "")
        )
    for w in closing_warnings:
        log(f"warning: {w}")
    if summary["runout_capped_by_wall"]:
        log(
            f"note: the material reached the domain wall at {sc.hi[gauge.axis]:g} m along axis {gauge.axis}: "
            "the runout is capped by the wall, not set by the material (runout_capped_by_wall in summary.json)"
        )
    log(
        f"final runout {summary['final_runout_m']:.3f} m at t = {sc.t_end:g} s "
        f"(farthest particle {summary['final_runout_farthest_particle_m']:.3f} m); wall {summary['wall_s']:.1f} s "
        f"({summary['particle_steps_per_s']:.3g} particle-steps/s); lost particles: {summary['n_lost']}"
    )
