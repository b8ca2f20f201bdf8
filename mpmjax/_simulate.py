"""Time integration: nested ``lax.scan`` (frames x steps) with ``jax.checkpoint``.

``simulate(scene, state, params)`` is the differentiable path: an outer scan over
the ``n_frames`` saved frames and an inner scan over ``steps_per_frame`` steps.
The inner chunk is wrapped in ``jax.checkpoint``, so reverse-mode memory grows with
the number of frames (plus one chunk's states), not with the number of steps; a run whose
every step's state and saved values fit in ``STORE_STATES_BYTES`` keeps them all instead and is
not recomputed.
There is no ``while_loop`` on this path.

``make_advance(scene)`` returns the jitted one-frame advance used by the command line,
which calls it frame by frame so that it can show progress and write each frame to
disk as soon as it exists.  Both paths share the same step and give the same numbers.

Staged capacity (pipe inflow): until its layer is released a pool particle is inactive
and carries no mass, yet a step over the whole buffer costs the same for it as for an
active one.  The release schedule is static and the pool is ordered by release time
(``_scene.Inflow``), so ``capacity_schedule(scene)`` gives, per frame, a prefix of the
buffer that holds every particle that can be active by the end of that frame; the
prefixes are a few fixed sizes halving down from the full buffer (one compilation
each).  ``make_prefix_advance(scene, n)`` steps only particles [0, n) and carries the
rest, which are inactive and which the step leaves unchanged, as they are.  Every
operation of a step is per particle or a scatter in particle order to which inactive
particles add exact zeros, so the result is the full-buffer advance's up to the rounding
of XLA programs compiled for other array sizes (measured: 1e-14 m in float64 over 9
frames of a pour, tests/test_skips.py); a staged run resumed from its checkpoint runs the
same programs and is bit for bit the uninterrupted staged run.
``StagedAdvance`` drives it frame by frame for the command line; ``simulate`` (the
differentiable path used by calibration) always steps the full buffer.

Staged spare slots (column splitting, ``_split``): a depth-averaged scene reserves its split's
children slots at the end of the buffer, inactive with volume 0, and the split fills them in buffer
order.  The command line steps a prefix that holds every slot in use and room for more
(``split_prefix_sizes``: the seeded columns and the pool's first half, quarter or eighth), chosen
before each frame from the state, and reruns the frame on the next size up if its splits filled
the prefix (a split refused for want of a slot is the only way the prefix changes the result), so a
run that splits little pays for the slots it uses (measured: ``dambreak-lab`` as columns at 8 a cell
and h = 5 mm, 1280 slots in all, 440 stepped, loop wall 6.6 s against 16.8 s, the same positions).
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ._fusion import SAVED, on_cpu
from ._received import check
from ._scene import Params, Scene, State
from ._shard import AXIS
from ._slab import make_slab_advance
from ._split import spare_slots
from ._step import make_step


class Frame(NamedTuple):
    """What is saved per frame: positions [m], velocities [m/s], volume ratio J [-],
    effective viscosity [Pa s], the rheology's internal fields, the active mask, the time [s]
    and, only where the depth-averaged step splits columns (``_split``), the particles' rest
    volumes [m^3; 2D: m^2]; None elsewhere, where they are the state's constant ``vol0``."""

    x: jnp.ndarray
    v: jnp.ndarray
    J: jnp.ndarray
    mu: jnp.ndarray
    internal: dict
    active: jnp.ndarray
    t: jnp.ndarray
    vol0: jnp.ndarray | None = None


def frame_of(state: State, scene: Scene | None = None) -> Frame:
    """The frame of ``state``; the volumes only where ``scene`` splits columns (a run pays only for them there)."""
    split = scene is not None and scene.split_levels > 0
    return Frame(state.x, state.v, state.J, state.mu, state.internal, state.active, state.t,
                 state.vol0 if split else None)


# Reverse mode through ``simulate`` keeps every step's input state and saved values
# (``residual_bytes``), instead of recomputing each chunk once more, when they take at most this
# many bytes (per run: a vmap batch of B runs holds B times as much): 1000 steps of the default
# scene (3600 particles, 238 kB a state, 186 kB saved) take 424 MB.  It saves one forward pass of
# the run (docs/performance.md, "Fusion boundaries": 4.44-4.47 -> 3.64-3.86 forward runs for that
# gradient when it was added).
STORE_STATES_BYTES = 512 * 2**20


