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
from .resume import CHECKPOINT_NAME
from .summary import complete_summary, write_summary

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


def finish(run: Run, animate: bool, quiet: bool) -> dict:
    """After the last frame: delete the checkpoint, write result.xdmf, summary.json, the pictures
    (and the 3D plan-view maps); returns the summary."""
    out, setup, cfg, state, advance, log = run.out, run.setup, run.cfg, run.state, run.advance, run.log
    sc = setup.scene
    gauge = _metrics.RunoutGauge.of(sc, setup.info)
    (out / CHECKPOINT_NAME).unlink(missing_ok=True)  # complete: nothing left to resume
    write_xdmf(out / "result.h5")  # result.xdmf: ParaView / VisIt sidecar of the closed result.h5
    summary, deposit_warning = complete_summary(
        run.base_summary, setup, state, run.acc, advance.schedule, run.compile_s, gauge
    )
    res = read_result(out / "result.h5")
    written = ["result.h5", "result.xdmf", "summary.json", "result.png"]
    hazard = None
    if isinstance(advance, _hazard.HazardAdvance):  # output.hazard_maps (mpmjax._hazard, docs/output.md)
        hazard = _hazard.final_maps(advance.maps, state, advance.grid)
        summary["hazard"] = _hazard.write_hazard(out, cfg, advance.grid, hazard)
        written += summary["hazard"]["files"] + ["hazard_maps.png"]
    if sc.dim == 3:
        # lobe width, plan-view maps (plan_view.h5) and the channel metric: mpmjax._metrics, docs/output.md
        summary.update(_metrics.plan_view_summary(res, out / "plan_view.h5"))
        written.insert(3, "plan_view.h5")
    if cfg["output.slump_test"]:  # slump height, spread and Pashias yield stress: mpmjax._slump, docs/slump-test.md
        summary["slump_test"] = _slump.summary(res)
    write_summary(out / "summary.json", summary)
    plotting.plot_result(out / "result.png", res, summary, cfg["name"])
    if hazard is not None:
        plotting.plot_hazard_maps(out / "hazard_maps.png", cfg, advance.grid, hazard, summary)
    if sc.dim == 3:
        plotting.plot_3d_overview(res, out / "plan_view.h5", summary, out)
        written += ["plan_view.png", "sections.png"]
    if animate:
        _write_animation(res, out, sc.dim, quiet)
        written.append("animation.gif")
    log(f"wrote {', '.join(str(out / f) for f in written)}")
    _log_closing(log, summary, sc, gauge, deposit_warning)
    return summary


def _log_closing(log, summary: dict, sc, gauge, deposit_warning: str | None) -> None:
    """The closing lines on stderr: 3D channels, the deposit warning, a wall-capped runout, the runout."""
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
    if deposit_warning is not None:
        log(f"warning: {deposit_warning}")
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
