"""Batches beyond one machine: the batch axis of a sweep or of a multi-start fit split over
every device of every process (``jax.distributed``), or over independent jobs (``--shard I/N``).

Two ways to spread one batch (sweep cases, calibration starts) over more than one machine:

* **One distributed job** (``join``): N processes, on one host or many, each run the same
  command with ``--coordinator HOST:PORT --num-processes N --process-id I`` (or, under Slurm
  or Open MPI, with ``--distributed`` and nothing else: ``jax.distributed.initialize``
  detects the rest).  JAX then sees the devices of all processes as one list, the batch is
  laid out along a one-axis mesh over all of them (``BatchLayout``: padded to a whole
  number of lanes per device by repeating the last lane), every process computes the lanes
  on its own devices, and the results are gathered to every process
  (``multihost_utils.process_allgather``) so that all of them take the same host-side
  decisions (a fit's stopping tests).  Only process 0 (``is_writer``) writes files.  On the
  CPU the cross-process collectives are gloo over TCP (JAX's default
  ``jax_cpu_collectives_implementation`` in jax 0.10; set it to ``"mpi"`` for MPI).
* **Independent jobs** (``mpmjax sweep --shard I/N``): no communication at all; job I runs
  its contiguous share of the cases (``shard_range``), writes them to ``OUT/part-I-of-N.npz``
  through a temporary file and an atomic rename, and ``mpmjax sweep-merge OUT`` joins the
  parts when all N are there.  This suits a plain job array, or hosts that cannot reach
  one another.

Every lane computes the same function of its own inputs, so a distributed batch equals the
single-process batch to float rounding (tests/test_parallel_distributed.py).
"""

from __future__ import annotations

import math
import os
import re

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "BATCH_AXIS",
    "BatchLayout",
    "DistributedError",
    "check_join_options",
    "is_writer",
    "join",
    "check_local_devices",
    "make_local_devices",
    "parse_shard",
    "shard_range",
]

BATCH_AXIS = "batch"  # the mesh axis along which batch lanes (cases, starts) are split

# jax.distributed: seconds to wait for every process to join (JAX's default is 300)
JOIN_TIMEOUT_S = 300


class DistributedError(ValueError):
    """A distributed option is invalid or the job cannot be joined (exit status 2)."""


def check_join_options(coordinator, num_processes, process_id, detect=False):
    """Validate ``--coordinator HOST:PORT``, ``--num-processes N``, ``--process-id I``.

    Returns ``None`` when no distributed option is given (a single-process run), else the
    keyword arguments of ``jax.distributed.initialize`` (missing values left ``None`` for JAX
    to detect, which it can under Slurm and Open MPI: ``detect`` or any option given).
    Raises ``DistributedError`` naming the option, the value and the allowed range."""
    if coordinator is None and num_processes is None and process_id is None and not detect:
        return None
    if coordinator is not None:
        m = re.fullmatch(r"\[?([^\[\]]+?)\]?:(\d+)", coordinator.strip())
        port = int(m.group(2)) if m else -1
        if not m or not 1 <= port <= 65535:
            raise DistributedError(
                f"--coordinator = {coordinator!r} is invalid; allowed: HOST:PORT with the host of process 0 "
                "and a free TCP port 1 .. 65535, e.g. node001:12345 or 127.0.0.1:12345"
            )
    if num_processes is not None and num_processes < 1:
        raise DistributedError(f"--num-processes = {num_processes} is invalid; allowed range: integer >= 1")
    if process_id is not None:
        hi = f"{num_processes - 1}" if num_processes is not None else "--num-processes - 1"
        if process_id < 0 or (num_processes is not None and process_id >= num_processes):
            raise DistributedError(f"--process-id = {process_id} is invalid; allowed range: 0 .. {hi}")
    if not detect and None in (coordinator, num_processes, process_id):
        missing = [
            n for n, v in (("--coordinator", coordinator), ("--num-processes", num_processes),
                           ("--process-id", process_id)) if v is None
        ]
        raise DistributedError(
            f"{', '.join(missing)} missing: a distributed run needs --coordinator, --num-processes and "
            "--process-id, or --distributed to detect them from the cluster (Slurm, Open MPI)"
        )
    return {"coordinator_address": coordinator, "num_processes": num_processes, "process_id": process_id}


def join(options) -> None:
    """``jax.distributed.initialize(**options)`` (``options`` from ``check_join_options``);
    nothing for ``None``.  Must come before any JAX computation in the process.  Raises
    ``DistributedError`` with JAX's reason when the job cannot be joined (no cluster detected,
    the coordinator unreachable within ``JOIN_TIMEOUT_S``)."""
    if options is None:
        return
    try:
        jax.distributed.initialize(**options, initialization_timeout=JOIN_TIMEOUT_S)
    except Exception as e:  # JAX raises ValueError / RuntimeError / XlaRuntimeError here
        where = options.get("coordinator_address") or "the detected coordinator"
        raise DistributedError(
            f"cannot join the distributed job at {where} as process {options.get('process_id')} of "
            f"{options.get('num_processes')}: {str(e).splitlines()[0] if str(e) else type(e).__name__}"
        ) from None


