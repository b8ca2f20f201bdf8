"""Batched parameter sweeps: every case of a grid of material parameters in one ``vmap``.

``sweep(scene, vary)`` runs the Cartesian product of the values in ``vary`` (material
parameter name -> values) on one scene.  Cases are run ``chunk`` at a time as a
``jax.vmap`` batch (padded to a whole chunk by repeating the last case, so there is one
compilation); with several devices the batch axis is sharded across them with
``jax.sharding`` (a 1-D mesh named ``batch``, ``calibration.distributed.BatchLayout``), so the
same code runs on many GPUs or, under ``jax.distributed``, on the devices of many processes and
hosts; ``shard=(I, N)`` runs one share of the cases for a job array (``write_part``,
``merge_parts``; docs/performance.md "Beyond one machine").  Each case gives:

* ``runout_m`` (per saved frame) and ``final_runout_m``: the headline runout of
  ``mpmjax run`` (docs/output.md "Runout") [m]: in 2D the free-surface front
  (``mpmjax.free_surface_front``: thickness >= 10 % of the frame's thickest point, kernel
  bandwidth one cell); in 3D, and for a vertical runout axis, the farthest particle (the
  plan-view front of summary.json is computed on the host, not inside the batch);
* ``runout_farthest_particle_m``, ``final_runout_farthest_particle_m``: ``mpmjax.runout``
  (the farthest active particle plus half a particle spacing), minus the runout origin [m];
* ``kinetic_energy_J`` per frame [J; 2D: J per metre of depth] and ``time_to_rest_s``
  (``mpmjax.time_to_rest``; NaN if the material has not come to rest);
* ``n_lost`` particles and the final height profile on ``profile_x_m``.

Material parameters, and the basal friction of a depth-averaged scene on a ``coulomb`` or
``voellmy`` terrain (``friction``, ``turbulence``: ``mpmjax.fit_parameters``), can vary inside
a batch (the scene's grid, time step and shape are static).  Every case is validated as a
scene (the usual key, value and range errors), and the batch uses one time step: the smallest stable step over the cases
(reported as ``dt_s``), so a stiffer case does not break the batch.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import signal
import sys
import time
import zipfile
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import mpmjax

from .distributed import (
    BatchLayout,
    DistributedError,
    check_join_options,
    check_local_devices,
    is_writer,
    join,
    make_local_devices,
    shard_range,
)
from .params import SCENE_KEYS

__all__ = [
    "FIELD_KEYS",
    "NO_SENSITIVITY_M",
    "kept_name",
    "merge_parts",
    "merge_sweep",
    "parse_vary",
    "run_sweep",
    "sweep",
    "sweep_figures",
    "write_part",
    "write_sweep",
]

# material field -> scene key (SI units in the key's name), from the laws' declarations
FIELD_KEYS = SCENE_KEYS


def parse_vary(items) -> dict:
    """``["n=1.5,2,2.5", "mu0=1,4"]`` -> {"n": [1.5, 2.0, 2.5], "mu0": [1.0, 4.0]} (ValueError
    naming the item otherwise)."""
    out = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--vary {it!r}: expected NAME=V1,V2,... (e.g. n=1.5,2,2.5)")
        name, vals = it.split("=", 1)
        name = name.strip()
        if name in out:
            raise ValueError(f"--vary {name} is given twice")
        try:
            v = [float(s) for s in vals.split(",") if s.strip()]
        except ValueError:
            raise ValueError(f"--vary {it!r}: values must be numbers separated by commas") from None
        if not v:
            raise ValueError(f"--vary {it!r}: no values")
        if not all(math.isfinite(x) for x in v):
            raise ValueError(f"--vary {it!r}: values must be finite")
        out[name] = v
    return out


def _cases(vary: dict) -> list[dict]:
    names = list(vary)
    return [dict(zip(names, c, strict=True)) for c in itertools.product(*(vary[k] for k in names))]


def _default_chunk(scene, n_cases) -> int:
    """Cases per batch so that the batch's working set stays below a quarter of the
    machine's memory: per case ~ 16 x (particle state + 3 grid copies) bytes, a generous
    multiple of the state that XLA keeps live in a step."""
    item = 8 if scene.dtype == "float64" else 4
    d = scene.dim
    per_particle = d + d + d * d + d * d + 6
    nodes = math.prod(scene.grid_shape)
    per_case = 16 * item * (scene.n_particles * per_particle + 3 * nodes * (d + 1))
    try:
        mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover
        mem = 4 << 30
    return int(max(1, min(n_cases, (mem // 4) // per_case)))


def _on_profile(sc, axis) -> bool:
    """Whether the headline runout is the free-surface front (2D, horizontal runout axis)."""
    return sc.dim == 2 and axis == 0


def _lane(params, m):
    """The scene's ``params`` with one lane's varied part ``m`` = (material, basal friction)."""
    return params._replace(material=m[0], basal=m[1])


@partial(jax.jit, static_argnames=("sc",))
def _batch_start(mats, params, state0, *, sc):
    """The lanes' initial states: the scene's, with each lane's material (``mpmjax.restate``)."""
    return jax.vmap(lambda m: mpmjax.restate(state0, sc, _lane(params, m)))(mats)


