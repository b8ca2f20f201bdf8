"""Time integration: nested ``lax.scan`` (frames x steps) with ``jax.checkpoint``.

``simulate(scene, state, params)`` is the differentiable path: an outer scan over
the ``n_frames`` saved frames and an inner scan over ``steps_per_frame`` steps.
The inner chunk is wrapped in ``jax.checkpoint``, so reverse-mode memory grows with
the number of frames (plus one chunk's residuals), not with the number of steps.
There is no ``while_loop`` on this path.

``make_advance(scene)`` returns the jitted one-frame advance used by the command line,
which calls it frame by frame so that it can show progress and write each frame to
disk as soon as it exists.  Both paths share the same step and give the same numbers.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ._scene import Params, Scene, State
from ._step import make_step


class Frame(NamedTuple):
    """What is saved per frame: positions [m], velocities [m/s], volume ratio J [-],
    effective viscosity [Pa s], the rheology's internal fields, the active mask and
    the time [s]."""

    x: jnp.ndarray
    v: jnp.ndarray
    J: jnp.ndarray
    mu: jnp.ndarray
    internal: dict
    active: jnp.ndarray
    t: jnp.ndarray


def frame_of(state: State) -> Frame:
    return Frame(state.x, state.v, state.J, state.mu, state.internal, state.active, state.t)


def make_chunk(scene: Scene, n_steps: int | None = None):
    """``chunk(state, params) -> state``: ``n_steps`` (default steps_per_frame) steps by
    ``lax.scan``, wrapped in ``jax.checkpoint``."""
    step = make_step(scene)
    length = scene.steps_per_frame if n_steps is None else n_steps

    def chunk(state, params):
        def body(s, _):
            return step(s, params), None

        return jax.lax.scan(body, state, None, length=length)[0]

    return jax.checkpoint(chunk)


def simulate(scene: Scene, state: State, params: Params, n_frames: int | None = None):
    """Run ``n_frames`` frames (default ``scene.n_frames``).  Pure and differentiable.

    Returns ``(final_state, frames)`` where ``frames`` is a ``Frame`` whose arrays have a
    leading axis of length n_frames (the state *after* each frame).  Use under ``jit``
    with ``scene`` static, e.g. ``jax.jit(simulate, static_argnums=(0, 3))``.
    """
    chunk = make_chunk(scene)
    nf = scene.n_frames if n_frames is None else n_frames

    def outer(s, _):
        s = chunk(s, params)
        return s, frame_of(s)

    return jax.lax.scan(outer, state, None, length=nf)


_jit_simulate = jax.jit(simulate, static_argnums=(0, 3))


def run(scene: Scene, state: State, params: Params, n_frames: int | None = None):
    """Jitted ``simulate`` (compiled once per scene and shapes)."""
    return _jit_simulate(scene, state, params, n_frames)


def make_advance(scene: Scene):
    """Jitted ``advance(state, params) -> state`` over one frame (for host-side loops)."""
    return jax.jit(make_chunk(scene))
