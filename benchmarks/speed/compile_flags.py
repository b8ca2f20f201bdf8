"""Compile CPU time of three of the test suite's programs under an XLA_FLAGS setting (docs/performance.md, "Test suite").

The harness's flags (tests/conftest.py, ``TEST_XLA_FLAGS``) are chosen by this measurement.  Run one process per flag
set, alternating, in one shell (XLA reads its flags once, at start):

    for r in 1 2 3; do for f in "" "--xla_llvm_disable_expensive_passes=true" "--xla_backend_optimization_level=1" \
        "--xla_backend_optimization_level=1 --xla_llvm_disable_expensive_passes=true"; do
      XLA_FLAGS="$f" .venv/bin/python benchmarks/speed/compile_flags.py; done; done

Prints one JSON line: the flags, and per program the compile CPU and one run's CPU [s].  Like the harness, it adds
the older fusion emitters when the flags do not name them.
"""
import os, sys, time, json
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
import mpmjax as m
from mpmjax._schema import load_scene
from mpmjax._simulate import make_chunk
out = {}
def timed(name, fn, args):
    c0 = time.process_time(); w0 = time.perf_counter()
    comp = jax.jit(fn).lower(*args).compile()
    c1 = time.process_time(); w1 = time.perf_counter()
    r = comp(*args); jax.block_until_ready(r)
    c2 = time.process_time(); w2 = time.perf_counter()
    r = comp(*args); jax.block_until_ready(r)
    c3 = time.process_time()
    out[name] = {"compile_cpu": round(c1 - c0, 2), "run_cpu": round(c3 - c2, 3)}
    return r
# 1: float64 reverse-mode gradient of a Coussot dam break (test_gradients' scene)
raw = {"domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.6, 0.3], "cell_size_m": 0.03},
       "numerics": {"dtype": "float64", "shape": "gimp", "ppc": 2, "pressure": "explicit"},
       "time": {"t_end_s": 0.3, "n_frames": 3},
       "material": {"model": "coussot", "density_kg_m3": 1850.0, "bulk_modulus_pa": 15000.0, "mu0_pa_s": 4.0,
                    "alpha": 1.0, "T_s": 0.5, "n": 2.5, "lambda0": 1.5, "mu_max_pa_s": 5000.0},
       "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.15]}]}
s = m.build(m.validate(raw))
def loss(mat):
    p = s.params._replace(material=mat)
    _, fr = m.simulate(s.scene, s.state, p)
    return jnp.sum(fr.x[-1][:, 0] ** 2)
timed("grad64", jax.grad(loss), (s.params.material,))
# 2: the lab dam break, grid pressure, float32, a chunk of 50 steps
st = m.build(load_scene("dambreak-lab", ["domain.cell_size_m=0.02"]))
timed("lab_grid_chunk", make_chunk(st.scene, 50), (st.state, st.params))
st = m.build(load_scene("dambreak-lab", ["domain.cell_size_m=0.02", "numerics.pressure=explicit"]))
timed("lab_expl_chunk", make_chunk(st.scene, 50), (st.state, st.params))
print(json.dumps({"flags": os.environ.get("XLA_FLAGS"), **out}))
