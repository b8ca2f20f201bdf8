"""Fusion boundaries for XLA:CPU: values the step forms once instead of once per consumer.

XLA fuses an elementwise producer into each consumer that reads it and recomputes it there.  On
the CPU this is where much of the step's time went (docs/performance.md, "Fusion boundaries"):

* the G2P gather read the nodal velocity through the whole grid update (mass division, gravity,
  every wall), recomputed for each gathered stencil node;
* the P2G's channel fusion and its scatter each rebuilt the stencil's node indices;
* in the reverse pass, the cotangent chain of the per-particle update (velocity gradient, J,
  rheology, stress) was fused into the cotangent of each gathered stencil entry, and the
  stencil's weights were rebuilt in every fusion of the transposed transfers.

``jax.lax.optimization_barrier`` does not stop this on XLA:CPU (it is expanded before fusion).
A ``lax.cond`` is a separate computation whose operands and results XLA must materialise, so:

* ``boundary(tree)``: the values pass a conditional whose predicate is always true but hidden
  from XLA (an ``optimization_barrier`` on the constant ``True``, which also keeps it unbatched
  under ``vmap``, so the conditional stays a conditional there).  Value and derivatives are the
  identity's.
* ``derivative_boundary(tree)``: nothing in a plain evaluation; under ``jvp``/``grad`` (and so in
  ``jax.checkpoint``'s recomputation and the transposed pass) the primal and tangent values each
  pass ``boundary``.  For values whose materialising costs the forward step more than it saves
  (the stencil arrays: 15 % slower on mpm88) but pays in the derivative.

Both are the identity on other backends (the GPU path is unchanged: a conditional there costs a
predicate read per step, and no GPU was measured).

``saved(tree, name)`` names a value the reverse pass keeps instead of recomputing (``SAVED``: the
grid sums of the P2G and the G2P's velocity gradient): the per-step checkpoint of
``_simulate.make_chunk`` stores these and recomputes the rest of the step from its input state.
Kept, the two cost 186 kB a step on the default scene and spare the recomputation of the P2G
and the G2P: the gradient through 1000 steps takes 0.83x the time (docs/performance.md, "Row
windows and saved residuals").
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import jaxlib
from jax._src import xla_bridge
from jax.ad_checkpoint import checkpoint_name

GRID_SUMS = "mpmjax_grid_sums"
VELOCITY_GRADIENT = "mpmjax_velocity_gradient"
SAVED = (GRID_SUMS, VELOCITY_GRADIENT)


def saved(tree, name: str):
    """``tree`` unchanged, named ``name`` (one of ``SAVED``) for the per-step checkpoint's policy."""
    return checkpoint_name(tree, name)


def on_cpu() -> bool:
    """Whether the default backend, for which the step is traced, is XLA:CPU."""
    return jax.default_backend() == "cpu"


def _pass(tree):
    always = jax.lax.optimization_barrier(jnp.bool_(True))
    return jax.lax.cond(always, lambda a: a, lambda a: jax.tree.map(jnp.zeros_like, a), tree)


def boundary(tree):
    """``tree`` materialised by XLA:CPU before its consumers read it (identity elsewhere)."""
    return _pass(tree) if on_cpu() else tree


@jax.custom_jvp
def _derivative_boundary(tree):
    return tree


@_derivative_boundary.defjvp
def _derivative_boundary_jvp(primals, tangents):
    (tree,), (t_tree,) = primals, tangents
    # integer leaves (stencil indices) have float0 tangents: they pass as they are
    leaves, treedef = jax.tree.flatten(t_tree)
    inexact = [jnp.issubdtype(a.dtype, jnp.inexact) for a in leaves]
    moved = iter(_pass([a for a, f in zip(leaves, inexact) if f]))
    t_out = jax.tree.unflatten(treedef, [next(moved) if f else a for a, f in zip(leaves, inexact)])
    return _pass(tree), t_out


def derivative_boundary(tree):
    """``tree`` unchanged when evaluated; under differentiation on XLA:CPU its primal and tangent
    values are materialised (``boundary``) before their consumers read them."""
    return _derivative_boundary(tree) if on_cpu() else tree


# XLA:CPU in jaxlib 0.10 hands reductions to YNNPACK ("__ynn_fusion" thunks), each reduction of a
# stencil axis its own library call that reads its operands again.  With them off, XLA's own loops
# fuse those reductions with their producers: measured side by side, the mpm88 step 1.45-1.5x,
# the default scene 1.23x and the reverse pass 1.3x faster (docs/performance.md, "Fusion
# boundaries").  The flag exists in the jaxlib versions listed; an XLA flag that a jaxlib does
# not know aborts the process at start, so no other version gets it.
YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type="
YNN_FLAG_VERSIONS = ("0.10.",)


def prefer_xla_reductions() -> bool:
    """Turn XLA:CPU's YNNPACK reduction fusions off for this process, through ``XLA_FLAGS``,
    before JAX starts its backends.  Not when the flag is already set (the user's choice wins),
    the environment has ``MPMJAX_KEEP_XLA_FLAGS=1`` (XLA's defaults kept, as for measuring
    them), the backends have started (the flags are read once), or the jaxlib is not one known
    to have the flag.  Returns whether the flag is in force from here on."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_experimental_ynn_fusion_type" in flags:
        return YNN_FLAG in flags.split()
    keep = os.environ.get("MPMJAX_KEEP_XLA_FLAGS", "") not in ("", "0")
    if keep or xla_bridge.backends_are_initialized() or not jaxlib.__version__.startswith(YNN_FLAG_VERSIONS):
        return False
    if flags.strip() and not flags.lstrip().startswith("--"):  # XLA reads such a value as a flag file's name
        return False
    # first: XLA stops reading flags at a word that does not start with "--"
    os.environ["XLA_FLAGS"] = (YNN_FLAG + " " + flags).strip()
    return True
