"""Why the reverse-mode gradient costs what it does: XLA's own operation counts (issue 18 item 3).

Compiles one step of the default scene (``dambreak-lab``, ppc 3, 3600 particles, float32) three
ways and reads ``Compiled.cost_analysis()`` (flops and bytes accessed, as XLA counts them over its
fused program):

* ``forward``: the step, state and Coussot mu0 in, state out;
* ``vjp``: the reverse-mode step, ``jax.vjp`` of the same function applied to a cotangent of the
  whole state (the forward inside it included, as a checkpointed chunk's recomputation runs it);
* ``jvp``: the forward-mode step with a tangent on the whole state and on mu0 (as inside a scan,
  where the state's tangent is not zero).

Then the vjp again with parts of the step cut out of the derivative (``jax.lax.stop_gradient``
patched in for this script only; the gradient is then wrong, the point is what the cut part costs):

* ``no_stencil_x``: the stencil (weights, weight gradients, offsets) taken as constant in x, so no
  cotangent flows through the particles' positions into the weights of either transfer;
* ``no_constitutive``: the rheology's outputs, the deviatoric stress and J taken as constant;

and the stencil alone (x -> w, grad w, r) forward and vjp, the part a hand-written stencil adjoint
would replace.

Nothing is timed; the counts are deterministic for a given jax/XLA version.

    .venv/bin/python benchmarks/gradient/gradient_opcount.py > benchmarks/gradient/gradient_opcount.json
"""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import dataclasses  # noqa: E402

from mpmjax import _step, _transfer, build, load_scene  # noqa: E402
from mpmjax._step import make_step  # noqa: E402


def counts(f, *a):
    c = jax.jit(f).lower(*a).compile().cost_analysis()
    c = c[0] if isinstance(c, (list, tuple)) else c
    return {"flops": float(c["flops"]), "bytes_accessed": float(c["bytes accessed"])}


def main():
    setup = build(load_scene("dambreak-lab", {}))
    step = make_step(setup.scene)
    st, pr = setup.state, setup.params

    def fwd(s, mu0):
        return step(s, pr._replace(material=pr.material._replace(mu0=mu0)))

    mu0 = pr.material.mu0
    ct = fwd(st, mu0)

    def rev(s, m, c):
        return jax.vjp(fwd, s, m)[1](c)

    def one_tangent(x):
        if jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.ones_like(x)
        return np.zeros(x.shape, jax.dtypes.float0)  # integer and boolean leaves carry no tangent

    def tan(s, m):
        ts = jax.tree_util.tree_map(one_tangent, s)
        return jax.jvp(fwd, (s, m), (ts, jnp.ones_like(m)))

    n = setup.scene.n_particles
    out = {"scene": "dambreak-lab (default, ppc 3)", "n_particles": n, "dtype": str(st.x.dtype), "jax": jax.__version__}
    f = counts(fwd, st, mu0)
    for name, c in (("forward", f), ("vjp", counts(rev, st, mu0, ct)), ("jvp", counts(tan, st, mu0))):
        out[name] = {
            "flops_per_particle_step": c["flops"] / n,
            "bytes_per_particle_step": c["bytes_accessed"] / n,
            "flops_over_forward": c["flops"] / f["flops"],
            "bytes_over_forward": c["bytes_accessed"] / f["bytes_accessed"],
        }
    out["vjp_with_parts_cut"] = {}
    for cut in ("no_stencil_x", "no_constitutive"):
        with _cut(cut, setup.scene) as scene:
            step_c = make_step(scene)

            def fwd_c(s, m, step_c=step_c):
                return step_c(s, pr._replace(material=pr.material._replace(mu0=m)))

            c = counts(lambda s, m, ct_: jax.vjp(fwd_c, s, m)[1](ct_), st, mu0, ct)
        out["vjp_with_parts_cut"][cut] = {
            "flops_per_particle_step": c["flops"] / n,
            "bytes_per_particle_step": c["bytes_accessed"] / n,
            "flops_saved_per_particle_step": out["vjp"]["flops_per_particle_step"] - c["flops"] / n,
        }

    def stencil(x):
        sc = _transfer._Stencil(setup.scene, x)
        return sc.w, sc.dw, sc.r

    sf = counts(stencil, st.x)
    sb = counts(lambda x, c: jax.vjp(stencil, x)[1](c), st.x, stencil(st.x))
    out["stencil_alone"] = {"forward_flops_per_particle": sf["flops"] / n, "vjp_flops_per_particle": sb["flops"] / n}
    print(json.dumps(out, indent=1))


class _cut:
    """Context: the step's module patched so that one part of the step is cut out of the derivative."""

    def __init__(self, what, scene):
        self.what, self.scene = what, scene

    def __enter__(self):
        self.saved = (_transfer._Stencil, _step.deviatoric_update)
        sg = jax.lax.stop_gradient
        if self.what == "no_stencil_x":
            orig = _transfer._Stencil

            class Frozen(orig):
                def __init__(self, scene, x, **kw):
                    super().__init__(scene, sg(x), **kw)

            _transfer._Stencil = Frozen
            return self.scene
        dev = _step.deviatoric_update
        _step.deviatoric_update = lambda *a: sg(dev(*a))
        rheo = self.scene.rheology

        class Frozen:
            def __getattr__(self, k):
                return getattr(rheo, k)

            def viscosity(self, *a):
                return sg(rheo.viscosity(*a))

        # J: cut where the step forms it, through the determinant it is formed from
        self.saved_det = jnp.linalg.det
        jnp.linalg.det = lambda a: sg(self.saved_det(a))
        return dataclasses.replace(self.scene, rheology=Frozen())

    def __exit__(self, *exc):
        _transfer._Stencil, _step.deviatoric_update = self.saved
        if hasattr(self, "saved_det"):
            jnp.linalg.det = self.saved_det


if __name__ == "__main__":
    main()