def make_chunk(scene: Scene, n_steps: int | None = None, recompute: bool = True):
    """``chunk(state, params) -> state``: ``n_steps`` (default steps_per_frame) steps by
    ``lax.scan``.

    Reverse mode: with ``recompute`` (the default) the chunk is wrapped in ``jax.checkpoint``,
    so only its input is kept and its steps run once more in the reverse pass; without, the
    input state of every step is kept instead (n_steps states of memory, one forward pass of
    the chunk less).  On XLA:CPU, and without ``recompute`` on any backend, each step is
    checkpointed too, saving only ``_fusion.SAVED`` (the grid sums and the velocity gradient,
    ``residual_bytes``): the reverse pass recomputes the rest of the step from its input state
    instead of storing the step's ~100 intermediate arrays (docs/performance.md, "Fusion
    boundaries" and "Row windows and saved residuals": on the CPU the gradient takes 0.7x the CPU
    time it took storing them all, and 0.83x that again with the two saved).
    Slab decomposition (``_slab``) always recomputes its chunk."""
    length = scene.steps_per_frame if n_steps is None else n_steps
    if scene.devices > 1 and scene.decomposition == "slab":  # slabs migrate particles between steps: _slab's own scan
        return jax.checkpoint(make_slab_advance(scene, make_step(scene, AXIS), length))
    step = make_step(scene)

    def chunk(state, params):
        per_step = on_cpu() or not recompute
        policy = jax.checkpoint_policies.save_only_these_names(*SAVED)
        one = jax.checkpoint(step, policy=policy) if per_step else step

        def body(s, _):
            return one(s, params), None

        return jax.lax.scan(body, state, None, length=length)[0]

    return jax.checkpoint(chunk) if recompute else chunk


def chunkable(scene: Scene) -> bool:
    """Whether a frame of ``scene`` can be stepped in chunks of any number of steps (``make_steps``):
    not on slabs (``numerics.decomposition = "slab"``), whose advance deals the particles out to
    the devices at the start of each call, so that a chunk boundary would change where they are
    dealt out, and with it the order of the grid sums."""
    return not (scene.devices > 1 and scene.decomposition == "slab")


def make_steps(scene: Scene):
    """``steps(state, params, n) -> state``: ``n`` steps, ``n`` an int32 that may be traced, so that
    one compiled program steps any number of them (a ``lax.fori_loop`` with a dynamic trip
    count).  A frame stepped as chunks of any lengths gives the frame's ``make_chunk`` state bit
    for bit: the loop body is the same step, compiled the same way (tests/test_chunked_frames.py).
    Forward only (no ``jax.checkpoint``: it is for the host-side drivers, which call it chunk by
    chunk so that a signal is seen between chunks: ``Pacer``).  Not on slabs (``chunkable``)."""
    if not chunkable(scene):
        raise ValueError("make_steps: slab decomposition steps whole frames only (_simulate.chunkable)")
    step = make_step(scene)

    def steps(state, params, n):
        # the per-step checkpoint of make_chunk, so that the body is compiled as it is there (it does
        # nothing in a forward pass, but is kept for the very same program)
        per_step = on_cpu()
        policy = jax.checkpoint_policies.save_only_these_names(*SAVED)
        one = jax.checkpoint(step, policy=policy) if per_step else step
        return jax.lax.fori_loop(0, n, lambda i, s: one(s, params), state)

    return steps


CHUNK_S = 1.0  # the wall time a chunk of steps aims at: a signal is acted on within about this


class Pacer:
    """How many steps the next chunk of a chunked frame takes (``make_steps``), so that a chunk
    takes about ``target_s`` of wall time and a signal is seen within seconds however long a frame
    is: it starts at ``first`` step(s) and, after each chunk (``took``), sets the count from the
    measured time per step, growing at most fourfold a chunk (the first call may include a
    compilation or a cold cache).  A frame shorter than ``target_s`` is one chunk, one call, as
    before the frames were chunked."""

    def __init__(self, target_s: float = CHUNK_S, first: int = 1):
        self.target_s, self.n = float(target_s), max(1, int(first))

    def next(self, left: int) -> int:
        """The steps of the next chunk when ``left`` steps of the frame remain."""
        return max(1, min(self.n, int(left)))

    def took(self, n: int, seconds: float) -> None:
        """A chunk of ``n`` steps took ``seconds``."""
        cap = 4 * max(self.n, int(n))
        ideal = cap if seconds <= 0 else n * self.target_s / seconds
        self.n = int(max(1, min(ideal, cap)))


