"""One simulation sharded over devices (``numerics.devices``, ``mpmjax._shard``): same results as one device."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import mpmjax as m

ROOT = Path(__file__).resolve().parent.parent

# Runs in a fresh process with 2 host devices: the lab dam break at h = 0.02 m, float64, 0.15 s
# (119 steps) on 1 and on 2 devices, from its state of 400 particles less the last one: 2 does not
# divide 399, so the sharded step also pads one inactive particle and drops it again.
_CODE = """
import json, jax, numpy as np
from mpmjax._build import build
from mpmjax._schema import load_scene
from mpmjax._simulate import make_chunk
ov = ["domain.cell_size_m=0.02", "time.t_end_s=0.15", "time.n_frames=1", "numerics.dtype=float64", "numerics.ppc=2"]
setup = build(load_scene("dambreak-lab", ov + ["numerics.devices=2"]))
sc, p = setup.scene, setup.params
s0 = jax.tree_util.tree_map(lambda a: a[:-1] if a.ndim and a.shape[0] == sc.n_particles else a, setup.state)
r = {d: jax.jit(make_chunk(sc.replace(devices=d), sc.n_steps))(s0, p) for d in (1, 2)}
print(json.dumps({
    "n_dev": jax.device_count(), "steps": sc.n_steps, "n": int(s0.x.shape[0]),
    "dx": float(np.abs(np.asarray(r[2].x) - np.asarray(r[1].x)).max()),
    "dJ": float(np.abs(np.asarray(r[2].J) - np.asarray(r[1].J)).max()),
    "moved": float(np.abs(np.asarray(r[1].x) - np.asarray(s0.x)).max()),
    "lost": [int(r[1].n_lost), int(r[2].n_lost)],
    "t": [float(r[1].t), float(r[2].t)],
    "sharded": len(r[2].x.sharding.device_set),
}))
"""


def test_two_host_devices_give_the_one_device_positions():
    """The lab dam break (399 particles, float64, 119 steps with the explicit pressure, 81 with the
    grid pressure) on 2 host devices ends where it ends on one, to 1e-12 m in position and 1e-11 in J.

    The sharded step differs from the single-device one only in the order of the floating-point
    additions that build the grid (two partial scatters summed by ``psum`` against one scatter):
    each nodal sum is off by a few float64 roundings (1e-16 relative), and the steps amplify that
    to the measured 3e-16 m (2e-15 in J; 2e-7 m in float32).  1e-12 m leaves room for that growth;
    a missing or doubled reduction, or a padding particle with mass, moves particles by
    O(dt^2 g) = 1e-5 m per step at least (here the block collapses by centimetres), 1e7 times more.
    Measured: 13 s of CPU time (two compilations), so about 13 s on the idle 2-core VM; 40-48 s of
    wall time at load 9-10.
    """
    env = dict(os.environ, XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    p = subprocess.run(
        [sys.executable, "-c", _CODE], capture_output=True, text=True, env=env, cwd=ROOT, timeout=300
    )
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(p.stdout.strip().splitlines()[-1])
    assert r["n_dev"] == 2 and r["steps"] > 50 and r["n"] == 399 and r["sharded"] == 2, r
    assert r["moved"] > 1e-3, r  # the block has flowed: the comparison is not of a state at rest
    assert r["dx"] < 1e-12, r
    assert r["dJ"] < 1e-11, r
    assert r["lost"] == [0, 0] and r["t"][0] == r["t"][1], r


_GRAD = """
import json, jax, jax.numpy as jnp
from mpmjax._build import build
from mpmjax._schema import load_scene
from mpmjax._simulate import simulate
ov = ["domain.cell_size_m=0.02", "time.t_end_s=0.1", "time.n_frames=2", "numerics.dtype=float64", "numerics.devices=2", "numerics.ppc=2"]
setup = build(load_scene("dambreak-lab", ov))
sc, p, s0 = setup.scene, setup.params, setup.state
out = {}
for d in (1, 2):
    def loss(mu0):
        s, _ = simulate(sc.replace(devices=d), s0, p._replace(material=p.material._replace(mu0=mu0)))
        return jnp.mean(s.x[:, 0])
    out[d] = [float(a) for a in jax.jit(jax.value_and_grad(loss))(p.material.mu0)]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_two_host_devices_give_the_one_device_gradient():
    """Reverse mode through the sharded ``simulate`` (checkpointed scans, ``psum`` inside): d(mean x)/d mu0
    of the coarse lab dam break after 0.1 s (float64) on 2 host devices equals one device's to 1e-9
    relative.  Measured: 1e-16 relative (the forward's rounding, as in the position test); a missing
    transpose of the reduction would be off by a factor of order 2.  Slow: 48 s of CPU time (two
    reverse-mode compilations), so not in CI.
    """
    env = dict(os.environ, XLA_FLAGS=os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", _GRAD], capture_output=True, text=True, env=env, cwd=ROOT, timeout=900)
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(p.stdout.strip().splitlines()[-1])
    (v1, g1), (v2, g2) = r["1"], r["2"]
    assert g1 != 0.0 and abs(g2 - g1) <= 1e-9 * abs(g1), r
    assert abs(v2 - v1) <= 1e-12, r


def test_devices_bad_input(tmp_path, capsys):
    """``--devices 0`` and devices with a pipe inflow stop with exit status 2 and a message naming the
    option (the CLI's range check, before the scene is built) or the key."""
    from mpmjax.cli import main

    assert main(["run", "dambreak-lab", "--devices", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--devices = 0 is invalid: allowed range: integer >= 1" in capsys.readouterr().err
    with pytest.raises(m.SceneError, match="numerics.devices = 2 is invalid with a pipe inflow"):
        m.load_scene("bingham-funnel", ["numerics.devices=2"])
