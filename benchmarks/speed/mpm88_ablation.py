"""Where mpmjax's mpm88-equivalent spends its time beyond a minimal JAX port (issue 18 item 2).

``static_skips.py mpm88_minimal`` measured mpmjax's mpm88-equivalent at about 2.4x the CPU time of
``static_skips.minimal_mpm88`` (the MLS-MPM of taichi_mlsmpm.py in jax.numpy), without saying
what costs what.  This script starts from that port and adds the general step's work one piece
at a time, cumulatively, each a variant compiled apart:

* ``A minimal``: the port (3 channels: mass and momentum, the pressure impulse folded into the
  APIC affine term; J <- J (1 + dt tr C); linear EOS p = kappa (1 - J));
* ``B +force channels``: the internal force as its own 2 channels, f_i = -sum V sigma grad w_ip
  with the quadratic B-spline's gradient (5 channels, as mpmjax scatters), and the velocity
  gradient L = sum v_i (x) grad w_ip in the G2P with J <- J det(I + dt L);
* ``C +Maxwell deviatoric``: a deviatoric stress per particle, updated by the exact Maxwell step
  with its Jaumann rotation (G = kappa, mu = 1e-3 Pa s as the mpm88-equivalent), added to sigma;
* ``D +Tait EOS``: p = (kappa / 7) (J^-7 - 1) instead of the linear law;
* ``E +walls and loss checks``: the particle-level push-back of the four walls (position and
  inward velocity) and the loss detection (stencil inside the grid, finite state, active mask,
  the state kept where a particle is lost);

then, as the lever the ablation points to,

* ``F E with the MLS force``: E's physics (Tait pressure, Maxwell deviatoric stress, walls, loss
  checks) with the whole stress folded into the APIC affine term as MLS-MPM does (Hu et al. 2018:
  the impulse -dt V sigma D^-1 (x_i - x_p) w_ip, D = h^2 / 4 for the quadratic B-spline), 3
  channels, and C as the velocity gradient (no grad w at all);

and mpmjax's own mpm88-equivalent (``studies.bench.MPM88``) beside them.  All: 128^2 cells (mpmjax:
135^2 nodes with its ghost layers), 8192 particles, float32, ``steps`` steps per call in one
``lax.scan``; compiled first, then timed in rounds, each round in a rotated order (CPU time of
the process and wall time per call).  Every variant's mean fall after the run is printed
against the minimal port's (the block does not reach a wall in 500 steps of 1e-4 s, so the
internal forces cancel and all fall alike; the check that each variant is the same physics).

    .venv/bin/python benchmarks/speed/mpm88_ablation.py [STEPS [ROUNDS]] >> benchmarks/speed/mpm88_ablation.jsonl
"""

from __future__ import annotations

import json
import os
import sys
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp

N_GRID, DX, DT = 128, 1.0 / 128, 1e-4
RHO, KAPPA, G, BOUND, MU = 1000.0, 4.0e5, 9.81, 3, 1e-3
NX, NY = 64, 128


class S(NamedTuple):
    x: jax.Array
    v: jax.Array
    C: jax.Array
    J: jax.Array
    tau: jax.Array
    active: jax.Array


def _weights(f):
    w = [0.5 * (1.5 - f) ** 2, 0.75 - (f - 1.0) ** 2, 0.5 * (f - 0.5) ** 2]
    dw = [-(1.5 - f), -2.0 * (f - 1.0), f - 0.5]
    return w, dw


