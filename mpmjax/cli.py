"""Command line: ``mpmjax scenes | run | rheometer | bench | study | calibrate | sweep``.

Exit status: 0 success, 2 invalid input (the message names the key, the value and the
allowed range), 130 interrupted (frames already written stay readable), 1 other errors.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

USAGE_ERROR = 2


class Progress:
    """A one-line progress report with elapsed time and an estimate of the time left."""

    def __init__(self, total: int, label: str, stream=sys.stderr):
        self.total, self.label, self.stream = total, label, stream
        self.t0 = time.perf_counter()
        self.tty = stream.isatty()
        self.last_pct = -1

    def update(self, done: int, extra: str = ""):
        el = time.perf_counter() - self.t0
        eta = el / done * (self.total - done) if done else float("nan")
        pct = int(100 * done / self.total)
        bar = "#" * (pct // 5) + "." * (20 - pct // 5)
        line = f"{self.label} [{bar}] {pct:3d}% {done}/{self.total} {extra} elapsed {el:6.1f} s, left ~{eta:6.1f} s"
        if self.tty:
            self.stream.write("\r" + line + ("\n" if done == self.total else ""))
            self.stream.flush()
        elif pct // 10 != self.last_pct // 10 or done == self.total:
            self.stream.write(line + "\n")
            self.stream.flush()
        self.last_pct = pct


def _fail(msg: str) -> int:
    print(f"mpmjax: error: {msg}", file=sys.stderr)
    return USAGE_ERROR


def cmd_scenes(args) -> int:
    from ._config import SCHEMA, builtin_scenes

    if args.keys:
        for key, spec in SCHEMA.items():
            default = "(required)" if spec.default is not None and spec.default.__class__ is object else spec.default
            rng = ""
            if spec.choices:
                rng = "one of " + ", ".join(map(str, spec.choices))
            elif spec.lo is not None or spec.hi is not None:
                rng = f"{'>' if spec.lo_open else '>='} {spec.lo}" if spec.lo is not None else ""
                rng += f"{', ' if rng else ''}<= {spec.hi}" if spec.hi is not None else ""
            print(f"{key:38s} [{spec.unit}] default={default!r} {rng}\n    {spec.doc}")
        return 0
    import tomllib

    for name, path in sorted(builtin_scenes().items()):
        desc = tomllib.loads(path.read_text()).get("description", "").split(". ")[0]
        print(f"{name:24s} {desc}")
    return 0


def _scenario_metrics(setup, state, times, kinetic) -> dict:
    """summary.json scenario metrics (definitions in docs/output.md and mpmjax._metrics):
    kinetic energy per frame, time to rest (1 % of the peak kinetic energy), mobilised
    fraction (share of the final material displaced by more than one cell size h from where
    it started or was released), the final free-surface profile along the runout axis (bins of
    width h over the domain; null where empty) and its beach slope."""
    import numpy as np

    from . import _metrics

    sc, info = setup.scene, setup.info
    axis = info["runout_axis"]
    # inflow pool particles are parked where they are released (half a layer behind the exit)
    moved_from = np.asarray(setup.state.x)
    x, act = np.asarray(state.x), np.asarray(state.active)
    edges = np.arange(sc.lo[axis], sc.hi[axis] + 0.5 * sc.h, sc.h)
    xc, top = _metrics.surface_profile(x, act, edges, info["particle_spacing_m"], axis=axis)
    slope = _metrics.beach_slope(xc, top, bed=sc.lo[-1], min_depth_m=info["particle_spacing_m"])

    def fin(a):
        return float(a) if np.isfinite(a) else None

    return {
        "kinetic_energy_J": kinetic,
        "kinetic_energy_unit": "J per metre of depth" if sc.dim == 2 else "J",
        "time_to_rest_s": fin(_metrics.time_to_rest(times, kinetic, rel_threshold=0.01)),
        "mobilised_fraction": fin(_metrics.mobilised_fraction(moved_from, x, act, sc.h, vol0=np.asarray(state.vol0))),
        "mobilised_distance_m": sc.h,
        "surface_profile_x_m": [float(a) for a in xc],
        "surface_profile_z_m": [fin(a) for a in top],
        "beach_slope": fin(slope),
    }


def run_scene(scene: str, out: Path, overrides: list[str], quiet: bool = False) -> dict:
    """Run a scene frame by frame, writing result.h5, summary.json and result.png to ``out``.

    Returns the summary dict.  Raises ``SceneError`` on invalid input and re-raises
    ``KeyboardInterrupt`` after closing the files (frames written so far stay readable).
    """
    import jax
    import numpy as np

    from . import __version__, _metrics
    from ._config import build, load_scene
    from ._io import FrameWriter, atomic_write_text, plot_result, read_result
    from ._observables import runout
    from ._simulate import make_advance
    from ._xdmf import write_xdmf

    cfg = load_scene(scene, overrides)
    setup = build(cfg)
    sc, info = setup.scene, setup.info
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda *a: None) if quiet else (lambda *a: print(*a, file=sys.stderr))
    log(
        f"scene {cfg['name']}: {sc.dim}D, {sc.n_particles} particles, grid {sc.grid_shape}, h = {sc.h} m, "
        f"dt = {sc.dt:.3g} s (wave limit {info['dt_wave_s']:.3g} s, viscous limit {info['dt_viscous_s']:.3g} s, "
        f"{sc.viscous_update} viscous update), {sc.n_steps} steps to t = {sc.t_end:g} s"
    )
    t0 = time.perf_counter()
    advance = make_advance(sc).lower(setup.state, setup.params).compile()
    compile_s = time.perf_counter() - t0
    log(f"compiled in {compile_s:.1f} s")
    rho = float(setup.params.material.rho)
    spacing, axis, origin = info["particle_spacing_m"], info["runout_axis"], info["runout_origin_m"]

    def front(st):
        # no active material yet (a pipe inflow before its start): the front is at the origin
        return float(runout(st.x, st.active, axis, origin, spacing)) if bool(np.any(st.active)) else 0.0

    def energy(st):
        return float(_metrics.kinetic_energy(np.asarray(st.v), np.asarray(st.vol0), np.asarray(st.active), rho))

    state = setup.state
    mass0 = float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * rho
    times, fronts = [0.0], [front(state)]
    kinetic = [energy(state)]
    prog = None if quiet else Progress(sc.n_frames, "run")
    complete = False
    t_run = time.perf_counter()
    with FrameWriter(out / "result.h5", setup, __version__) as w:
        w.append(state)
        lost_reported = 0
        for i in range(sc.n_frames):
            state = advance(state, setup.params)
            jax.block_until_ready(state.x)
            w.append(state)
            times.append((i + 1) * sc.steps_per_frame * sc.dt)
            fronts.append(front(state))
            kinetic.append(energy(state))
            lost = int(state.n_lost)
            if lost > lost_reported:
                log(
                    f"\nwarning: {lost - lost_reported} particle(s) left the grid or became non-finite by "
                    f"t = {float(state.t):.3f} s (frame {i + 1}); they were deactivated and are counted in "
                    "summary.json n_lost"
                )
                lost_reported = lost
            if prog:
                prog.update(i + 1, f"t = {float(state.t):7.3f} s, runout {fronts[-1]:.3f} m,")
        complete = True
    wall = time.perf_counter() - t_run
    write_xdmf(out / "result.h5")  # result.xdmf: ParaView / VisIt sidecar of the closed result.h5
    mass1 = float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * rho
    summary = {
        "scene": cfg["name"],
        "dim": sc.dim,
        "n_particles": sc.n_particles,
        "n_steps": sc.n_steps,
        "dt_s": sc.dt,
        "t_end_s": sc.t_end,
        "wall_s": wall,
        "compile_s": compile_s,
        "particle_steps_per_s": sc.n_particles * sc.n_steps / wall,
        "mass_initial_kg": mass0,
        "mass_final_kg": mass1,
        "mass_unit": "kg per metre of depth" if sc.dim == 2 else "kg",
        "n_lost": int(state.n_lost),
        "times_s": times,
        "runout_m": fronts,
        "final_runout_m": fronts[-1],
        **_scenario_metrics(setup, state, times, kinetic),
        "runout_definition": (
            f"max over active particles of x[{axis}] + half the initial particle spacing ({spacing / 2:g} m), "
            f"minus runout_origin_m = {origin:g} m"
        ),
        "dt_limits": {
            k: info[k]
            for k in (
                "dt_wave_s",
                "dt_viscous_s",
                "dt_limit_s",
                "wave_speed_m_s",
                "velocity_scale_m_s",
                "maxwell_G_pa",
                "mu_max_pa_s",
            )
        },
        "grid_shape": list(sc.grid_shape),
        "cell_size_m": sc.h,
        "code_version": __version__,
        "jax_backend": jax.default_backend(),
        "complete": complete,
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    res = read_result(out / "result.h5")
    plot_result(out / "result.png", res["frames"], summary, cfg["name"])
    log(f"wrote {out / 'result.h5'}, {out / 'result.xdmf'}, {out / 'summary.json'}, {out / 'result.png'}")
    log(
        f"final runout {summary['final_runout_m']:.3f} m at t = {sc.t_end:g} s; wall {wall:.1f} s "
        f"({summary['particle_steps_per_s']:.3g} particle-steps/s); lost particles: {summary['n_lost']}"
    )
    return summary


def cmd_run(args) -> int:
    from ._config import SceneError

    out = Path(args.out) if args.out else Path("runs") / Path(args.scene).stem
    try:
        run_scene(args.scene, out, args.set or [], quiet=args.quiet)
    except SceneError as e:
        return _fail(str(e))
    except KeyboardInterrupt:
        print(f"\ninterrupted: frames written so far remain readable in {out / 'result.h5'}", file=sys.stderr)
        return 130
    return 0


def cmd_rheometer(args) -> int:
    from . import rheometer

    return rheometer.run_from_args(args)


def cmd_bench(args) -> int:
    from ._bench import run_bench

    try:
        return run_bench(args)
    except ValueError as e:
        return _fail(str(e))


def cmd_study(args) -> int:
    from ._studies import run_study

    try:
        return run_study(args.name, Path(args.out))
    except ValueError as e:
        return _fail(str(e))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="mpmjax", description="Differentiable MPM for thixotropic mine tailings (SI units)."
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    ps = sub.add_parser("scenes", help="list the built-in scenes (or, with --keys, every scene key)")
    ps.add_argument("--keys", action="store_true", help="list every scene key with unit, default and range")
    ps.set_defaults(fn=cmd_scenes)
    pr = sub.add_parser("run", help="run a scene and write result.h5, summary.json and result.png")
    pr.add_argument("scene", nargs="?", default="dambreak-lab", help="built-in scene name or TOML path")
    pr.add_argument("--out", help="output directory (default runs/SCENE)")
    pr.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a scene key, e.g. material.mu0_pa_s=2"
    )
    pr.add_argument("--quiet", action="store_true", help="no progress output")
    pr.set_defaults(fn=cmd_run)
    try:
        from . import rheometer

        prh = sub.add_parser("rheometer", help="0-D Coussot rheometer: viscosity vs time and flow curves")
        rheometer.add_arguments(prh)
        prh.set_defaults(fn=cmd_rheometer)
    except ImportError:  # pragma: no cover
        pass
    pb = sub.add_parser("bench", help="measure particle-steps per second (default scene, mpm88-equivalent)")
    pb.add_argument("--out", default="bench.json", help="JSON file to write")
    pb.add_argument("--steps", type=int, default=2000, help="steps per measurement")
    pb.add_argument("--dtype", default="float32", choices=("float32", "float64"))
    pb.set_defaults(fn=cmd_bench)
    from . import _stress

    pss = sub.add_parser("stress", help="robustness cases (stiff, viscous, field scale, slope, drop, 100k steps)")
    _stress.add_arguments(pss)
    pss.set_defaults(fn=_stress.cmd_stress)
    pst = sub.add_parser("study", help="thesis sensitivity tables and the stiff-viscosity comparison (slow)")
    pst.add_argument("name", choices=("numerical", "physical", "stiff"))
    pst.add_argument("--out", default="studies", help="output directory")
    pst.set_defaults(fn=cmd_study)
    from calibration import cli as calcli

    pc = sub.add_parser("calibrate", help="fit material parameters to measured height profiles (optax, gradients)")
    calcli.add_calibrate_arguments(pc)
    pc.set_defaults(fn=calcli.cmd_calibrate)
    psw = sub.add_parser("sweep", help="run a grid of material parameters as one vmap batch (runout, time to rest)")
    calcli.add_sweep_arguments(psw)
    psw.set_defaults(fn=calcli.cmd_sweep)
    args = p.parse_args(argv)
    return args.fn(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
