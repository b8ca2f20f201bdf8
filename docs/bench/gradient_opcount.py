"""Why the reverse-mode gradient costs what it does: XLA's own operation counts (issue 18 item 3).

Compiles one step of the default scene (``dambreak-lab``, ppc 3, 3600 particles, float32) three
ways and reads ``Compiled.cost_analysis()`` (flops and bytes accessed, as XLA counts them over its
fused program):

* ``forward``: the step, state and Coussot mu0 in, state out;
* ``vjp``: the reverse-mode step, ``jax.vjp`` of the same function applied to a cotangent of the
  whole state (the forward inside it included, as a checkpointed chunk's recomputation runs it);
* ``jvp``: the forward-mode step with a tangent on the whole state and on mu0 (as inside a scan,
  where the state's tangent is not zero).

Nothing is timed; the counts are deterministic for a given jax/XLA version.

    .venv/bin/python docs/bench/gradient_opcount.py > docs/bench/gradient_opcount.json
"""

import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from mpmjax import build, load_scene  # noqa: E402
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

    def tan(s, m):
        ts = jax.tree_util.tree_map(
            lambda x: jnp.ones_like(x) if jnp.issubdtype(x.dtype, jnp.floating) else np.zeros(x.shape, jax.dtypes.float0),
            s,
        )
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
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