@partial(jax.jit, static_argnames=("sc",))
def _batch_steps(states, mats, params, n, *, sc):
    """``n`` steps of every lane (``mpmjax.make_steps``: one program for any ``n``)."""
    steps = mpmjax.make_steps(sc)
    return jax.vmap(lambda s, m: steps(s, _lane(params, m), n))(states, mats)


@partial(jax.jit, static_argnames=("sc",))
def _batch_frame(states, mats, params, *, sc):
    """One whole frame of every lane (slab decomposition, which is not chunked: ``mpmjax.chunkable``)."""
    chunk = mpmjax.make_chunk(sc)
    return jax.vmap(lambda s, m: chunk(s, _lane(params, m)))(states, mats)


@partial(jax.jit, static_argnames=("sc", "axis", "origin", "spacing"))
def _batch_observe(states, mats, *, sc, axis, origin, spacing):
    """Per lane, of one frame: front [m], farthest particle [m] (both from the runout origin; at
    the origin while no material is active) and kinetic energy [J], with the lane's own volumes
    (they change where the depth-averaged step splits columns)."""

    def one(st, mat):
        vol0 = st.vol0
        some = jnp.any(st.active)
        far = jnp.where(some, mpmjax.runout(st.x, st.active, axis, origin, spacing), 0.0)
        if _on_profile(sc, axis):
            front = mpmjax.free_surface_front(st.x, vol0, st.active, bandwidth=sc.h, x_lo=sc.lo[0], x_hi=sc.hi[0])
            front = jnp.where(some, front - origin, 0.0)
        else:
            front = far
        return front, far, mpmjax.kinetic_energy(st.v, vol0, st.active, mat[0].rho)

    return jax.vmap(one)(states, mats)


@partial(jax.jit, static_argnames=("sc",))
def _batch_final(states, x_prof, *, sc):
    """Per lane, of the final state: particles lost and the height profile on ``x_prof`` (2D)."""

    def one(st):
        if sc.dim == 2:
            prof = mpmjax.height_profile(st.x, st.vol0, st.active, x_prof, bandwidth=sc.h)
        else:
            prof = jnp.zeros_like(x_prof)
        return st.n_lost, prof

    return jax.vmap(one)(states)


def _run_batch(mats, shared, how, layout, pacer):
    """Every case of one batch (``mats`` holds the lanes' (material, basal friction)), frame by
    frame and each frame in chunks of steps (``mpmjax.run_chunked``), so that Ctrl-C / SIGTERM is
    acted on within about a second (``mpmjax.Pacer``) however long a batch or a frame is, not only
    when the batch ends (issue 35).
    Returns (front per frame, farthest particle per frame, kinetic energy per frame, lost
    particles, final height profile) per lane as numpy arrays."""
    params, state0, x_prof = shared
    sc = how["sc"]
    states = _batch_start(mats, params, state0, sc=sc)
    obs = [_batch_observe(states, mats, **how)]
    for _ in range(sc.n_frames):
        if mpmjax.chunkable(sc):
            states = mpmjax.run_chunked(
                lambda s, n: _batch_steps(s, mats, params, n, sc=sc),
                states,
                sc.steps_per_frame,
                pacer,
                between=mpmjax.check_interrupted,
            )
        else:
            states = jax.block_until_ready(_batch_frame(states, mats, params, sc=sc))
            mpmjax.check_interrupted()
        obs.append(_batch_observe(states, mats, **how))
    lost, prof = _batch_final(states, x_prof, sc=sc)
    obs, lost, prof = layout.gather((obs, lost, prof))
    fronts, far, ke = (np.stack([o[i] for o in obs], axis=1) for i in range(3))
    return fronts, far, ke, lost, prof


