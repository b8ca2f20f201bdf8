"""One simulation across devices: particles sharded, grid replicated, grid sums reduced.

``numerics.devices = N`` (``mpmjax run --devices N``) splits the particle arrays of one run
into N equal blocks, one per device, with ``jax.shard_map``.  Every device holds the whole
grid: it scatters its own particles into a grid of its own, the N partial grids are summed
across devices (``psum``, an all-reduce; ``_transfer.make_p2g``'s ``axis``), and the grid
update and the G2P gather then run on every device with the reduced grid and its own
particles.  This is the pattern of CB-Geo MPM's first MPI version (particles decomposed, the
grid replicated and reduced).  ``numerics.decomposition = "slab"`` cuts the grid into slabs
instead, with halo exchange (``_slab``); both read the grid through a layout object
(``Replicated`` here, ``_slab.Slab``).

What crosses devices per step: the P2G grid (n_nodes x (1 + 2 dim) numbers), the J-bar
average's grid with ``numerics.volume_averaging = "jbar"``, and the count of particles lost
in the step.  Everything else is per particle.  The time and the lost count stay replicated.

Results equal the single-device run's to float rounding, not bit for bit: the reduction sums
the devices' partial grids in another order than one scatter does (tests/test_parallel_shard.py).

On a CPU, N host devices are made with ``jax_num_cpu_devices`` (``use_devices``), which works
only before JAX starts its backends and holds for the whole process: the run driver
(``mpmjax run``, ``run_scene``) does it first; ``build`` and the step only check that the devices
are there.  A particle count that N does not divide is padded with inactive particles for the
sharded step (they carry no mass, so they add exact zeros to the grid) and the padding is dropped
again after it.

Pipe-inflow scenes are refused with N > 1 for now: the release schedule numbers pool particles
by their global index (``_boundary.make_release``), which a device does not know.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax._src import xla_bridge  # backends_are_initialized: no public way to ask whether the backends started
from jax.sharding import Mesh, PartitionSpec

from ._schema import SceneError

# the mesh axis over which particles are split
AXIS = "particles"


class Replicated:
    """The grid layout of one device, or of a run whose particles are sharded with the grid replicated.

    A step reads the grid only through its layout (``_step.make_step``'s ``grid``; ``_slab.Slab`` is
    the other one): ``local`` maps global flat node indices to the indices of the grid the device
    holds (here the same), ``nodes`` gives a static per-node array (``scene.n_nodes`` rows) for that
    grid, ``reduce`` turns the device's partial grid sums into the whole sums (``psum`` over
    ``axis``; nothing on one device) and ``total`` a per-device count into the run's.
    """

    def __init__(self, n_nodes: int, axis: str | None = None):
        self.n_nodes, self.axis = n_nodes, axis

    def local(self, idx):
        return idx

    def nodes(self, a, dtype=None):
        return jnp.asarray(a, dtype)

    def reduce(self, grid):
        return grid if self.axis is None else jax.lax.psum(grid, self.axis)

    def total(self, x):
        return x if self.axis is None else jax.lax.psum(x, self.axis)


def use_devices(n: int, make: bool = True) -> list:
    """The first ``n`` devices of the default backend.

    ``make``: on a CPU with fewer than ``n`` devices, first ask JAX for ``n`` host devices
    (``jax_num_cpu_devices``); that is possible only before anything has started JAX's backends,
    and it holds for the whole process, so only the run driver does it (``build`` and the step
    only check).  Raises ``SceneError`` naming ``numerics.devices`` when ``n`` devices are not there.
    """
    if n < 1:
        raise SceneError(f"numerics.devices = {n} is invalid: allowed range: >= 1")
    if make and n > 1 and not xla_bridge.backends_are_initialized():
        platforms = (jax.config.jax_platforms or "").split(",")
        if platforms[0] in ("", "cpu"):
            try:
                if jax.config.jax_num_cpu_devices < n:
                    jax.config.update("jax_num_cpu_devices", n)
            except Exception:  # set by XLA_FLAGS or refused: jax.devices() below says what there is
                pass
    devs = jax.devices()
    if len(devs) < n:
        raise SceneError(
            f"numerics.devices = {n} is invalid here: JAX has {len(devs)} {devs[0].platform} device(s) in this "
            f"process (on a CPU, `mpmjax run` and `mpmjax.run_scene` make host devices before JAX starts; in your "
            f"own code set jax.config.update('jax_num_cpu_devices', {n}) or "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={n} before the first JAX computation); "
            f"allowed range: 1 .. {len(devs)}"
        )
    return devs[:n]


def particle_mesh(n: int) -> Mesh:
    """A one-axis mesh (``AXIS``) over the first ``n`` devices (which must exist)."""
    return Mesh(np.asarray(use_devices(n, make=False)), (AXIS,))


def _specs(tree, n_particles: int):
    """PartitionSpec per leaf: split along the particle axis, replicate the rest (time, lost count)."""
    return jax.tree_util.tree_map(
        lambda a: PartitionSpec(AXIS) if jnp.ndim(a) and jnp.shape(a)[0] == n_particles else PartitionSpec(), tree
    )


def _pad(state, n: int, pad: int):
    """Append ``pad`` inactive particles (copies of the last one, made inactive) to every particle array."""

    def f(a):
        if not (jnp.ndim(a) and a.shape[0] == n):
            return a
        tail = jnp.broadcast_to(a[-1:], (pad,) + a.shape[1:])
        return jnp.concatenate([a, tail])

    padded = jax.tree_util.tree_map(f, state)
    inactive = jnp.concatenate([state.active, jnp.zeros((pad,), bool)])
    return padded._replace(active=inactive)


def shard_particles(local_step, n_devices: int):
    """``step(state, params) -> state`` running ``local_step`` under ``shard_map`` over particles.

    ``local_step`` is the step built with ``axis=AXIS`` (its grid sums are ``psum``-reduced);
    particle arrays are split into ``n_devices`` blocks, parameters, time and lost count replicated.
    """
    mesh = particle_mesh(n_devices)

    def step(state, params):
        n = state.x.shape[0]
        pad = -n % n_devices
        s = _pad(state, n, pad) if pad else state
        spec = _specs(s, n + pad)
        pspec = jax.tree_util.tree_map(lambda _: PartitionSpec(), params)
        out = jax.shard_map(local_step, mesh=mesh, in_specs=(spec, pspec), out_specs=spec)(s, params)
        if pad:
            out = jax.tree_util.tree_map(lambda a: a[:n] if jnp.ndim(a) and a.shape[0] == n + pad else a, out)
        return out

    return step