def make_local_devices(n) -> None:
    """``mpmjax sweep --devices N``, first half: before JAX starts (and before ``join``), ask for ``n``
    host devices (``jax_num_cpu_devices``), so that on a CPU the sweep's batch is split over them, each
    running its share on one core, as over the devices of a distributed job (``BatchLayout``: the batch
    always uses every device the process has).  Measured on 2 cores: ``sweep --devices 2`` 1.3-1.5x
    faster than ``--devices 1`` (docs/performance.md, "Beyond one machine").  ``None`` or 1: nothing.
    Raises ``DistributedError`` naming ``--devices``, the value and the allowed range (1 .. the
    machine's cores)."""
    if n is None or n == 1:
        return
    cores = os.cpu_count() or 1
    if not 1 <= n <= cores:
        raise DistributedError(
            f"--devices = {n} is invalid; allowed range: integer 1 .. {cores} (this machine's cores: one "
            "host device per core)"
        )
    try:
        if jax.config.jax_num_cpu_devices < n:
            jax.config.update("jax_num_cpu_devices", n)
    except Exception:  # JAX has started already, or XLA_FLAGS set the count: check_local_devices says
        pass


def check_local_devices(n) -> None:
    """``--devices N``, second half, after ``join``: this process must hold at least ``n`` devices.
    Raises ``DistributedError`` naming ``--devices`` and the count there is."""
    if n is None or n == 1:
        return
    have = jax.local_device_count()
    if have < n:
        raise DistributedError(
            f"--devices = {n} is invalid here: this process has {have} {jax.devices()[0].platform} device(s) "
            f"(host devices are made only before JAX starts); allowed range: 1 .. {have}"
        )


def is_writer() -> bool:
    """Whether this process writes the outputs: process 0 (also in a single-process run)."""
    return jax.process_index() == 0


class BatchLayout:
    """``n`` batch lanes laid out over every device of every process.

    With one device the lanes stay where JAX puts them; with several (host devices, GPUs, or
    the devices of all processes of a ``jax.distributed`` job) the batch is padded to a
    multiple of the device count by repeating its last lane and split along a one-axis mesh
    (``BATCH_AXIS``).  ``put`` makes the (global) input arrays from host arrays every process
    holds alike, ``replicate`` the arrays all lanes share; ``gather`` returns a computation's
    outputs as numpy arrays on every process, padding dropped.  ``min_lanes``: below this many
    lanes the batch is not split (each process computes all of it: cheaper than padding one lane
    to one per device)."""

    def __init__(self, n: int, min_lanes: int = 1):
        self.n = int(n)
        self.n_devices = jax.device_count()
        self.sharded = self.n_devices > 1 and self.n >= min_lanes
        self.n_padded = self.n_devices * math.ceil(self.n / self.n_devices) if self.sharded else self.n
        self.sharding = (
            NamedSharding(Mesh(np.asarray(jax.devices()), (BATCH_AXIS,)), PartitionSpec(BATCH_AXIS))
            if self.sharded
            else None
        )

    def pad(self, a):
        """``a`` (host array, lanes first) padded to ``n_padded`` lanes with copies of its last lane."""
        a = np.asarray(a)
        if a.shape[0] == self.n_padded:
            return a
        return np.concatenate([a, np.repeat(a[-1:], self.n_padded - a.shape[0], axis=0)])

    def put(self, tree):
        """Host arrays (lanes first, ``n`` or ``n_padded`` of them) -> device arrays laid out
        over the batch mesh (each process places only its own devices' lanes)."""
        if not self.sharded:
            return jax.tree.map(lambda a: jax.numpy.asarray(a), tree)

        def one(a):
            a = self.pad(a)
            return jax.make_array_from_callback(a.shape, self.sharding, lambda idx: a[idx])

        return jax.tree.map(one, tree)

    def replicate(self, tree):
        """Arrays every lane shares (a scene's state and parameters) -> copies on every device of
        the batch mesh (unchanged with one device)."""
        if not self.sharded:
            return tree
        rep = NamedSharding(self.sharding.mesh, PartitionSpec())

        def one(a):
            a = np.asarray(a)
            return jax.make_array_from_callback(a.shape, rep, lambda idx: a[idx])

        return jax.tree.map(one, tree)

    def gather(self, tree):
        """Device arrays (lanes first) -> numpy arrays of the first ``n`` lanes, on every
        process (a collective in a distributed job: every process must call it)."""
        if self.sharded and jax.process_count() > 1:
            tree = multihost_utils.process_allgather(tree, tiled=True)
        return jax.tree.map(lambda a: np.asarray(a)[: self.n], tree)


def parse_shard(text: str) -> tuple[int, int]:
    """``"I/N"`` -> (I, N) with 0 <= I < N, or ``DistributedError`` naming ``--shard``."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text or "")
    if not m or not (int(m.group(2)) >= 1 and int(m.group(1)) < int(m.group(2))):
        raise DistributedError(
            f"--shard = {text!r} is invalid; allowed: I/N with N >= 1 jobs and 0 <= I <= N - 1 (e.g. 3/16; "
            "under a Slurm job array: $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT)"
        )
    return int(m.group(1)), int(m.group(2))


def shard_range(n: int, shard: tuple[int, int]) -> range:
    """The contiguous cases of job I of N among ``n`` (sizes differ by at most one; a job
    beyond the cases gets none)."""
    i, k = shard
    return range(i * n // k, (i + 1) * n // k)