def sweep(
    scene,
    vary: dict,
    *,
    overrides=None,
    chunk: int | None = None,
    profile_x_m=None,
    progress=True,
    shard=None,
    keep=None,
    resume: bool = False,
):
    """Run every combination of ``vary`` on ``scene`` (built-in name or TOML path) with the
    scene ``overrides``.  Returns a dict with ``cases`` (list of name -> value), per-case
    arrays (``final_runout_m``, ``time_to_rest_s``, ``n_lost``, ``runout_m`` (cases, frames),
    ``kinetic_energy_J``, ``profile_h_m``), ``times_s``, ``profile_x_m``, ``dt_s``, ``chunk``,
    ``n_devices`` (of all processes), ``n_processes`` and ``wall_s``.

    Under ``jax.distributed`` (``calibration.distributed.join``) every process calls ``sweep``
    alike; the batch is split over the devices of all of them and every process gets the whole
    result.  ``shard = (I, N)``: only the I-th of N contiguous shares of the cases
    (``calibration.distributed.shard_range``; ``cases`` and ``case_index`` say which), with the
    time step of the whole grid, for ``write_part`` and ``merge_parts``.  Raises ``SceneError``
    (from ``mpmjax``) for invalid values, ``ValueError`` for names that are not material
    parameters of the scene.

    ``keep``: a file (``kept_name``) where the finished cases are written, atomically, after every
    batch; a sweep that finds there the cases of the same sweep (scene, overrides, ``vary``,
    ``shard``, profile points) runs only the others, and one that finds another sweep's refuses
    (``ValueError``) rather than lose them; ``resume``: there must be such a file.  On SIGINT /
    SIGTERM (``mpmjax.Interrupted``, acted on between chunks of steps) the batch under way is
    dropped, and the message says how many cases are kept."""
    overrides = list(overrides or [])
    cfg = mpmjax.load_scene(scene, overrides)
    identity = _identity(cfg, vary, shard, profile_x_m)
    kept = None if keep is None else _read_kept(Path(keep), identity, resume)
    mpmjax.check_memory(cfg)  # before anything is built: a case that cannot fit is refused (MemoryRefused, exit 2)
    p_cfg = mpmjax.make_params(cfg)  # the names it carries, before the scene is built
    fields = mpmjax.fit_parameters(p_cfg, cfg)
    unused = mpmjax.unused_parameters(cfg)
    for k in vary:
        if k in unused:
            raise ValueError(f"--vary {k}: not used by scene {cfg['name']!r}: {unused[k]} (every case would be the same)")
        if k not in fields:
            raise ValueError(
                f"--vary {k}: not a parameter of scene {cfg['name']!r} ({cfg['material.model']}"
                + (f", terrain {cfg['terrain.type']}" if p_cfg.basal is not None else "")
                + f"); allowed: {', '.join(fields)} (only material parameters, and the basal friction of a "
                "depth-averaged scene on a coulomb or voellmy terrain, can vary inside a batch)"
            )
    setup = mpmjax.build(cfg)
    cases = _cases(vary)
    # validate each case as a scene, and find the stable step of each.  The depth-averaged step's limit
    # (``_shallow.time_step_limits``: gravity-wave and flow speeds of the geometry; its friction is implicit)
    # depends on no parameter a sweep can vary, so the scene's step holds for every case there; the full
    # model's (sound speed, Maxwell modulus, viscous limit) is taken per case
    shallow = cfg["model.formulation"] == "depth-averaged"
    limits = [setup.scene.dt]
    for c in cases:
        ov = overrides + [f"{FIELD_KEYS[k]}={v!r}" for k, v in c.items()]
        ci = mpmjax.load_scene(scene, ov)
        if shallow:
            continue
        pi = mpmjax.make_params(ci, setup.scene.dim, setup.scene.dtype)
        x0, v0 = np.asarray(setup.state.x), np.asarray(setup.state.v)
        lim = mpmjax.time_step_limits(ci, pi, x0, v0, setup.scene.rheology)
        limits.append(lim["dt_limit_s"])
    if min(limits) < setup.scene.dt * (1 - 1e-9):
        setup = mpmjax.build(mpmjax.load_scene(scene, overrides + [f"numerics.dt_s={min(limits)!r}"]))
    sc, params, state0 = setup.scene, setup.params, setup.state
    info = setup.info
    x_prof = np.linspace(sc.lo[0], sc.hi[0], 101) if profile_x_m is None else np.asarray(profile_x_m, float)
    axis, origin, spacing = info["runout_axis"], info["runout_origin_m"], info["particle_spacing_m"]
    how = dict(sc=sc, axis=axis, origin=float(origin), spacing=float(spacing))

    n_all = len(cases)
    share = range(n_all) if shard is None else shard_range(n_all, shard)
    index = list(share)
    cases_run = [cases[i] for i in share]
    n = len(cases_run)
    times = np.arange(sc.n_frames + 1) * sc.steps_per_frame * sc.dt
    # cases finished by an earlier, interrupted run of this sweep (``keep``): case index -> results
    done = {} if kept is None else dict(kept)
    todo = [k for k, i in enumerate(index) if i not in done]
    n_dev = jax.device_count()
    ch = _default_chunk(sc, max(len(todo), 1)) if chunk is None else int(chunk)
    if ch < 1:
        raise ValueError(f"chunk = {chunk}; allowed range: >= 1")
    ch = min(ch, max(len(todo), 1))
    ch = int(math.ceil(ch / n_dev) * n_dev)  # whole batches per device (of every process)
    layout = BatchLayout(ch)
    # the scene's arrays as arguments (replicated over the batch mesh), not closed over: one
    # compilation serves every sweep of the same scene and batch size in the process
    npdt = np.dtype(sc.dtype)
    shared = layout.replicate((params, state0, np.asarray(x_prof, npdt)))
    cols = {k: np.asarray([c[k] for c in cases_run], npdt) for k in vary}
    # every lane starts as the scene's material and basal friction; each batch sets the varied names
    mat_l, bas_l = jax.tree.map(
        lambda a: np.broadcast_to(np.asarray(a), (ch,) + np.shape(a)).copy(), (params.material, params.basal)
    )
    lane_base = params._replace(material=mat_l, basal=bas_l)
    say = progress and is_writer()
    if say and done:
        sys.stderr.write(f"sweep: {len(done)} of {n} cases already finished (kept in {keep}); running the others\n")
    pacer = mpmjax.Pacer()
    t0 = time.perf_counter()
    n_chunks = math.ceil(len(todo) / ch)
    for b in range(n_chunks):
        sel = todo[b * ch : (b + 1) * ch]
        idx = np.asarray(sel + [sel[-1]] * (ch - len(sel)))  # pad with the last case
        lanes = mpmjax.replace_parameters(lane_base, {k: cols[k][idx] for k in vary})
        try:
            out = _run_batch(layout.put((lanes.material, lanes.basal)), shared, how, layout, pacer)
        except KeyboardInterrupt as e:
            note = _interrupted_note(len(done), n, keep)
            raise mpmjax.Interrupted(getattr(e, "signum", signal.SIGINT), note) from None
        for j, k in enumerate(sel):
            done[index[k]] = tuple(a[j] for a in out)
        if keep is not None:
            _write_kept(keep, identity, done)  # atomically, after every batch: a signal loses at most this batch
        if say:
            el = time.perf_counter() - t0
            sys.stderr.write(
                f"sweep: batch {b + 1}/{n_chunks} ({len(done)}/{n} cases) elapsed {el:6.1f} s, "
                f"left ~{el / (b + 1) * (n_chunks - b - 1):6.1f} s\n"
            )
            sys.stderr.flush()
    wall = time.perf_counter() - t0
    if n:
        fronts, far, ke, lost, prof = (np.stack([np.asarray(done[i][j]) for i in index]) for j in range(5))
    else:  # a job of a --shard array with no case of its own
        nf = len(times)
        fronts, far, ke = (np.zeros((0, nf)) for _ in range(3))
        lost, prof = np.zeros(0, int), np.zeros((0, len(x_prof)))
    rest = np.asarray([mpmjax.time_to_rest(times, k) for k in ke]).reshape(-1)
    return {
        "scene": cfg["name"],
        "overrides": overrides,
        "vary": {k: list(v) for k, v in vary.items()},
        "cases": cases_run,
        "case_index": np.asarray(list(share), int),
        "n_cases": n_all,
        "shard": None if shard is None else list(shard),
        "times_s": times,
        "runout_m": fronts,
        "final_runout_m": fronts[:, -1],
        "runout_definition": (
            "free-surface front (docs/output.md 'Runout')" if _on_profile(sc, axis) else "farthest particle"
        ),
        "runout_farthest_particle_m": far,
        "final_runout_farthest_particle_m": far[:, -1],
        "kinetic_energy_J": ke,
        "time_to_rest_s": rest,
        "n_lost": lost,
        "profile_x_m": x_prof,
        "profile_h_m": prof,
        "dt_s": sc.dt,
        "chunk": ch,
        "n_devices": n_dev,
        "n_processes": jax.process_count(),
        "n_particles": sc.n_particles,
        "n_steps": sc.n_steps,
        "wall_s": wall,
        "cases_resumed": n - len(todo),
        "dim": sc.dim,
    }