def run_chunked(steps, state, n_steps: int, pacer: Pacer, between=None):
    """``n_steps`` steps of ``steps(state, n) -> state`` in chunks paced by ``pacer``: after each
    chunk the result is waited for (``jax.block_until_ready``, in which Python's signal handlers
    run) and ``between()`` is called (a driver checks there for a signal its handler could not
    raise).  Returns the state after the last step."""
    left = int(n_steps)
    while left > 0:
        n = pacer.next(left)
        t0 = time.perf_counter()
        state = jax.block_until_ready(steps(state, np.int32(n)))
        pacer.took(n, time.perf_counter() - t0)
        left -= n
        if between is not None:
            between()
    return state


def state_bytes(state: State) -> int:
    """Bytes of one state (one run's; the leaves' sizes, traced or not)."""
    return sum(int(np.prod(a.shape)) * np.dtype(a.dtype).itemsize for a in jax.tree.leaves(state))


def residual_bytes(scene: Scene, state: State) -> int:
    """Bytes the per-step checkpoint saves per step (``_fusion.SAVED``): the grid sums (mass,
    momentum and, but with the MLS force, force on every node) and the velocity gradient (n, dim, dim)."""
    itemsize = np.dtype(state.x.dtype).itemsize
    channels = 1 + scene.dim * (1 if scene.force == "mls" else 2)
    return (scene.n_nodes * channels + state.x.shape[0] * scene.dim**2) * itemsize


def simulate(scene: Scene, state: State, params: Params, n_frames: int | None = None):
    """Run ``n_frames`` frames (default ``scene.n_frames``).  Pure and differentiable.

    Returns ``(final_state, frames)`` where ``frames`` is a ``Frame`` whose arrays have a
    leading axis of length n_frames (the state *after* each frame).  Use under ``jit``
    with ``scene`` static, e.g. ``jax.jit(simulate, static_argnums=(0, 3))``.
    In reverse mode each frame's chunk is recomputed from its input state unless the input
    states of all the run's steps and their saved values fit in ``STORE_STATES_BYTES`` (then they
    are kept: ``make_chunk``).
    """
    nf = scene.n_frames if n_frames is None else n_frames
    kept = nf * scene.steps_per_frame * (state_bytes(state) + residual_bytes(scene, state))
    chunk = make_chunk(scene, recompute=kept > STORE_STATES_BYTES)

    def outer(s, _):
        s = chunk(s, params)
        return s, frame_of(s, scene)

    return jax.lax.scan(outer, state, None, length=nf)


_jit_simulate = jax.jit(simulate, static_argnums=(0, 3))


def run(scene: Scene, state: State, params: Params, n_frames: int | None = None):
    """Jitted ``simulate`` (compiled once per scene and shapes)."""
    return _jit_simulate(scene, state, params, n_frames)


def make_advance(scene: Scene):
    """Jitted ``advance(state, params) -> state`` over one frame (for host-side loops)."""
    return jax.jit(make_chunk(scene))


def layer_time(scene: Scene, k):
    """Release time t_k = t_start + k layer_dt [s] of pool layer ``k``, computed as ``_boundary.make_release``
    does, in the scene's dtype."""
    inf = scene.inflow
    dt = np.dtype(scene.dtype).type
    return dt(inf.t_start) + dt(k) * dt(inf.layer_dt)


# smallest prefix worth a compilation of its own: below a few hundred particles a step costs about
# the same whatever their number (docs/performance.md, "Static skips")
MIN_STAGE = 256


def capacity_schedule(
    scene: Scene, n_frames: int | None = None, max_levels: int = 8, min_size: int = MIN_STAGE
) -> tuple[int, ...]:
    """Per frame, the size n of the buffer prefix [0, n) that the frame must step.

    Without an inflow every frame steps the whole buffer.  With one, frame i (ending at
    t_i = (i + 1) steps_per_frame dt) needs the bodies and every layer released before
    t_i, plus a slack of one layer, two steps and 1e-3 t_i (the time in the state is a
    running sum that drifts from i dt by rounding; ``StagedAdvance`` checks the real time
    after each frame and reruns it on the whole buffer if the slack was short).  Each
    frame gets the smallest of the sizes N, N/2, N/4, ... (at most ``max_levels``
    halvings, none below the first frame's need nor below ``min_size``) that holds its
    need, so a run compiles at most ``max_levels + 1`` programs and, above ``min_size``,
    steps at most twice the particles it must.
    """
    N = scene.n_particles
    nf = scene.n_frames if n_frames is None else n_frames
    inf = scene.inflow
    if inf is None:
        return (N,) * nf
    t_frame = scene.dt * scene.steps_per_frame
    need = []
    for i in range(nf):
        t_i = (i + 1) * t_frame
        t_due = t_i + inf.layer_dt + 2.0 * scene.dt + 1e-3 * t_i
        layers = min(inf.n_layers, max(0, math.floor((t_due - inf.t_start) / inf.layer_dt) + 1))
        need.append(min(N, inf.first + layers * inf.n_per_layer))
    levels = [N]
    while len(levels) <= max_levels and math.ceil(levels[-1] / 2) >= max(need[0], min_size, 1):
        levels.append(math.ceil(levels[-1] / 2))
    levels = sorted(levels)
    return tuple(next(c for c in levels if c >= n) for n in need)


