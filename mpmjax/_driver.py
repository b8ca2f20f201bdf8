"""The run driver: ``run_scene`` runs a scene frame by frame and writes it to disk (what
``mpmjax run`` does), with checkpoint and resume, SIGINT/SIGTERM handling, the compiled-advance
cache, progress on stderr, the summary.json metrics and the animation.

Also the exit statuses shared by the command layers (``mpmjax.cli`` and the ``cmd_*`` functions of
``mpmjax.studies``): 0 success, 1 other errors, 2 invalid input (``USAGE_ERROR``, printed by
``fail``; also an output folder that cannot be used and a run refused by the memory estimate),
3 a run stopped by a failed health check (``FAILED``), 4 a run stopped because its output could
not be written (``OUTPUT_FAILED``: the folder became unwritable, the disk is full), 128 + the
signal number for an interrupted run (130 Ctrl-C, 143 SIGTERM).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shlex
import signal
import sys
import threading
import time
from pathlib import Path

import h5py
import jax
import jax.numpy as jnp
import numpy as np

from . import _hazard, _health, _metrics, plotting
from ._build import build, memory_estimate, start_warnings
from ._schema import SceneError, load_scene
from ._io import FrameWriter, _jsonable, atomic_write_text, config_hash, read_checkpoint, read_result
from ._io import write_checkpoint as _write_ckpt
from ._shard import use_devices
from ._simulate import StagedAdvance, make_prefix_advance
from ._version import __version__
from ._xdmf import write_xdmf

USAGE_ERROR = 2  # exit status of invalid input (the message names the key, the value and the allowed range)
FAILED = 3  # exit status of a run stopped by a failed health check (mpmjax._health)
OUTPUT_FAILED = 4  # exit status of a run stopped because writing its output failed (OutputFailure)


class Progress:
    """A one-line progress report with elapsed time and an estimate of the time left.

    The clock starts at construction and again at ``update(0)``: a caller that compiles after
    creating the bar calls ``update(0)`` once compiled, so that neither the elapsed time nor the
    estimate (elapsed / done x left) counts the compilation (it used to: the first "left" of a
    stress case was 40x too high)."""

    def __init__(self, total: int, label: str, stream=sys.stderr):
        self.total, self.label, self.stream = total, label, stream
        self.t0 = time.perf_counter()
        self.tty = stream.isatty()
        self.last_pct = -1

    def update(self, done: int, extra: str = ""):
        if done == 0:
            self.t0 = time.perf_counter()
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


def fail(msg: str) -> int:
    """Print ``mpmjax: error: MSG`` on stderr; return the invalid-input exit status ``USAGE_ERROR``."""
    print(f"mpmjax: error: {msg}", file=sys.stderr)
    return USAGE_ERROR


def _scenario_metrics(setup, state, times, kinetic) -> dict:
    """summary.json scenario metrics (definitions in docs/output.md and mpmjax._metrics):
    kinetic energy per frame, time to rest (1 % of the peak kinetic energy), mobilised
    fraction (share of the final material displaced by more than one cell size h from where
    it started or was released), the final free-surface profile along the runout axis (bins of
    width h over the domain; null where empty) and its beach slope."""
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


CHECKPOINT_EVERY = 10  # frames between checkpoints (default of --checkpoint-every)


class Interrupted(KeyboardInterrupt):
    """A run stopped by SIGINT (Ctrl-C) or SIGTERM; ``message`` says how to resume it."""

    def __init__(self, signum: int, message: str = ""):
        super().__init__(message)
        self.signum, self.message = signum, message


class _Signals:
    """Turn SIGINT/SIGTERM into ``Interrupted`` and hold them back while a frame and its
    checkpoint are being written (``with sig.hold():``), so that the files on disk always
    match the state in memory.  Only installed in the main thread (Python delivers signals
    there only)."""

    def __init__(self):
        self.pending = None
        self.depth = 0
        self.old = {}
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self.old[s] = signal.signal(s, self._handler)

    def _handler(self, signum, frame):
        if self.depth:
            self.pending = signum
        else:
            raise Interrupted(signum)

    def hold(self):
        @contextlib.contextmanager
        def cm():
            self.depth += 1
            try:
                yield
            finally:
                self.depth -= 1
            if not self.depth and self.pending is not None:
                signum, self.pending = self.pending, None
                raise Interrupted(signum)

        return cm()

    def restore(self):
        for s, h in self.old.items():
            signal.signal(s, h)


_ADVANCE_CACHE: dict = {}


def _compiled_advance(sc, state, params, n=None):
    """The compiled one-frame advance for this scene, these array shapes and the buffer prefix
    [0, n) it steps (default: all; see ``_simulate.make_prefix_advance``), kept for the
    process (a few scenes' worth), so repeated runs of one scene (a resume, tests, notebooks)
    compile once and run the very same programs."""
    n = sc.n_particles if n is None else int(n)
    leaves, tree = jax.tree_util.tree_flatten((state, params))
    key = (sc, tree, tuple((a.shape, str(a.dtype)) for a in leaves), n)
    if key not in _ADVANCE_CACHE:
        if len(_ADVANCE_CACHE) >= 24:
            _ADVANCE_CACHE.pop(next(iter(_ADVANCE_CACHE)))
        _ADVANCE_CACHE[key] = make_prefix_advance(sc, n).lower(state, params).compile()
    return _ADVANCE_CACHE[key]


def resume_command(out: Path) -> str:
    return f"mpmjax run --resume {shlex.quote(str(out))}"


LOCK_NAME = ".mpmjax.lock"  # in the output folder: held (flock) by the run writing there


class OutputBusy(SceneError):
    """The output folder is being written by another run (exit status 2, like invalid input)."""


class OutputLock:
    """An exclusive lock on an output folder, held for a whole run: ``flock`` on
    ``OUT/.mpmjax.lock``, which holds the owner's process id.  The kernel releases a flock when
    its process ends, however it ends, so a lock left by a killed run is never stale: the
    next run takes it over.  A second run into a held folder gets ``OutputBusy`` before it
    creates or truncates anything there."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.fd = None

    def acquire(self) -> None:
        if self.fd is not None:
            return
        path = self.out / LOCK_NAME
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise OutputBusy(
                f"--out {self.out}: another mpmjax run (process {holder}) is writing to this folder; "
                "wait for it to finish, or choose another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self.fd = fd

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)  # closing the descriptor releases the flock
            self.fd = None


class OutputError(SceneError):
    """``--out`` cannot hold a run's files: an existing file, a folder that cannot be created,
    or one without write permission (exit status 2; found before anything is built)."""


class OutputFailure(Exception):
    """Writing the output failed during or after the run (the folder became unwritable, the
    disk filled up): exit status ``OUTPUT_FAILED``.  The message says what was kept."""


class MemoryRefused(SceneError):
    """The memory estimate of a run exceeds the memory available (exit status 2)."""


MEMORY_ENV = "MPMJAX_MEMORY_LIMIT_GB"  # overrides the memory available to a run ("inf": no check)


def check_output_folder(out: Path) -> None:
    """Raise ``OutputError`` unless ``out`` is, or can be created as, a folder we can write to.
    Creates nothing (a probe file is created and removed in the nearest existing folder)."""
    out = Path(out)
    try:
        if out.exists() and not out.is_dir():
            raise OutputError(f"--out {out} is an existing file; allowed: a folder (existing, or one to create)")
        base = out
        while not base.exists() and base != base.parent:
            base = base.parent
        if not base.is_dir():
            raise OutputError(f"--out {out} cannot be created: {base} is a file, not a folder")
    except OSError as e:  # e.g. a parent without search permission
        raise OutputError(f"--out {out} cannot be used: {e.strerror or e}") from None
    probe = base / f".mpmjax-write-test-{os.getpid()}"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except OSError as e:
        what = "is not writable" if base == out else f"cannot be created in {base}"
        raise OutputError(f"--out {out} {what}: cannot create a file there ({e.strerror or e})") from None


def _available_memory() -> dict:
    """Bytes available to a run: ``{"device": .., "host": .., "source": ..}``.  Host: the
    smaller of MemAvailable (/proc/meminfo) and the cgroup's memory.max - memory.current; the
    device (GPU) from its allocator's statistics; ``$MPMJAX_MEMORY_LIMIT_GB`` overrides both."""
    env = os.environ.get(MEMORY_ENV)
    if env:
        try:
            gb = float(env)
        except ValueError:
            raise SceneError(f"{MEMORY_ENV} = {env!r} is invalid: allowed: a number of GB > 0, or inf") from None
        if not gb > 0:
            raise SceneError(f"{MEMORY_ENV} = {env!r} is invalid: allowed: a number of GB > 0, or inf")
        return {"device": gb * 1e9, "host": gb * 1e9, "source": f"{MEMORY_ENV} = {env}"}
    host, source = float("inf"), "unknown"
    with contextlib.suppress(OSError, ValueError, IndexError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                host, source = float(line.split()[1]) * 1024, "MemAvailable"
    with contextlib.suppress(OSError, ValueError):
        cg = Path("/sys/fs/cgroup")
        lim = (cg / "memory.max").read_text().strip()
        if lim != "max":
            free = float(lim) - float((cg / "memory.current").read_text())
            if free < host:
                host, source = free, "the cgroup's memory.max"
    device, dsource = host, source
    if jax.default_backend() != "cpu":
        with contextlib.suppress(Exception):
            st = jax.devices()[0].memory_stats() or {}
            if "bytes_limit" in st:
                device = float(st["bytes_limit"] - st.get("bytes_in_use", 0))
                dsource = f"{jax.devices()[0].device_kind} memory"
    return {"device": device, "host": host, "source": source, "device_source": dsource}


def check_memory(cfg: dict) -> dict:
    """Refuse (``MemoryRefused``) a run whose ``_build.memory_estimate`` exceeds the memory
    available; returns the estimate."""
    est = memory_estimate(cfg)
    avail = _available_memory()
    cpu = jax.default_backend() == "cpu"
    need = {"host": est["host_bytes"] + (est["device_bytes"] if cpu else 0.0)}
    if not cpu:
        need["device"] = est["device_bytes"]
    for where, b in need.items():
        if b > avail[where]:
            src = avail.get("device_source", avail["source"]) if where == "device" else avail["source"]
            raise MemoryRefused(
                f"the run needs about {_gb(b)} of {'GPU ' if where == 'device' else ''}memory "
                f"({est['particles']:.4g} particles: {_gb(est['particle_bytes'])}; grid of {est['grid_nodes']:.4g} "
                f"nodes: {_gb(est['grid_bytes'])}; {cfg['time.n_frames'] + 1} frames read back at the end: "
                f"{_gb(est['frames_bytes'])}; {est['dtype']}) but {_gb(avail[where])} is available ({src}); "
                "allowed: a run that fits: raise domain.cell_size_m, lower numerics.ppc or time.n_frames, or set "
                f"{MEMORY_ENV} to the memory the run may use (inf: no check)"
            )
    return est


def _gb(b: float) -> str:
    return f"{b / 1e9:.3g} GB" if b >= 1e8 else f"{b / 1e6:.3g} MB"


def _write_summary(path: Path, doc: dict) -> bool:
    """Write summary.json; if the folder no longer takes new files (the atomic write needs a
    temporary file), rewrite the existing summary.json in place.  Returns whether it worked."""
    text = json.dumps(_jsonable(doc), indent=2)
    try:
        atomic_write_text(path, text)
        return True
    except OSError:
        pass
    try:
        with open(path, "r+") as f:
            f.write(text)
            f.truncate()
        return True
    except OSError:
        return False


def _os_reason(e: OSError) -> str:
    where = f" ({e.filename})" if getattr(e, "filename", None) else ""
    return f"{e.strerror or e}{where}"


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
    (see ``_run_scene`` for the whole contract).  The folder is locked for the whole run
    (``OutputLock``): a second run into it raises ``OutputBusy`` (a ``SceneError``) before it
    creates or truncates anything."""
    lock = OutputLock(Path(out))
    try:
        return _run_scene(
            scene, out, overrides, quiet, checkpoint_every, resume, on_frame, animate, staged, lock=lock
        )
    finally:
        lock.release()


def _run_scene(
    scene: str | None,
    out: Path,
    overrides: list[str] | None,
    quiet: bool = False,
    checkpoint_every: int = CHECKPOINT_EVERY,
    resume: bool = False,
    on_frame=None,
    animate: bool = False,
    staged: bool = True,
    *,
    lock: OutputLock,
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
    """
    out = Path(out)
    ckpt_path = out / "checkpoint.h5"
    ckpt = None
    check_output_folder(out)  # an existing file, an uncreatable or unwritable folder: exit 2, before building
    if resume:
        if out.is_dir():
            lock.acquire()  # before the checkpoint is read: no other run may change it meanwhile
        if not ckpt_path.is_file():
            done = (out / "result.h5").is_file() and _result_complete(out / "result.h5")
            raise SceneError(
                f"--resume {out}: "
                + ("the run there is already complete; nothing to resume" if done else f"no {ckpt_path.name} there")
            )
        try:
            ckpt = read_checkpoint(ckpt_path)
        except (OSError, KeyError, ValueError) as e:
            raise SceneError(f"--resume {out}: {ckpt_path} cannot be read: {e}") from None
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
    if ckpt is not None and ckpt[2] != chash:
        old = ckpt[3].get("cfg", {})
        diff = [k for k in sorted(set(old) | set(cfg)) if json.dumps(old.get(k)) != json.dumps(_jsonable(cfg.get(k)))]
        shown = ", ".join(f"{k}: {old.get(k)!r} in the checkpoint, {_jsonable(cfg.get(k))!r} now" for k in diff[:6])
        raise SceneError(
            f"--resume {out}: the checkpoint was written for a different scene or different --set overrides "
            f"(checkpoint: {ckpt[3]['scene_source']} {ckpt[3]['overrides']}; now: {source} {overrides}); "
            f"differing keys: {shown or 'none found (the scene file changed)'}. Resume with the original scene "
            f"and overrides (or none: `{resume_command(out)}`)"
        )
    use_devices(cfg["numerics.devices"])  # first: on a CPU, host devices can be made only before JAX starts
    check_memory(cfg)  # before anything is built: a run that cannot fit is refused (exit 2)
    setup = build(cfg)
    sc, info = setup.scene, setup.info
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"--out {out} cannot be created: {_os_reason(e)}") from None
    lock.acquire()  # before anything in the folder is created or truncated
    log = (lambda *a: None) if quiet else (lambda *a: print(*a, file=sys.stderr))
    sig = _Signals()  # from here Ctrl-C / SIGTERM raise Interrupted (while compiling: once the compiler returns)
    try:
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
        # a pipe inflow's parked pool is stepped only once released: each frame steps the buffer prefix
        # that holds every particle active by its end (a few sizes, compiled here; _simulate.StagedAdvance)
        if cfg["output.hazard_maps"]:
            # hazard maps sampled inside the compiled frame, an extra carry next to the state (_hazard)
            advance = _hazard.HazardAdvance(sc, setup.state, setup.params, _hazard.HazardGrid.of(sc, cfg))
        else:
            advance = StagedAdvance(
                sc, staged=staged, compile=lambda n: _compiled_advance(sc, setup.state, setup.params, n)
            )
        first_frame = int(ckpt[1]) if ckpt is not None else 0
        sizes = advance.sizes(first_frame)
        for n in sizes:
            advance.program(n)
        compile_s = time.perf_counter() - t0
        staged_note = (
            f" (pipe pool staged: frames step the first {', '.join(map(str, sizes))} of {sc.n_particles} particles)"
            if sizes != [sc.n_particles]
            else ""
        )
        log(f"compiled in {compile_s:.1f} s{staged_note}")
        rho = float(setup.params.material.rho)
        gauge = _metrics.RunoutGauge.of(sc, info)

        def front(st):
            # no active material yet (a pipe inflow before its start): both fronts are at the origin
            return gauge.front(st.x, st.vol0, st.active)

        def farthest(st):
            return gauge.farthest(st.x, st.active)

        def energy(st):
            return float(_metrics.kinetic_energy(np.asarray(st.v), np.asarray(st.vol0), np.asarray(st.active), rho))

        if ckpt is None:
            state = setup.state
            done = 0
            acc = dict(
                times=[0.0],
                fronts=[front(state)],
                farthest=[farthest(state)],
                kinetic=[energy(state)],
                lost_reported=0,
                n_outflow=0,
                wall_s=0.0,
                mass0=float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * rho,
            )
            ckpt_path.unlink(missing_ok=True)  # a stale checkpoint of an earlier run here
        else:
            st_np, done, _, meta = ckpt
            state = jax.tree_util.tree_map(jnp.asarray, st_np)
            acc = meta["acc"]
            if "farthest" not in acc:
                raise SceneError(
                    f"--resume {out}: the checkpoint was written by mpmjax {meta.get('code_version', '?')}, before "
                    "the free-surface runout (docs/output.md 'Runout'); its runout series cannot be continued: rerun "
                    "without --resume"
                )
            if isinstance(advance, _hazard.HazardAdvance):
                advance.restore(acc["hazard"])
            log(f"resuming {out} from the checkpoint at frame {done}/{sc.n_frames} (t = {float(state.t):.4g} s)")
        last_ckpt = done if ckpt is not None else -1
        meta_base = dict(scene_source=source, overrides=overrides, cfg=_jsonable(cfg), code_version=__version__)

        def write_checkpoint(st, frame):
            nonlocal last_ckpt
            if isinstance(advance, _hazard.HazardAdvance):
                acc["hazard"] = advance.to_json()
            _write_ckpt(ckpt_path, st, frame, chash, dict(meta_base, acc=acc))
            last_ckpt = frame

        base_summary = {
            "scene": cfg["name"],
            "scene_source": source,
            "overrides": overrides,
            "dim": sc.dim,
            "n_particles": sc.n_particles,
            "n_steps": sc.n_steps,
            "dt_s": sc.dt,
            "t_end_s": sc.t_end,
            "warnings": warnings,
            # map placement (scene = map - map_origin_m) and the breach release's volumes (docs/output.md)
            **{k: info[k] for k in ("map", "release") if k in info},
        }
    except KeyboardInterrupt as e:
        sig.restore()
        kept = (
            f"the checkpoint in {ckpt_path} is unchanged; resume with: {resume_command(out)}"
            if ckpt is not None
            else f"no result in {out} was written or changed"
        )
        raise Interrupted(getattr(e, "signum", signal.SIGINT), f"interrupted while compiling: {kept}") from None
    except BaseException:
        sig.restore()
        raise
    start = done  # progress and its time estimate count this session's frames
    prog = None if quiet else Progress(sc.n_frames - start, "run" if not start else f"run (from frame {start})")
    t_run = time.perf_counter()
    wall0 = acc["wall_s"]
    w = None
    try:
        try:
            with sig.hold():
                if ckpt is None:
                    w = FrameWriter(out / "result.h5", setup, __version__)
                    w.append(state)
                else:
                    try:
                        w = FrameWriter(out / "result.h5", setup, __version__, keep_frames=done + 1)
                    except (OSError, KeyError, ValueError) as e:
                        raise SceneError(f"--resume {out}: {out / 'result.h5'} cannot be continued: {e}") from None
                # a summary.json from the start, so that a failure after the folder became unwritable can
                # still rewrite it in place (_write_summary)
                _write_summary(out / "summary.json", dict(base_summary, status="running", complete=False))
            for i in range(done, sc.n_frames):
                new = advance(i, state, setup.params)
                jax.block_until_ready(new.x)
                probs, outflow = _health.check(sc, cfg, state, new)
                if probs:
                    raise _health.failure(sc, setup.params, cfg, state, new, probs, i + 1, log=log)
                with sig.hold():
                    w.append(new)
                    state, done = new, i + 1
                    acc["times"].append(done * sc.steps_per_frame * sc.dt)
                    acc["fronts"].append(front(state))
                    acc["farthest"].append(farthest(state))
                    acc["kinetic"].append(energy(state))
                    acc["n_outflow"] += int(len(outflow))
                    acc["wall_s"] = wall0 + time.perf_counter() - t_run
                    if checkpoint_every and done % checkpoint_every == 0 and done < sc.n_frames:
                        write_checkpoint(state, done)
                lost = int(state.n_lost)
                if lost > acc["lost_reported"]:
                    log(
                        f"\nnote: {lost - acc['lost_reported']} particle(s) left the domain through an open face by "
                        f"t = {float(state.t):.3f} s (frame {done}); they were deactivated and are counted in "
                        "summary.json n_lost"
                    )
                    acc["lost_reported"] = lost
                if prog:
                    prog.update(done - start, f"t = {float(state.t):7.3f} s, runout {acc['fronts'][-1]:.3f} m,")
                if on_frame is not None:
                    on_frame(done, state)
        except KeyboardInterrupt as e:
            signum = getattr(e, "signum", 2)
            sig.depth += 1  # a second Ctrl-C while the files are closed is only recorded
            if w is not None and done > last_ckpt:
                write_checkpoint(state, done)
            if w is not None:
                w.close(False, status="interrupted")
            msg = (
                f"interrupted at frame {done}/{sc.n_frames} (t = {float(state.t):.4g} s): frames 0..{done} remain "
                f"readable in {out / 'result.h5'}; the state is saved in {ckpt_path}. Resume with: "
                f"{resume_command(out)}"
            )
            atomic_write_text(
                out / "summary.json",
                json.dumps(
                    dict(base_summary, status="interrupted", frames_written=done, message=msg, complete=False),
                    indent=2,
                ),
            )
            raise Interrupted(signum, msg) from None
        except _health.RunFailure as e:
            sig.depth += 1
            w.close(False, status="failed", error=str(e))
            atomic_write_text(
                out / "summary.json",
                json.dumps(
                    _jsonable(
                        dict(
                            base_summary,
                            status="failed",
                            error=str(e),
                            failure=e.info,
                            frames_written=done,
                            times_s=acc["times"],
                            runout_m=acc["fronts"],
                            complete=False,
                        )
                    ),
                    indent=2,
                ),
            )
            raise
        except OSError as e:
            # writing failed (the folder became unwritable, the disk is full): result.h5 is marked failed
            # where it can still be written, and summary.json gets what was written
            sig.depth += 1
            reason = (
                f"writing the output in {out} failed after frame {done}/{sc.n_frames} "
                f"(t = {float(state.t):.4g} s): {_os_reason(e)}"
            )
            marked = False
            if w is not None:
                with contextlib.suppress(Exception):
                    w.close(False, status="failed", error=reason)
                    marked = True
            doc = dict(
                base_summary,
                status="failed",
                error=reason,
                failure={"kind": "output", "message": reason, "frame": done},
                frames_written=done if w is not None else 0,
                times_s=acc["times"],
                runout_m=acc["fronts"],
                complete=False,
            )
            wrote = _write_summary(out / "summary.json", doc)
            kept = (
                f"frames 0..{done} remain readable in {out / 'result.h5'}"
                + (" (status 'failed')" if marked else " (its status could not be set)")
                if w is not None
                else "no frame was written"
            )
            resume = (
                f"; after fixing the folder, resume from the checkpoint at frame {last_ckpt}: {resume_command(out)}"
                if last_ckpt >= 0 and ckpt_path.is_file()
                else ""
            )
            raise OutputFailure(
                f"{reason}. {kept}; summary.json "
                + ("has status 'failed'" if wrote else "could not be written")
                + resume
            ) from None
        except BaseException:
            if w is not None:
                w.close(False, status="interrupted")
            raise
        with sig.hold():
            w.close(True, status="complete")
    finally:
        sig.restore()
    try:
        return _finish(out, setup, cfg, state, acc, advance, compile_s, base_summary, animate, quiet, log)
    except OSError as e:
        reason = f"the run is complete in {out / 'result.h5'}, but writing its other outputs failed: {_os_reason(e)}"
        wrote = _write_summary(out / "summary.json", dict(base_summary, status="complete", error=reason, complete=True))
        raise OutputFailure(
            reason + ("; summary.json has the run facts and this message" if wrote else "; summary.json could not be written")
        ) from None


def _finish(out, setup, cfg, state, acc, advance, compile_s, base_summary, animate, quiet, log) -> dict:
    """After the last frame: delete the checkpoint, write result.xdmf, summary.json, the pictures
    (and the 3D plan-view maps); returns the summary."""
    sc, info = setup.scene, setup.info
    ckpt_path = out / "checkpoint.h5"
    rho = float(setup.params.material.rho)
    gauge = _metrics.RunoutGauge.of(sc, info)
    ckpt_path.unlink(missing_ok=True)  # complete: nothing left to resume
    wall = acc["wall_s"]
    times, fronts, kinetic = acc["times"], acc["fronts"], acc["kinetic"]
    write_xdmf(out / "result.h5")  # result.xdmf: ParaView / VisIt sidecar of the closed result.h5
    mass1 = float(np.sum(np.asarray(state.vol0) * np.asarray(state.active))) * rho
    thick = gauge.max_thickness(state.x, state.vol0, state.active)
    summary = {
        **base_summary,
        "status": "complete",
        "wall_s": wall,
        "compile_s": compile_s,
        # particle-steps actually stepped: a staged pipe pour steps a prefix of the buffer per frame
        "particle_steps_per_s": sum(advance.schedule) * sc.steps_per_frame / wall,
        "particles_stepped_mean": sum(advance.schedule) / len(advance.schedule),
        "mass_initial_kg": acc["mass0"],
        "mass_final_kg": mass1,
        "mass_unit": "kg per metre of depth" if sc.dim == 2 else "kg",
        "n_lost": int(state.n_lost),
        "n_outflow": acc["n_outflow"],
        "times_s": times,
        "runout_m": fronts,
        "final_runout_m": fronts[-1],
        "runout_farthest_particle_m": acc["farthest"],
        "final_runout_farthest_particle_m": acc["farthest"][-1],
        **_scenario_metrics(setup, state, times, kinetic),
        "runout_definition": gauge.definition(),
        "runout_farthest_particle_definition": gauge.farthest_definition(),
        "runout_front_fraction": gauge.fraction,
        # the domain face the runout runs towards, measured like the runout; a front within one cell
        # of it was stopped by the wall, not by the material (docs/output.md "Runout")
        "runout_wall_m": sc.hi[gauge.axis] - gauge.origin,
        "runout_capped_by_wall": bool(
            max(fronts[-1], acc["farthest"][-1]) >= sc.hi[gauge.axis] - gauge.origin - sc.h
        ),
        # resolution across the deposit (docs/output.md "Runout"; the needed number: docs/validation.md)
        "deposit_max_thickness_m": thick,
        "deposit_cells_across": thick / sc.h,
        "deposit_cells_across_needed": _metrics.DEPOSIT_CELLS_NEEDED,
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
        "complete": True,
    }
    deposit_warning = None
    if 0 < summary["deposit_cells_across"] < _metrics.DEPOSIT_CELLS_NEEDED:
        deposit_warning = (
            f"the final deposit is {summary['deposit_cells_across']:.1f} cells thick at its thickest point "
            f"(deposit_cells_across; {thick:.3g} m at domain.cell_size_m = {sc.h:g} m); the convergence benchmark "
            f"needs >= {_metrics.DEPOSIT_CELLS_NEEDED} for a runout within about 5 % (docs/validation.md, 'Convergence "
            f"benchmark'): set domain.cell_size_m <= {thick / _metrics.DEPOSIT_CELLS_NEEDED:.3g} m, the cheapest remedy "
            "that converges (docs/validation.md, 'Depth resolution': more particles per cell do not pay; a domain.hi_m "
            "cropped to where the material goes saves the grid's few per cent; boundary.slip_length_m = "
            f"{0.25 * sc.h:.3g} m (h/4) cut the shortfall by 15-30 % there at no cost, but changes the bed's physics)"
        )
        summary["warnings"] = list(summary.get("warnings", [])) + [deposit_warning]
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
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
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
    if sc.dim == 3:
        ch = summary["channels"]
        log(
            f"lobe width {summary['lobe_width_m']} m (thickness > {summary['lobe_width_threshold_m']:g} m); "
            f"channels: {'yes, from t = ' + format(ch['first_time_s'], 'g') + ' s' if ch['detected'] else 'no'}"
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
        f"(farthest particle {summary['final_runout_farthest_particle_m']:.3f} m); wall {wall:.1f} s "
        f"({summary['particle_steps_per_s']:.3g} particle-steps/s); lost particles: {summary['n_lost']}"
    )
    return summary


def _result_complete(path: Path) -> bool:
    try:
        with h5py.File(path, "r") as f:
            return bool(f.attrs.get("complete", False))
    except OSError:
        return False