def kept_name(shard=None) -> str:
    """The file of a sweep's finished cases while it is not complete (``sweep(keep=...)``):
    ``sweep-partial.npz``, or ``part-I-of-N.partial.npz`` for job I of a ``--shard`` array."""
    return "sweep-partial.npz" if shard is None else f"part-{shard[0]}-of-{shard[1]}.partial.npz"


def _identity(cfg: dict, vary: dict, shard, profile_x_m) -> dict:
    """What makes two runs the same sweep, whose finished cases one may take from the other."""
    return {
        "scene": cfg["name"],
        "config_hash": mpmjax.config_hash(cfg),
        "vary": {k: [float(x) for x in v] for k, v in vary.items()},
        "shard": None if shard is None else [int(shard[0]), int(shard[1])],
        "profile_x_m": None if profile_x_m is None else [float(x) for x in np.asarray(profile_x_m).ravel()],
    }


_KEPT_ARRAYS = ("case_index", "runout_m", "runout_farthest_particle_m", "kinetic_energy_J", "n_lost", "profile_h_m")
_WHAT = {
    "scene": "the scene",
    "config_hash": "the scene's keys or --set overrides",
    "vary": "--vary",
    "shard": "--shard",
    "profile_x_m": "the profile points",
}


def _write_npz(path: Path, doc: dict, arrays: dict) -> None:
    """``path`` (npz: ``doc`` as JSON in ``shared``, and ``arrays``) through a temporary file, an
    fsync and an atomic rename: a reader sees the old file or the new one, never half of one."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            np.savez(f, shared=np.asarray(json.dumps(_jsonable(doc))), **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _write_kept(path: Path, identity: dict, done: dict) -> None:
    """The finished cases ``done`` (case index -> (front, farthest, kinetic energy per frame,
    lost, profile)) to ``path``."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    ii = sorted(done)
    arrays = {"case_index": np.asarray(ii, int)}
    for j, k in enumerate(_KEPT_ARRAYS[1:]):
        arrays[k] = np.stack([np.asarray(done[i][j]) for i in ii])
    _write_npz(Path(path), {"identity": identity}, arrays)


