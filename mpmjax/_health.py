"""Run health checks for the command line: stop a run that has gone wrong, and say why.

After each frame ``mpmjax run`` compares the new state with the last good one
(``check``).  A problem is any of, over the active particles:

* ``nonfinite``: NaN or inf in a position, velocity, J, viscosity, stress or internal field;
* ``jacobian``: a volume ratio J outside [``J_MIN``, ``J_MAX``] (a weakly compressible
  material never gets there: the Tait pressure at J = 0.1 is ~2000 bulk moduli);
* ``lost``: a particle deactivated by the step because its state became non-finite,
  its J non-positive, or it left the grid anywhere but through an ``open`` face (leaving
  through an open face is outflow, not a failure);
* ``cfl``: a particle moving more than ``CFL_MAX`` cells per step, |v| dt / h > 1.

The step itself deactivates particles with a non-finite state or J <= 0 (``_step``), so
those show up as ``lost``.  On a problem, ``locate`` replays the frame one step at a time
from the last good state to find the first step at which a check fails.
"""

from __future__ import annotations

import jax
import numpy as np

from ._simulate import make_chunk

CFL_MAX = 1.0
J_MIN, J_MAX = 0.1, 10.0

HINTS = {
    "cfl": (
        "the time step is too large for the speeds reached: lower numerics.cfl, set numerics.dt_s smaller, "
        "or raise numerics.velocity_scale_m_s to the fastest speed expected (0 = the free-fall estimate)"
    ),
    "nonfinite": (
        "a numerical blow-up: usually a time step above the stability limit (lower numerics.cfl or "
        "numerics.dt_s) or extreme material parameters"
    ),
    "jacobian": (
        "the material was compressed or stretched far beyond a weakly compressible state: the time step is "
        "too large (lower numerics.cfl) or the bulk modulus material.bulk_modulus_pa too low for the speeds"
    ),
    "lost": (
        "particles are removed when their state becomes non-finite, their J non-positive or they leave the grid "
        "through a wall; this follows a numerical instability (lower numerics.cfl or numerics.dt_s) or material "
        "moving faster than the time step allows"
    ),
}


class RunFailure(RuntimeError):
    """A run stopped by a failed health check.  ``info`` is a JSON-able dict: ``kind``,
    ``particle``, ``position_m``, ``t_s``, ``frame``, ``step`` (or ``None``), ``first_step``,
    ``last_step``, ``message``, ``hint``, ``others``."""

    def __init__(self, info: dict):
        self.info = info
        super().__init__(info["error"])


def _fmt_pos(x) -> str:
    return ", ".join(f"{a} = {float(c):.4g} m" for a, c in zip("xyz", x))


def open_faces(cfg: dict) -> list[tuple[int, int]]:
    """(axis, side) of every ``open`` domain face (side 0: lo, 1: hi)."""
    out = []
    for a in range(cfg["domain.dim"]):
        for side, end in enumerate(("lo", "hi")):
            if cfg[f"boundary.{'xyz'[a]}_{end}"] == "open":
                out.append((a, side))
    return out


def outflow_mask(scene, cfg, x) -> np.ndarray:
    """Particles at ``x`` within one cell of (or beyond) an open face: their loss is outflow."""
    m = np.zeros(len(x), bool)
    for a, side in open_faces(cfg):
        if side == 0:
            m |= x[:, a] < scene.lo[a] + scene.h
        else:
            m |= x[:, a] > scene.hi[a] - scene.h
    return m


