"""Fusion boundaries (``_fusion``), the per-step checkpoint and the kept states of ``simulate``,
and the process's XLA:CPU reduction flag: each changes only how XLA:CPU evaluates the step,
never a value or a derivative.

Scene: the coarse 2D lab dam break (0.6 m x 0.3 m box, h = 0.03 m, ppc 2, GIMP, APIC, Coussot,
float64), 0.1 s = 51 steps in 3 frames.  float64 so that the only differences left are the
order in which XLA sums (fusions differ with and without the boundaries): bounded by 1e-12
relative over 51 steps (measured: 0 to 4e-15).
"""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import jaxlib
import numpy as np
import pytest
from conftest import COUSSOT_BASE

import mpmjax as m
from mpmjax import _fusion, _simulate

RAW = {
    "domain": {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.6, 0.3], "cell_size_m": 0.03},
    # the particles' pressure: these tests compare code paths to 1e-12 (REL), below the rounding of the grid
    # pressure's conjugate gradients (5e-10 to 2.4e-9 relative in float64); tests/test_pressure.py checks the
    # grid pressure's derivatives against finite differences
    "numerics": {"dtype": "float64", "shape": "gimp", "ppc": 2, "pressure": "explicit"},
    "time": {"t_end_s": 0.1, "n_frames": 3},
    "material": dict(COUSSOT_BASE),
    "bodies": [{"lo_m": [0.0, 0.0], "hi_m": [0.2, 0.15]}],
}
REL = 1e-12


def _mean_x(setup):
    def f(mu0):
        p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
        s = m.simulate(setup.scene, setup.state, p)[0]
        w = s.active.astype(s.x.dtype)
        return jnp.sum(s.x[:, 0] * w) / jnp.sum(w)

    return f


def _value_grad_jvp(setup):
    f = _mean_x(setup)
    mu0 = setup.params.material.mu0
    v, g = jax.jit(jax.value_and_grad(f))(mu0)
    _, t = jax.jit(lambda a: jax.jvp(f, (a,), (jnp.ones_like(a),)))(mu0)
    return float(v), float(g), float(t)


def test_fusion_boundaries_change_neither_values_nor_derivatives(monkeypatch):
    setup = m.build(m.validate(RAW))
    step = m.make_step(setup.scene)
    hlo_on = jax.jit(step).lower(setup.state, setup.params).compile().as_text()
    on = _value_grad_jvp(setup)
    monkeypatch.setattr(_fusion, "on_cpu", lambda: False)
    monkeypatch.setattr(_simulate, "on_cpu", lambda: False)
    hlo_off = jax.jit(m.make_step(setup.scene)).lower(setup.state, setup.params).compile().as_text()
    off = _value_grad_jvp(setup)
    # the boundary is really there on the CPU (the nodal velocity's conditional), and gone without it
    assert hlo_on.count("conditional(") >= 1 and hlo_off.count("conditional(") == 0
    assert on[1] != 0.0
    for a, b in zip(on, off):
        assert abs(a - b) <= REL * abs(b), (on, off)
    # reverse and forward mode agree with the boundaries on
    assert abs(on[1] - on[2]) <= 1e-9 * abs(on[2])


def test_simulate_kept_states_give_the_recomputed_gradient(monkeypatch):
    setup = m.build(m.validate(RAW))
    kept = _simulate.state_bytes(setup.state) * setup.scene.n_frames * setup.scene.steps_per_frame
    assert kept < _simulate.STORE_STATES_BYTES  # this run keeps its states by default
    keep = _value_grad_jvp(setup)
    monkeypatch.setattr(_simulate, "STORE_STATES_BYTES", 0)  # every chunk recomputed
    again = _value_grad_jvp(setup)
    for a, b in zip(keep, again):
        assert abs(a - b) <= REL * abs(b), (keep, again)


_PROBE = (
    "import os, jax, jax.numpy as jnp, mpmjax\n"
    "t = jax.jit(lambda x: jnp.sum(jnp.sin(x) * 2, axis=1)).lower(jnp.ones((3600, 9))).compile().as_text()\n"
    "print(repr(os.environ.get('XLA_FLAGS')), '__ynn_fusion' in t)\n"
)


def _probe(flags, **extra):
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "MPMJAX_KEEP_XLA_FLAGS")}
    if flags is not None:
        env["XLA_FLAGS"] = flags
    env.update(extra)
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


@pytest.mark.skipif(not jaxlib.__version__.startswith(_fusion.YNN_FLAG_VERSIONS), reason="jaxlib without the flag")
def test_import_turns_ynn_reductions_off_unless_the_user_set_the_flag():
    # a fresh process: importing mpmjax sets the flag, and a compiled reduction has no YNNPACK call
    assert _probe(None) == f"{_fusion.YNN_FLAG!r} False"
    # the user's own value of the flag is left as it is
    own = "--xla_cpu_use_xnnpack=true --xla_cpu_experimental_ynn_fusion_type="
    assert _probe(own) == f"{own!r} False"
    # put first: XLA stops reading its flags at a word without "--" (here a thread option of another library)
    other = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    assert _probe(other) == f"{_fusion.YNN_FLAG + ' ' + other!r} False"
    # MPMJAX_KEEP_XLA_FLAGS=1 keeps XLA's defaults: YNNPACK reductions on
    assert _probe(None, MPMJAX_KEEP_XLA_FLAGS="1") == "None True"
    # here the backends are running: the flags are read, so nothing is changed
    before = os.environ.get("XLA_FLAGS")
    jnp.zeros(1).block_until_ready()
    if "xla_cpu_experimental_ynn_fusion_type" not in (before or ""):
        assert _fusion.prefer_xla_reductions() is False
        assert os.environ.get("XLA_FLAGS") == before


def test_state_leaves_are_what_state_bytes_counts():
    setup = m.build(m.validate(RAW))
    total = sum(np.asarray(a).nbytes for a in jax.tree.leaves(setup.state))
    assert _simulate.state_bytes(setup.state) == total


@pytest.mark.parametrize("numerics", [{}, {"force": "mls", "shape": "quadratic"}])
def test_the_per_step_checkpoint_saves_what_residual_bytes_counts(capsys, numerics):
    """The values a checkpointed step saves beyond its input (reverse mode, two steps so that the
    first step's result depends on mu0; the nodal force and MLS, whose grid has no force channels): once per step the grid sums and the velocity gradient,
    the bytes ``_simulate.residual_bytes`` charges to the kept-states budget."""
    setup = m.build(m.validate(dict(RAW, numerics=dict(RAW["numerics"], **numerics))))
    one = jax.checkpoint(m.make_step(setup.scene), policy=jax.checkpoint_policies.save_only_these_names(*_fusion.SAVED))

    def two(mu0):
        p = setup.params._replace(material=setup.params.material._replace(mu0=mu0))
        return one(one(setup.state, p), p).x

    jax.ad_checkpoint.print_saved_residuals(two, setup.params.material.mu0)
    named = [ln for ln in capsys.readouterr().out.splitlines() if " named '" in ln]
    assert sorted({ln.split("'")[1] for ln in named}) == sorted(_fusion.SAVED) and len(named) == 4
    # each line starts with the saved value's type, such as f64[459,5]
    kinds = [ln.split("[")[0].strip() for ln in named]
    assert set(kinds) == {"f64"}
    nbytes = sum(8 * int(np.prod([int(d) for d in ln.split("[")[1].split("]")[0].split(",")])) for ln in named)
    assert nbytes == 2 * _simulate.residual_bytes(setup.scene, setup.state)