def _read_kept(path: Path, identity: dict, resume: bool) -> dict | None:
    """The finished cases in ``path`` (``_write_kept``) when they are of the sweep ``identity``;
    None where there is no file (``ValueError`` with ``resume``); ``ValueError`` naming what
    differs where they are of another sweep, and naming the file where it cannot be read."""
    folder = path.parent
    if not path.is_file():
        if resume:
            complete = (folder / "sweep.json").is_file() or any(folder.glob("part-*-of-*.npz"))
            raise ValueError(
                f"--resume: no unfinished sweep in {folder} ({path.name} not there)"
                + ("; the sweep there is complete" if complete else "")
                + "; allowed: the --out of an interrupted sweep (or leave --resume out to start one)"
            )
        return None
    try:
        with np.load(path) as z:
            doc = json.loads(str(z["shared"]))
            arrays = {k: np.asarray(z[k]) for k in _KEPT_ARRAYS}
        old = doc["identity"]
        if not isinstance(old, dict):
            raise TypeError("identity is not a table")
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as e:
        raise ValueError(
            f"{path}: the finished cases of an interrupted sweep cannot be read ({type(e).__name__}: {e}); "
            f"allowed: a file written by mpmjax sweep (move it away to start the sweep afresh)"
        ) from None
    diff = [k for k in _WHAT if json.dumps(old.get(k)) != json.dumps(identity[k])]
    if diff:
        raise ValueError(
            f"--out {folder}: {path.name} holds {len(arrays['case_index'])} finished case(s) of another sweep "
            f"(it differs in {', '.join(_WHAT[k] for k in diff)}); allowed: the same command to continue it, or "
            f"another --out (or move {path.name} away to start afresh: its cases would be lost)"
        )
    cols = [arrays[k] for k in _KEPT_ARRAYS[1:]]
    return {int(i): tuple(c[j] for c in cols) for j, i in enumerate(arrays["case_index"])}


def _interrupted_note(n_done: int, n: int, keep) -> str:
    """The one line of an interrupted sweep: what is kept and how to continue."""
    if keep is None:
        return f"interrupted: {n_done} of {n} cases had finished (not kept: no output folder)"
    if not n_done:
        return f"interrupted before any of the {n} cases finished; nothing was kept"
    return (
        f"interrupted: {n_done} of {n} cases finished and are kept in {keep}; run the same command again "
        f"(or with --resume) to run only the other {n - n_done}"
    )


def _jsonable(v):
    """``v`` with numpy arrays and scalars as lists and numbers, non-finite floats as None."""
    if isinstance(v, np.ndarray):
        return [_jsonable(a) for a in v.tolist()] if v.ndim else _jsonable(v.item())
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, (list, tuple)):
        return [_jsonable(a) for a in v]
    if isinstance(v, dict):
        return {k: _jsonable(a) for k, a in v.items()}
    if isinstance(v, (np.floating, np.integer)):
        return _jsonable(v.item())
    return v


def write_sweep(res: dict, out) -> list[Path]:
    """Write ``sweep.csv`` (one row per case: varied values, final runout [m], time to rest
    [s], lost particles), ``sweep.json`` (everything, with per-frame series) and plots
    (``sweep_figures``: ``sweep_runout.png``, final runout against each varied parameter;
    ``sweep_profiles.png``, final height profiles) to the folder ``out``.  Returns the paths."""
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = list(res["vary"])
    units = {"runout": "m", "time_to_rest": "s"}
    lines = [",".join(names + ["final_runout_m", "time_to_rest_s", "n_lost"])]
    for i, c in enumerate(res["cases"]):
        lines.append(
            ",".join(
                [f"{c[k]:.6g}" for k in names]
                + [f"{res['final_runout_m'][i]:.6g}", f"{res['time_to_rest_s'][i]:.6g}", str(int(res["n_lost"][i]))]
            )
        )
    mpmjax.atomic_write_text(out / "sweep.csv", "\n".join(lines) + "\n")

    doc = {k: _jsonable(v) for k, v in res.items()}
    doc["units"] = {
        "final_runout_m": "m",
        "time_to_rest_s": "s",
        "times_s": "s",
        "runout_m": "m",
        "runout_farthest_particle_m": "m",
        "final_runout_farthest_particle_m": "m",
        "kinetic_energy_J": "J (2D: J per metre of depth)",
        "profile_x_m": "m",
        "profile_h_m": "m",
        "dt_s": "s",
        "wall_s": "s",
    }
    mpmjax.atomic_write_text(out / "sweep.json", json.dumps(doc, indent=1))
    del units
    paths = [out / "sweep.csv", out / "sweep.json"]
    for name, fig in sweep_figures(res).items():
        tmp = out / f".{name}.{os.getpid()}.tmp.png"
        try:
            fig.savefig(tmp, dpi=110)  # then renamed: a signal never leaves half a picture
            os.replace(tmp, out / name)
        finally:
            plt.close(fig)
            tmp.unlink(missing_ok=True)
        paths.append(out / name)
    return paths