def _split(state: State, n: int):
    """(particles [0, n), particles [n, N)) of a state; scalars (t, n_lost) go with the first."""
    N = state.x.shape[0]

    def cut(lo, hi):
        return jax.tree_util.tree_map(lambda a: a[lo:hi] if a.ndim and a.shape[0] == N else a, state)

    return cut(0, n), cut(n, N)


def _on_prefix(fn, n: int):
    """``fn(state, params, *args)`` applied to particles [0, n) of the buffer; particles [n, N) are
    carried as the step carries an inactive one (position, J, viscosity, internal fields and gate
    kept; velocity, affine matrix and stress zero)."""

    def advance(state, params, *args):
        head, tail = _split(state, n)
        new = fn(head, params, *args)
        tail = tail._replace(v=jnp.zeros_like(tail.v), C=jnp.zeros_like(tail.C), tau=jnp.zeros_like(tail.tau))
        N = state.x.shape[0]

        def join(a, b, c):
            return jnp.concatenate([a, b]) if c.ndim and c.shape[0] == N else a

        return jax.tree_util.tree_map(join, new, tail, state)

    return advance


def make_prefix_advance(scene: Scene, n: int):
    """Jitted ``advance(state, params) -> state`` over one frame that steps only particles
    [0, n) of the buffer and carries particles [n, N) as the step carries an inactive one
    (position, J, viscosity, internal fields and gate kept; velocity, affine matrix and stress
    zero).  The full advance up to float rounding when particles [n, N) are inactive and none
    of them is released during the frame (``StagedAdvance`` checks both)."""
    chunk = make_chunk(scene)
    if n >= scene.n_particles:
        return jax.jit(chunk)

    return jax.jit(_on_prefix(chunk, n))


def make_prefix_steps(scene: Scene, n: int):
    """Jitted ``advance(state, params, k) -> state``: ``k`` steps (an int32; one program for any
    ``k``: ``make_steps``) of particles [0, n) of the buffer, carrying particles [n, N) as
    ``make_prefix_advance`` does.  The driver's frame is a few such calls (``run_chunked``), and
    gives ``make_prefix_advance``'s frame bit for bit."""
    steps = make_steps(scene)
    if n >= scene.n_particles:
        return jax.jit(steps)

    return jax.jit(_on_prefix(steps, n))


def make_frame_program(scene: Scene, n: int):
    """The driver's program for the buffer prefix [0, n): ``make_prefix_steps`` (called with the
    steps of a chunk) where the scene is ``chunkable``, else ``make_prefix_advance`` (a whole frame)."""
    return make_prefix_steps(scene, n) if chunkable(scene) else make_prefix_advance(scene, n)


def frame_program_args(scene: Scene, state: State, params: Params) -> tuple:
    """Example arguments to lower ``make_frame_program``'s program with."""
    return (state, params, np.int32(1)) if chunkable(scene) else (state, params)


# prefix sizes of a split pool: the seeded columns and the pool's first 1/2^j, j = 1 .. SPLIT_STAGES - 1
SPLIT_STAGES = 4


def split_prefix_sizes(scene: Scene, pool: int, min_size: int = MIN_STAGE) -> tuple[int, ...]:
    """The buffer prefixes a depth-averaged scene that splits its columns (``numerics.split_levels`` > 0) steps,
    ascending, below the whole buffer: the seeded columns (the buffer less its last ``pool`` spare slots) with the
    pool's first pool / 2^j slots, j = 1 .. SPLIT_STAGES - 1; none that leaves out fewer than ``min_size`` slots
    (below a few hundred particles a step costs about the same, and each size is a compilation).  () where the
    scene does not split or has no pool."""
    N = scene.n_particles
    if scene.formulation != "depth-averaged" or scene.split_levels <= 0 or pool <= 0 or scene.inflow is not None:
        return ()
    seeded = N - pool
    sizes = {seeded + math.ceil(pool / 2**j) for j in range(1, SPLIT_STAGES)}
    return tuple(sorted(n for n in sizes if N - n >= min_size))


def _slots_in_use(state: State) -> int:
    """One past the last slot of the buffer in use (not a never-used spare slot, ``_split.spare_slots``: a column
    gone through an open face keeps its slot)."""
    used = ~np.asarray(spare_slots(state))
    return int(np.nonzero(used)[0][-1]) + 1 if used.any() else 0


