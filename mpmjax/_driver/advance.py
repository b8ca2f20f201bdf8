"""The compiled one-frame advance of a run: a process cache of compiled programs
(``_compiled_advance``), the advance a scene steps with (``make_advance``: staged pipe pool or
hazard-map sampling) and its compilation before the first frame (``compile_advance``)."""

from __future__ import annotations

import jax

from .. import _hazard
from .._simulate import StagedAdvance, frame_program_args, make_frame_program

_ADVANCE_CACHE: dict = {}


def _compiled_advance(sc, state, params, n=None):
    """The compiled frame program for this scene, these array shapes and the buffer prefix
    [0, n) it steps (default: all; ``_simulate.make_frame_program``: a chunk of any number of
    steps, or on slabs a whole frame), kept for the
    process (a few scenes' worth), so repeated runs of one scene (a resume, tests, notebooks)
    compile once and run the very same programs."""
    n = sc.n_particles if n is None else int(n)
    leaves, tree = jax.tree_util.tree_flatten((state, params))
    key = (sc, tree, tuple((a.shape, str(a.dtype)) for a in leaves), n)
    if key not in _ADVANCE_CACHE:
        if len(_ADVANCE_CACHE) >= 24:
            _ADVANCE_CACHE.pop(next(iter(_ADVANCE_CACHE)))
        _ADVANCE_CACHE[key] = make_frame_program(sc, n).lower(*frame_program_args(sc, state, params)).compile()
    return _ADVANCE_CACHE[key]


def make_advance(setup, cfg: dict, staged: bool):
    """The frame advance of a built scene.  A pipe inflow's parked pool is stepped only once
    released: each frame steps the buffer prefix that holds every particle active by its end (a
    few sizes; ``_simulate.StagedAdvance``); so are the spare slots of column splitting, as far as
    used (not with hazard maps: the whole buffer).  With output.hazard_maps the maps are sampled
    inside the compiled frame, an extra carry next to the state (``_hazard.HazardAdvance``)."""
    sc = setup.scene
    if cfg["output.hazard_maps"]:
        return _hazard.HazardAdvance(sc, setup.state, setup.params, _hazard.HazardGrid.of(sc, cfg))
    return StagedAdvance(
        sc, staged=staged, compile=lambda n: _compiled_advance(sc, setup.state, setup.params, n),
        split_pool=int(setup.info.get("split_pool", 0)),
    )


def compile_advance(advance, first_frame: int) -> list:
    """Compile the programs the frames from ``first_frame`` on will run; returns their prefix sizes."""
    sizes = advance.sizes(first_frame)
    for n in sizes:
        advance.program(n)
    return sizes