def check(scene, cfg, prev, cur, consecutive: bool = False) -> tuple[list[dict], np.ndarray]:
    """Problems in ``cur`` (a State after ``prev``; one step after it if ``consecutive``),
    worst first, and the indices of the particles that left through an open face (outflow)
    between the two."""
    act = np.asarray(cur.active)
    was = np.asarray(prev.active)
    x, v = np.asarray(cur.x, float), np.asarray(cur.v, float)
    probs = []

    fields = {"x": cur.x, "v": cur.v, "J": cur.J, "mu": cur.mu, "tau": cur.tau}
    fields.update({f"internal {k}": a for k, a in cur.internal.items()})
    bad = np.zeros(len(act), bool)
    which = {}
    for name, arr in fields.items():
        a = np.asarray(arr)
        fin = np.isfinite(a).reshape(len(a), -1).all(axis=1)
        new = act & ~fin & ~bad
        for i in np.flatnonzero(new):
            which[int(i)] = name
        bad |= act & ~fin
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        probs.append(
            dict(
                kind="nonfinite",
                particle=i,
                position_m=x[i].tolist(),
                message=f"non-finite {which[i]} (NaN/inf) at particle {i} ({_fmt_pos(x[i])}); "
                f"{int(bad.sum())} particle(s) affected",
            )
        )

    # a deactivated particle keeps the position and J it had before the step that removed it
    newly = was & ~act
    outflow = newly & outflow_mask(scene, cfg, x)
    lost = newly & ~outflow
    if lost.any():
        i = int(np.flatnonzero(lost)[0])
        jl = float(np.asarray(cur.J)[i])
        speed = ""
        if consecutive:  # prev is the state one step before the loss
            speed = f"|v| = {float(np.linalg.norm(np.asarray(prev.v, float)[i])):.3g} m/s, "
        probs.append(
            dict(
                kind="lost",
                particle=i,
                position_m=x[i].tolist(),
                message=f"{int(lost.sum())} particle(s) lost (state non-finite, J <= 0, or left the grid through a "
                f"wall), first particle {i}, last seen at {_fmt_pos(x[i])} with {speed}J = {jl:.4g}",
            )
        )

    J = np.asarray(cur.J, float)
    badj = act & np.isfinite(J) & ((J < J_MIN) | (J > J_MAX))
    if badj.any():
        idx = np.flatnonzero(badj)
        i = int(idx[np.argmax(np.abs(np.log(np.abs(J[idx]) + 1e-300)))])
        word = "non-positive" if J[i] <= 0 else "absurd"
        probs.append(
            dict(
                kind="jacobian",
                particle=i,
                position_m=x[i].tolist(),
                message=f"{word} Jacobian J = {J[i]:.4g} at particle {i} ({_fmt_pos(x[i])}); allowed "
                f"[{J_MIN}, {J_MAX}]; {int(badj.sum())} particle(s) outside",
            )
        )

    speed = np.where(act & np.isfinite(v).all(axis=1), np.linalg.norm(np.nan_to_num(v), axis=1), 0.0)
    courant = speed * scene.dt / scene.h
    if courant.size and courant.max() > CFL_MAX:
        i = int(np.argmax(courant))
        probs.append(
            dict(
                kind="cfl",
                particle=i,
                position_m=x[i].tolist(),
                message=f"CFL violated: |v| = {speed[i]:.3g} m/s at particle {i} ({_fmt_pos(x[i])}), "
                f"|v| dt/h = {courant[i]:.3g} > {CFL_MAX:g} (dt = {scene.dt:.4g} s, h = {scene.h:g} m); "
                f"{int((courant > CFL_MAX).sum())} particle(s) above",
            )
        )
    return probs, np.flatnonzero(outflow)


def locate(scene, params, cfg, start, max_steps: int | None = None):
    """Replay one frame step by step from ``start`` (the last good state) and return
    ``(step_in_frame, state_before, state_after, problems)`` for the first step whose
    state fails ``check``, or ``None`` if no single step fails (the replay is a separately
    compiled program and may differ from the frame in the last bits)."""
    one = jax.jit(make_chunk(scene, 1))
    n = scene.steps_per_frame if max_steps is None else min(max_steps, scene.steps_per_frame)
    st = start
    for k in range(n):
        nxt = one(st, params)
        probs, _ = check(scene, cfg, st, nxt, consecutive=True)
        if probs:
            return k, st, nxt, probs
        st = nxt
    return None


def failure(scene, params, cfg, prev, cur, probs, frame: int, log=None, replay_max_steps: int = 20000) -> RunFailure:
    """Build the ``RunFailure`` for frame ``frame`` (1-based: the frame from ``prev`` to ``cur``)
    that failed with ``probs``: the first bad step by a step-by-step replay (up to
    ``replay_max_steps`` steps), else the frame's step range."""
    spf = scene.steps_per_frame
    first, last = (frame - 1) * spf + 1, frame * spf
    step, t = None, float(np.asarray(cur.t))
    if spf > 1 and spf <= replay_max_steps:
        if log:
            log(f"\nlocating the first failing step of frame {frame} (steps {first}..{last}) ...")
        found = locate(scene, params, cfg, prev)
        if found is not None:
            k, _, after, probs = found
            step = first + k
            t = float(np.asarray(after.t))
    elif spf == 1:
        step = first
    p = probs[0]
    where = f"step {step}" if step is not None else f"steps {first}..{last}"
    hint = HINTS[p["kind"]]
    if p["kind"] == "lost" and scene.devices > 1 and scene.decomposition == "slab":
        hint += (
            f"; or, with numerics.decomposition = 'slab', a device ran out of particle slots and dropped them "
            f"(then the particle's last state is finite and inside the grid): raise numerics.slab_capacity "
            f"(now {scene.slab_capacity:g})"
        )
    error = f"run failed at {where} (frame {frame}), t = {t:.6g} s: {p['message']}. Likely cause: {hint}."
    if len(probs) > 1:
        error += " Also: " + "; ".join(q["message"] for q in probs[1:]) + "."
    info = dict(
        error=error,
        kind=p["kind"],
        particle=p["particle"],
        position_m=p["position_m"],
        t_s=t,
        frame=frame,
        step=step,
        first_step=first,
        last_step=last,
        message=p["message"],
        hint=hint,
        others=[q["message"] for q in probs[1:]],
    )
    return RunFailure(info)