def variant(level: str, steps: int):
    """(state, advance) of the port with the pieces up to ``level`` (A..E) switched on; F: E's pieces
    with the MLS force instead of the separate force channels."""
    force5, dev, tait, walls = (level in "BCDE"), (level >= "C"), (level >= "D"), (level >= "E")
    p_vol = (0.5 * DX) ** 2
    p_mass = RHO * p_vol
    k = jnp.arange(NX * NY)
    x0 = jnp.stack([0.1 + (k % NX + 0.5) * 0.5 * DX, 0.1 + (k // NX + 0.5) * 0.5 * DX], axis=1).astype(jnp.float32)
    n = x0.shape[0]
    z2 = jnp.zeros((n, 2, 2), jnp.float32)
    state = S(x0, jnp.zeros_like(x0), z2, jnp.ones((n,), jnp.float32), z2, jnp.ones((n,), bool))
    offs = [(a, b) for a in range(3) for b in range(3)]
    gi, gj = jnp.meshgrid(jnp.arange(N_GRID), jnp.arange(N_GRID), indexing="ij")
    gi, gj = gi.reshape(-1), gj.reshape(-1)
    eye = jnp.eye(2, dtype=jnp.float32)
    lo_safe, hi_safe = 1.5 * DX, 1.0 - 1.5 * DX
    wall_pts = [(0, BOUND * DX, 1.0), (0, 1.0 - BOUND * DX, -1.0), (1, BOUND * DX, 1.0), (1, 1.0 - BOUND * DX, -1.0)]

    def stencil(x):
        xi = x / DX
        base = jnp.floor(xi - 0.5).astype(jnp.int32)
        f = xi - base
        w, dw = _weights(f)
        idx = jnp.stack([(base[:, 0] + a) * N_GRID + base[:, 1] + b for a, b in offs], axis=1)
        wt = jnp.stack([w[a][:, 0] * w[b][:, 1] for a, b in offs], axis=1)
        gw = jnp.stack([jnp.stack([dw[a][:, 0] * w[b][:, 1], w[a][:, 0] * dw[b][:, 1]], -1) for a, b in offs], 1) / DX
        r = jnp.stack([(jnp.array([a, b], jnp.float32)[None] - f) * DX for a, b in offs], axis=1)
        return idx, wt, gw, r

    def pressure(J):
        return (KAPPA / 7.0) * (J**-7.0 - 1.0) if tait else KAPPA * (1.0 - J)

    def step(s, _):
        idx, wt, gw, r = stencil(s.x)
        p = pressure(s.J)
        if force5:
            sigma = -p[:, None, None] * eye[None] + (s.tau if dev else 0.0)
            vol = p_vol * s.J
            frc = -vol[:, None, None] * jnp.einsum("nij,nsj->nsi", sigma, gw)
            mom = wt[..., None] * p_mass * (s.v[:, None, :] + jnp.einsum("nij,nsj->nsi", s.C, r))
            chans = jnp.concatenate([(wt * p_mass)[..., None], mom, frc], axis=-1).reshape(-1, 5)
            grid = jnp.zeros((N_GRID * N_GRID, 5), jnp.float32).at[idx.reshape(-1)].add(chans)
            m = grid[:, 0]
            inv = jnp.where(m > 0, 1.0 / jnp.where(m > 0, m, 1.0), 0.0)
            gv = (grid[:, 1:3] + DT * grid[:, 3:5]) * inv[:, None]
        else:
            # MLS: the stress impulse -dt V sigma D^-1 in the affine term (D^-1 = 4 / h^2)
            sigma = -p[:, None, None] * eye[None] + (s.tau if dev else 0.0)
            vol = p_vol * s.J if level == "F" else jnp.full_like(s.J, p_vol)  # the port: V0, as taichi_mlsmpm.py
            affine = -DT * 4.0 / DX**2 * vol[..., None, None] * sigma + p_mass * s.C
            mom = wt[..., None] * (p_mass * s.v[:, None, :] + jnp.einsum("nij,nsj->nsi", affine, r))
            chans = jnp.concatenate([mom, (wt * p_mass)[..., None]], axis=-1).reshape(-1, 3)
            grid = jnp.zeros((N_GRID * N_GRID, 3), jnp.float32).at[idx.reshape(-1)].add(chans)
            m = grid[:, 2]
            gv = jnp.where(m[:, None] > 0, grid[:, :2] / jnp.where(m > 0, m, 1.0)[:, None], 0.0)
        gv = gv.at[:, 1].add(-DT * G)
        vx = jnp.where(((gi < BOUND) & (gv[:, 0] < 0)) | ((gi > N_GRID - BOUND) & (gv[:, 0] > 0)), 0.0, gv[:, 0])
        vy = jnp.where(((gj < BOUND) & (gv[:, 1] < 0)) | ((gj > N_GRID - BOUND) & (gv[:, 1] > 0)), 0.0, gv[:, 1])
        gv = jnp.where(m[:, None] > 0, jnp.stack([vx, vy], axis=1), 0.0)
        gvp = gv[idx]
        nv = jnp.sum(wt[..., None] * gvp, axis=1)
        nC = 4.0 / DX**2 * jnp.einsum("ns,nsi,nsj->nij", wt, gvp, r)
        x = s.x + DT * nv
        L = jnp.einsum("nsi,nsj->nij", gvp, gw) if force5 else nC  # MLS: C is the velocity gradient
        if level == "A":
            J = s.J * (1.0 + DT * (nC[:, 0, 0] + nC[:, 1, 1]))
        else:
            J = s.J * jnp.linalg.det(eye[None] + DT * L)
        tau = s.tau
        if dev:
            d = 0.5 * (L + jnp.swapaxes(L, 1, 2))
            dprime = d - 0.5 * (d[:, 0, 0] + d[:, 1, 1])[:, None, None] * eye[None]
            W = 0.5 * (L - jnp.swapaxes(L, 1, 2))
            rate = jnp.sqrt(2.0 * jnp.sum(dprime * dprime, axis=(1, 2)))
            mu = jnp.where(rate >= 0.0, MU, MU)  # the Newtonian "rheology call": a constant viscosity
            xg = KAPPA * DT / mu
            tau_rot = tau + DT * (W @ tau - tau @ W)
            tau = tau_rot * jnp.exp(-xg)[:, None, None] + 2.0 * (mu * -jnp.expm1(-xg))[:, None, None] * dprime
        active = s.active
        if walls:
            for ax, pt, nrm in wall_pts:
                phi = (x[:, ax] - pt) * nrm
                behind = phi < 0.0
                x = x.at[:, ax].set(jnp.where(behind, x[:, ax] - phi * nrm, x[:, ax]))
                vn = nv[:, ax] * nrm
                nv = nv.at[:, ax].set(jnp.where(behind & (vn < 0.0), nv[:, ax] - vn * nrm, nv[:, ax]))
            inside = jnp.all((x >= lo_safe) & (x <= hi_safe), axis=1)
            finite = jnp.all(jnp.isfinite(x), axis=1) & jnp.all(jnp.isfinite(nv), axis=1) & jnp.isfinite(J) & (J > 0)
            active = s.active & inside & finite

            def keep(new, old):
                return jnp.where(active.reshape(active.shape + (1,) * (new.ndim - 1)), new, old)

            x, nv, nC, J, tau = keep(x, s.x), keep(nv, 0 * nv), keep(nC, 0 * nC), keep(J, s.J), keep(tau, 0 * tau)
        return S(x, nv, nC, J, tau, active), None

    return state, jax.jit(lambda s: jax.lax.scan(step, s, None, length=steps)[0])


def main(steps: int = 500, rounds: int = 6) -> None:
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    from mpmjax import build
    from mpmjax._schema import validate
    from mpmjax._simulate import make_chunk
    from mpmjax.studies.bench import MPM88

    names = {"A": "A minimal", "B": "B +force channels", "C": "C +Maxwell deviatoric", "D": "D +Tait EOS",
             "E": "E +walls and loss checks", "F": "F E with the MLS force"}
    progs, y0 = {}, {}
    for lv, nm in names.items():
        st, adv = variant(lv, steps)
        progs[nm] = (lambda st=st, adv=adv: adv(st).x)
        y0[nm] = float(jnp.mean(st.x[:, 1]))
    setup = build(validate(json.loads(json.dumps(MPM88))))
    full = jax.jit(make_chunk(setup.scene, steps))
    progs["mpmjax mpm88-equivalent"] = lambda: full(setup.state, setup.params).x
    y0["mpmjax mpm88-equivalent"] = float(jnp.mean(setup.state.x[:, 1]))
    fall = {}
    for k, f in progs.items():
        fall[k] = y0[k] - float(jnp.mean(jax.block_until_ready(f())[:, 1]))
    keys = list(progs)
    for rnd in range(rounds):
        order = keys[rnd % len(keys):] + keys[: rnd % len(keys)]
        for k in order:
            load = os.getloadavg()[0]
            c0, w0 = time.process_time(), time.perf_counter()
            jax.block_until_ready(progs[k]())
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            print(json.dumps({"part": "mpm88_ablation", "code": k, "round": rnd + 1, "steps": steps,
                              "n_particles": 8192, "cpu_s": cpu, "wall_s": wall, "mean_fall_m": fall[k], "load_avg_start": load,
                              "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}), flush=True)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
