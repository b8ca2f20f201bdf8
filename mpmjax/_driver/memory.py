"""The memory check before a run is built: the memory available to it (``_available_memory``) and
the refusal of a run whose ``_build.memory_estimate`` exceeds it (``check_memory``, ``MemoryRefused``)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import jax

from .._build import memory_estimate
from .._schema import SceneError


class MemoryRefused(SceneError):
    """The memory estimate of a run exceeds the memory available (exit status 2)."""


MEMORY_ENV = "MPMJAX_MEMORY_LIMIT_GB"  # overrides the memory available to a run ("inf": no check)


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