class StagedAdvance:
    """Frame-by-frame driver: ``advance(i, state, params) -> state`` advances frame ``i`` (0-based)
    on the prefix ``capacity_schedule(scene)[i]`` of the buffer (the whole buffer when
    ``staged`` is False or the scene has no inflow).

    ``compile(n)`` returns the program for prefix size n (default: ``make_frame_program``; the
    command line passes a cached, ahead-of-time compiled one).  Where the scene is ``chunkable``
    the program takes a number of steps and a frame is stepped in chunks of about ``CHUNK_S``
    seconds (``run_chunked``, ``pacer``), with ``between()`` after each (default: raise
    ``Interrupted`` for a signal noted in ``_received``), so that a signal is acted on within
    seconds however long a frame is; the frame is the same bit for bit.  Before a frame the
    particles beyond the prefix must all be inactive, and after it the first of them must
    still be due later than the state's time; otherwise (a state not from this schedule,
    or time drift beyond the slack) the frame is run on the whole buffer instead (always
    correct) and counted in ``fallbacks``.
    """

    def __init__(
        self, scene: Scene, staged: bool = True, compile=None, min_size: int | None = None, pacer=None, between=check,
        split_pool: int = 0,
    ):
        self.scene = scene
        N = scene.n_particles
        m = MIN_STAGE if min_size is None else min_size
        self.schedule = capacity_schedule(scene, min_size=m) if staged else (N,) * scene.n_frames
        # column splitting's spare slots (the last ``split_pool`` of the buffer): stepped only as far as used
        self.split_sizes = split_prefix_sizes(scene, split_pool, m) if staged else ()
        if self.split_sizes:
            self.schedule = [N] * scene.n_frames  # each frame's size, set when it runs
        self._growth = 0  # slots the last frame took (split pools)
        self._compile = compile or (lambda n: make_frame_program(scene, n))
        self._programs: dict = {}
        self.fallbacks = 0
        self.chunked = chunkable(scene)
        self.pacer = pacer or Pacer()
        self.between = between

    def sizes(self, first_frame: int = 0) -> list[int]:
        """The prefix sizes that frames ``first_frame``.. use, ascending (with split pools: the smallest, which a
        run that splits little keeps to; the larger ones are compiled when a frame first needs them)."""
        if self.split_sizes:
            return [self.split_sizes[0]]
        return sorted(set(self.schedule[first_frame:]))

    def program(self, n: int):
        if n not in self._programs:
            self._programs[n] = self._compile(n)
        return self._programs[n]

    def __call__(self, i: int, state: State, params: Params) -> State:
        sc = self.scene
        N = sc.n_particles
        if self.split_sizes:
            return self._split_frame(i, state, params)
        n = self.schedule[i] if i < len(self.schedule) else N
        if n < N and bool(jnp.any(state.active[n:])):
            n = N
        new = self._frame(self.program(n), state, params)
        if n < N:
            k = (n - sc.inflow.first) // sc.inflow.n_per_layer
            if not layer_time(sc, k) >= float(new.t) + 0.5 * sc.dt:
                self.fallbacks += 1
                new = self._frame(self.program(N), state, params)
        return new

    def _split_frame(self, i: int, state: State, params: Params) -> State:
        """Frame ``i`` of a scene whose columns split into spare slots (``_split``, used in buffer order): on the
        smallest prefix that holds every used slot and room for one more split; rerun on the next size up whenever
        the prefix's free slots ran short during the frame (fewer left than one split takes: a split may have been
        refused for want of them), so that the frame is the full buffer's (up to the rounding of programs compiled
        for other sizes)."""
        N = self.scene.n_particles
        per = 2 ** (self.scene.dim - 1) - 1  # slots one split takes
        before = _slots_in_use(state)
        # room for one split, or for twice the slots the last frame took (a flow that is splitting goes on)
        need = before + max(per, 2 * self._growth)
        sizes = [n for n in self.split_sizes if n >= need] + [N]
        for n in sizes:
            new = self._frame(self.program(n), state, params)
            if n >= N:
                break
            if int(np.asarray(spare_slots(new))[:n].sum()) >= per:
                break
            self.fallbacks += 1
        self._growth = _slots_in_use(new) - before
        if i < len(self.schedule):
            self.schedule[i] = n
        return new

    def _frame(self, program, state: State, params: Params) -> State:
        if not self.chunked:
            return program(state, params)
        spf = self.scene.steps_per_frame
        return run_chunked(lambda s, k: program(s, params, k), state, spf, self.pacer, self.between)