# per-case entries of a sweep result (lanes first), the rest is shared by all cases
PER_CASE = (
    "case_index",
    "runout_m",
    "final_runout_m",
    "runout_farthest_particle_m",
    "final_runout_farthest_particle_m",
    "kinetic_energy_J",
    "time_to_rest_s",
    "n_lost",
    "profile_h_m",
)
# shared entries that every part of one sweep must agree on
_SAME = ("scene", "overrides", "vary", "n_cases", "dt_s", "times_s", "profile_x_m", "n_particles", "n_steps", "dim")


def part_name(shard) -> str:
    """File name of job I of N's results: ``part-I-of-N.npz``."""
    return f"part-{shard[0]}-of-{shard[1]}.npz"


def write_part(res: dict, out) -> Path:
    """Write the result of ``sweep(..., shard=(I, N))`` to ``out/part-I-of-N.npz`` (numpy's npz:
    the per-case arrays, and the rest as JSON) through a temporary file and an atomic rename, so
    ``merge_parts`` never reads half a part.  Returns the path."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / part_name(res["shard"])
    shared = {k: v for k, v in res.items() if k not in PER_CASE and k != "cases"}
    arrays = {k: np.asarray(res[k]) for k in PER_CASE}
    names = list(res["vary"])
    arrays["cases"] = np.asarray([[c[k] for k in names] for c in res["cases"]], float).reshape(-1, len(names))
    _write_npz(path, shared, arrays)
    return path


def merge_parts(folder) -> dict:
    """The whole sweep from the parts ``folder/part-I-of-N.npz`` of one ``--shard`` job array:
    the same dict as ``sweep`` without ``shard`` (``wall_s`` is the sum over the parts, ``parts``
    their number).  Raises ``ValueError`` naming the missing, extra or mismatching parts."""
    folder = Path(folder)
    found = {}
    for p in sorted(folder.glob("part-*-of-*.npz")):
        m = re.fullmatch(r"part-(\d+)-of-(\d+)\.npz", p.name)
        if m:
            found[(int(m.group(1)), int(m.group(2)))] = p
    if not found:
        raise ValueError(f"{folder}: no part-I-of-N.npz files (written by mpmjax sweep --shard I/N --out {folder})")
    counts = sorted({k for _, k in found})
    if len(counts) > 1:
        raise ValueError(f"{folder}: parts of job arrays of different sizes N = {counts}; allowed: one N per folder")
    n_jobs = counts[0]
    missing = [i for i in range(n_jobs) if (i, n_jobs) not in found]
    if missing:
        raise ValueError(
            f"{folder}: {len(missing)} of {n_jobs} parts missing (jobs {', '.join(map(str, missing[:20]))}"
            f"{' ...' if len(missing) > 20 else ''}); rerun them with --shard I/{n_jobs}"
        )
    parts = []
    for i in range(n_jobs):
        path = found[(i, n_jobs)]
        try:
            with np.load(path) as z:
                doc = json.loads(str(z["shared"]))
                doc.update({k: z[k] for k in PER_CASE})
                doc["cases"] = [dict(zip(doc["vary"], map(float, row), strict=True)) for row in z["cases"]]
        except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as e:
            raise ValueError(
                f"{path}: not a readable part of `mpmjax sweep --shard` ({type(e).__name__}: {e}); rerun job {i} "
                f"with --shard {i}/{n_jobs}"
            ) from None
        parts.append(doc)
    first = parts[0]
    for i, d in enumerate(parts[1:], 1):
        bad = [k for k in _SAME if json.dumps(d[k]) != json.dumps(first[k])]
        if bad:
            raise ValueError(
                f"{folder}: {part_name((i, n_jobs))} differs from {part_name((0, n_jobs))} in {', '.join(bad)}: "
                "the parts come from different sweeps"
            )
    res = dict(first)
    for k in PER_CASE:
        res[k] = np.concatenate([np.asarray(d[k]) for d in parts])
    res["cases"] = [c for d in parts for c in d["cases"]]
    if not np.array_equal(res["case_index"], np.arange(first["n_cases"])):
        raise ValueError(f"{folder}: the parts do not cover cases 0 .. {first['n_cases'] - 1} once each")
    for k in ("times_s", "profile_x_m"):
        res[k] = np.asarray(res[k], float)
    res["time_to_rest_s"] = np.asarray(res["time_to_rest_s"], float)
    res.update(shard=None, parts=n_jobs, wall_s=float(sum(d["wall_s"] for d in parts)))
    return res


def _print_sweep(res, paths, how):
    names = list(res["vary"])
    print(
        " ".join(f"{k:>10s}" for k in names) + f" {'runout [m]':>11s} {'rest [s]':>9s} {'lost':>5s}",
        file=sys.stderr,
    )
    for i, c in enumerate(res["cases"]):
        print(
            " ".join(f"{c[k]:10.4g}" for k in names)
            + f" {res['final_runout_m'][i]:11.4f} {res['time_to_rest_s'][i]:9.3g} {int(res['n_lost'][i]):5d}",
            file=sys.stderr,
        )
    print(f"sweep: {len(res['cases'])} cases {how}; wrote {', '.join(str(p) for p in paths)}", file=sys.stderr)


def run_sweep(
    scene,
    vary: dict,
    *,
    overrides=None,
    chunk: int | None = None,
    out="sweep-out",
    quiet: bool = False,
    devices: int | None = None,
    shard: tuple[int, int] | None = None,
    coordinator: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    distributed: bool = False,
    resume: bool = False,
) -> dict:
    """The whole of ``mpmjax sweep`` as one call: ``sweep`` over ``vary`` (``parse_vary``'s dict)
    on ``devices`` host devices, in one ``jax.distributed`` job (``coordinator``, ...,
    ``calibration.distributed``) or as the job ``shard = (I, N)`` of an array; writes ``out``
    (``write_sweep``, or ``write_part`` for a shard; only process 0 of a distributed job), prints
    the table unless ``quiet`` and returns ``sweep``'s dict.  Must run before any JAX computation
    of the process (the host devices and the distributed job are set up first).

    The finished cases are kept in ``out`` (``kept_name``) after every batch until the outputs are
    written: an interrupted sweep run again (the same command, or with ``resume``) runs only the
    cases not finished.  Not in a ``jax.distributed`` job, whose processes would each have to read
    the same file to agree on the cases left (its batches are still chunked)."""
    options = check_join_options(coordinator, num_processes, process_id, distributed)
    make_local_devices(devices)
    if shard is not None and options is not None:
        raise DistributedError(
            "--shard and --coordinator / --num-processes / --process-id / --distributed both given; allowed: one "
            "(--shard: independent jobs merged by `mpmjax sweep-merge`; the others: one jax.distributed job)"
        )
    join(options)  # before any JAX computation; nothing for a single-process run
    check_local_devices(devices)
    writer = is_writer()
    keep = Path(out) / kept_name(shard) if options is None else None
    if resume and keep is None:
        raise DistributedError(
            "--resume is not available in a jax.distributed job; allowed: a single-process sweep or --shard"
        )
    res = sweep(
        scene, vary, overrides=overrides, chunk=chunk, progress=not quiet, shard=shard, keep=keep, resume=resume
    )
    how = (
        f"in batches of {res['chunk']} on {res['n_devices']} device(s) of {res['n_processes']} process(es), "
        f"{res['wall_s']:.1f} s"
    )
    if shard is not None:
        path = write_part(res, out)
        keep.unlink(missing_ok=True)  # the part has every case now
        if not quiet:
            ci = res["case_index"]
            share = f"cases {ci[0]} .. {ci[-1]}" if len(ci) else "no case"
            _print_sweep(res, [path], f"(job {shard[0]} of {shard[1]}: {share} of {res['n_cases']}) {how}")
        return res
    if not writer:  # the other processes of a distributed job leave --out to process 0
        return res
    paths = write_sweep(res, out)
    if keep is not None:
        keep.unlink(missing_ok=True)  # sweep.json has every case now
    if not quiet:
        _print_sweep(res, paths, how)
    return res


def merge_sweep(parts, out=None, quiet: bool = False) -> dict:
    """The whole of ``mpmjax sweep-merge``: ``merge_parts(parts)`` written to ``out`` (default: the
    parts' folder) as ``write_sweep`` writes a sweep; prints the table unless ``quiet``."""
    res = merge_parts(parts)
    paths = write_sweep(res, out or parts)
    if not quiet:
        _print_sweep(res, paths, f"from {res['parts']} part(s), {res['wall_s']:.1f} s of wall time in all")
    return res


NO_SENSITIVITY_M = 1e-3  # a spread of the results below this [m] is reported as "no sensitivity"


def _ranges(res) -> str:
    """The varied parameters' ranges for plot titles: ``n = 1.5-3 (4 values), mu0 = 1-4 (2 values)``."""
    parts = []
    for k, v in res["vary"].items():
        lo, hi = min(v), max(v)
        span = f"{lo:g}" if lo == hi else f"{lo:g}–{hi:g}"
        parts.append(f"{k} = {span} ({len(set(v))} value{'s' if len(set(v)) != 1 else ''})")
    return ", ".join(parts)


def _plain_axes(ax):
    """Absolute tick labels: no offset (``+1.19``) and no scientific notation on a linear axis."""
    for axis in ("x", "y"):
        if getattr(ax, f"get_{axis}scale")() == "linear":
            ax.ticklabel_format(axis=axis, useOffset=False, style="plain")


def sweep_figures(res: dict) -> dict:
    """The sweep's plots as matplotlib Figures, by file name: ``sweep_runout.png`` (final runout
    against each varied parameter, one line per combination of the others) and, in 2D,
    ``sweep_profiles.png`` (final height profiles).  Axes are absolute (no offset notation);
    titles give the parameter ranges; a panel where the results vary by less than
    ``NO_SENSITIVITY_M`` (1 mm) says "no sensitivity" and is drawn on a y range of at least
    1 cm, so that rounding-level differences do not show as steep lines."""
    # matplotlib only when plots are made (optional heavy import)
    import matplotlib.pyplot as plt

    names = list(res["vary"])
    rng = _ranges(res)
    figs = {}
    fig, axes = plt.subplots(1, len(names), figsize=(4.4 * len(names), 3.6), squeeze=False)
    final = np.asarray(res["final_runout_m"], float)
    for j, k in enumerate(names):
        ax = axes[0, j]
        others = [o for o in names if o != k]
        groups = {}
        for i, c in enumerate(res["cases"]):
            groups.setdefault(tuple(c[o] for o in others), []).append(i)
        spread = 0.0  # largest change of the final runout with k alone (the others fixed)
        for key, ii in groups.items():
            ii = sorted(ii, key=lambda i: res["cases"][i][k])
            vals = final[ii]
            fin = vals[np.isfinite(vals)]
            if fin.size:
                spread = max(spread, float(fin.max() - fin.min()))
            lab = ", ".join(f"{o}={v:g}" for o, v in zip(others, key, strict=True)) or None
            ax.plot([res["cases"][i][k] for i in ii], vals, "o-", label=lab)
        fin = final[np.isfinite(final)]
        if fin.size and float(fin.max() - fin.min()) < 0.01:
            mid = 0.5 * float(fin.max() + fin.min())
            ax.set_ylim(mid - 0.005, mid + 0.005)
        if spread < NO_SENSITIVITY_M:
            ax.text(
                0.5, 0.5, f"no sensitivity\n(final runout changes by {1e3 * spread:.2g} mm < 1 mm)",
                transform=ax.transAxes, ha="center", va="center", fontsize=9, color="#a00000",
                bbox=dict(boxstyle="round", fc="white", ec="#a00000", alpha=0.9),
            )
        field = FIELD_KEYS.get(k)
        ax.set_xlabel(f"{k}" + (f" ({field})" if field else ""))
        ax.set_ylabel("final runout [m]")
        vals_k = [c[k] for c in res["cases"]]
        ax.set_title(f"{k} = {min(vals_k):g}–{max(vals_k):g}: spread {1e3 * spread:.3g} mm", fontsize=9)
        _plain_axes(ax)
        ax.grid(alpha=0.3)
        if others and len(groups) <= 8:
            ax.legend(fontsize=7)
    fig.suptitle(f"{res['scene']}: final runout at t = {res['times_s'][-1]:g} s; {rng}", fontsize=10)
    fig.tight_layout()
    figs["sweep_runout.png"] = fig
    if res.get("dim", 2) == 2:
        fig, ax = plt.subplots(figsize=(7.5, 3.6))
        hp = np.asarray(res["profile_h_m"], float)
        for i, c in enumerate(res["cases"]):
            ax.plot(res["profile_x_m"], hp[i], lw=1, label=", ".join(f"{k}={c[k]:g}" for k in names))
        spread = float(np.nanmax(np.nanmax(hp, axis=0) - np.nanmin(hp, axis=0))) if hp.size else 0.0
        if spread < NO_SENSITIVITY_M:
            ax.text(
                0.5, 0.5, f"no sensitivity\n(profiles differ by at most {1e3 * spread:.2g} mm < 1 mm)",
                transform=ax.transAxes, ha="center", va="center", fontsize=9, color="#a00000",
                bbox=dict(boxstyle="round", fc="white", ec="#a00000", alpha=0.9),
            )
        ax.set_xlabel("x [m]")
        ax.set_ylabel("height h [m]")
        ax.set_title(
            f"{res['scene']}: final height profiles at t = {res['times_s'][-1]:g} s\n{rng}; "
            f"largest difference {1e3 * spread:.3g} mm",
            fontsize=9,
        )
        _plain_axes(ax)
        ax.grid(alpha=0.3)
        if len(res["cases"]) <= 12:
            ax.legend(fontsize=6)
        fig.tight_layout()
        figs["sweep_profiles.png"] = fig
    return figs
