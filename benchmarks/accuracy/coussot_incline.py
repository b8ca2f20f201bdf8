"""The full MPM's no-slip bed under a Coussot layer (issue 31, item 2): a film on an incline against its
one-dimensional solution across the depth (``mpmjax.studies.film``), and against the steady profile.

A layer of depth H on a no-slip incline at angle theta, periodic along it (4 cells long), free surface,
the lab's Coussot material (``dambreak-lab``: rho = 1850 kg/m^3, mu0 = 4 Pa s, alpha = 1, T = 0.5 s,
n = 2.5, mu_max = 5000 Pa s; its steady flow curve has its minimum tau_c = 15.7 Pa at 2.35 1/s, the stress
below which it stops: the lab deposit stops where its bed stress falls to about tau_c).  The bed stress
tau_w = rho g H sin(theta) is set to ``r`` tau_c by the slope.  Exact steady state (``coussot_film.case``):
the structure at its steady value at every height, the heights whose stress exceeds tau_c flowing on the
rising branch of the flow curve and the rest creeping on its capped branch, so the sheared band is
H (1 - 1/r) thick and its rate at the bed is the flow curve's at tau_w.

That steady state is one of many: the flow curve's capped branch peaks at 575 Pa, far above tau_w, so every
height can stand jammed or flow, and a layer started from rest at lambda0 finds a thinner band.  The
reference is therefore the transient itself, solved across the depth on 100 layers (``film.film_profiles``;
0.06 % from 200 layers).  Measured: the layer's mean speed U (all particles, averaged over the frames of the
last ``T_AVG`` of ``T_END``) against the film's mean speed at the same times, and against the steady
"flowing state" (``*_steady``).  One JSON line per run.

    .venv/bin/python benchmarks/accuracy/coussot_incline.py incompressible 2 5,10,20
    .venv/bin/python benchmarks/accuracy/coussot_incline.py explicit 2,4 10 cell_shear=series
    .venv/bin/python benchmarks/accuracy/coussot_incline.py profile 10 2 cell_shear=series   # lambda and u by layer
    .venv/bin/python benchmarks/accuracy/coussot_incline.py layers 2 50,100,200              # the film's own convergence
"""

import json
import math
import sys
import time

import numpy as np

import jax

import coussot_film  # this directory's script: the exact steady layer
from mpmjax import build
from mpmjax._simulate import run
from mpmjax import rheometer
from mpmjax.studies import film, validate

MATERIAL = "dambreak-lab"
H = validate.FILM_H  # m: the lab deposit's thickness, about
T_END, T_AVG = 6.0, 1.0


def slope_for(r: float) -> tuple[float, float]:
    """(theta [deg], tau_c [Pa]) with the bed stress rho g H sin(theta) = r tau_c: validate's layer."""
    return validate.film_slope_deg(r), float(rheometer.critical_point(rheometer.make_params())[1])


def exact(theta: float) -> tuple[float, float]:
    """(depth-averaged speed, surface speed) [m/s] of the exact steady layer."""
    m = coussot_film.MATERIALS[MATERIAL]
    gd, tau = coussot_film.flow_curve(m)
    tw = m["rho"] * coussot_film.G * H * math.sin(math.radians(theta))
    y = np.linspace(0.0, H, 4001)
    g = np.array([coussot_film.rate(gd, tau, tw * (1 - yy / H)) for yy in y])
    u = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(y))])
    return float(np.sum(0.5 * (u[1:] + u[:-1]) * np.diff(y)) / H), float(u[-1])


def config(cells: int, r: float, numerics: dict) -> dict:
    """validate's coussot-film layer (``validate.film_config``) at ``r`` tau_c, 12 frames to T_END, in float64 and
    at kappa = 200 kPa (rho g H / kappa 0.45 %: the explicit pressure near its incompressible limit);
    ``numerics``: numerics keys without their section."""
    base = {"numerics.dtype": "float64", "material.bulk_modulus_pa": 2e5}
    base.update({f"numerics.{k}": v for k, v in numerics.items()})
    return validate.film_config(cells, T_END, 12, base, r=r)


def measure(r: float, cells: int, pressure: str, numerics: dict) -> dict:
    theta, tau_c = slope_for(r)
    s = build(config(cells, r, {"pressure": pressure, **numerics}))
    c0 = time.process_time()
    final, frames = run(s.scene, s.state, s.params)
    jax.block_until_ready(frames.v)
    cpu = time.process_time() - c0
    times = (np.arange(s.scene.n_frames) + 1) * T_END / s.scene.n_frames
    keep = int(np.sum(times >= T_END - T_AVG - 1e-9))  # the frames of the last T_AVG, both ends (as validate)
    vx = np.asarray(frames.v)[-keep:, :, 0]
    U_s = exact(theta)[0]
    mean = float(vx.mean())
    series = [round(float(v), 5) for v in np.asarray(frames.v)[:, :, 0].mean(axis=1)]
    y, u, _, _ = film.film_profiles(s.params.material, H, theta, times)
    ref = film.mean_speed(y, u)
    U = float(ref[-keep:].mean())
    return {
        "r": r,
        "theta_deg": round(theta, 4),
        "tau_c_pa": round(tau_c, 3),
        "cells": cells,
        "pressure": pressure,
        **{f"numerics.{k}": v for k, v in numerics.items()},
        "U_film": round(U, 6),
        "U": round(mean, 6),
        "err_U_pct": round(100 * (mean - U) / U, 2),
        "U_steady": round(U_s, 6),
        "err_U_steady_pct": round(100 * (mean - U_s) / U_s, 2),
        "U_frames": series,
        "U_film_frames": [round(float(v), 5) for v in ref],
        "steps": s.scene.n_steps,
        "cpu_s": round(cpu, 1),
        "date": time.strftime("%Y-%m-%d"),
    }


def value(v: str):
    try:
        return float(v)
    except ValueError:
        return v  # a choice, e.g. wall_yield=wall


def profile(cells: int, r: float, numerics: dict) -> None:
    """Per particle layer at T_END: height / h, the particles' mean lambda and speed, and the film's at that height
    (400 layers), one line each."""
    theta, _ = slope_for(r)
    s = build(config(cells, r, {"pressure": "incompressible", **numerics}))
    final, _ = run(s.scene, s.state, s.params)
    y, lam, vx = np.asarray(final.x)[:, 1], np.asarray(final.internal["lam"]), np.asarray(final.v)[:, 0]
    yf, u, z, _ = film.film_profiles(s.params.material, H, theta, [T_END], n_layers=400)
    yc = 0.5 * (yf[1:] + yf[:-1])
    h = H / cells
    for yy in np.unique(np.round(y / h, 3)):
        m = np.round(y / h, 3) == yy
        print(
            f"y/h {yy:7.3f}  lambda {lam[m].mean():7.3f} film {np.interp(yy * h, yc, z['lam'][-1]):7.3f}  "
            f"u {vx[m].mean():.5f} film {np.interp(yy * h, yf, u[-1]):.5f} m/s",
            flush=True,
        )


def layers(r: float, counts) -> None:
    """The film's own convergence: its mean speed over the comparison's window (the frames at 5, 5.5, 6 s of 12)
    and at 6 s, at each count of layers, one JSON line each."""
    theta, _ = slope_for(r)
    s = build(config(5, r, {}))
    times = (np.arange(12) + 1) * T_END / 12
    for n in counts:
        c0 = time.process_time()
        y, u, _, steps = film.film_profiles(s.params.material, H, theta, times, n_layers=n)
        ref = film.mean_speed(y, u)
        rec = {"r": r, "n_layers": n, "U_window": float(ref[times >= T_END - T_AVG - 1e-9].mean()), "U_6s": float(ref[-1]),
               "steps": steps, "cpu_s": round(time.process_time() - c0, 1), "date": time.strftime("%Y-%m-%d")}
        print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "layers":  # layers R [COUNTS]
        layers(float(sys.argv[2]), [int(x) for x in (sys.argv[3] if len(sys.argv) > 3 else "50,100,200").split(",")])
        sys.exit(0)
    if len(sys.argv) > 1 and sys.argv[1] == "profile":  # profile CELLS R [key=value ...]
        profile(int(sys.argv[2]), float(sys.argv[3]), {k: value(v) for k, v in (a.split("=", 1) for a in sys.argv[4:])})
        sys.exit(0)
    pressures = sys.argv[1].split(",") if len(sys.argv) > 1 else ["explicit", "incompressible"]
    ratios = [float(x) for x in sys.argv[2].split(",")] if len(sys.argv) > 2 else [2.0, 4.0]
    cells = [int(x) for x in sys.argv[3].split(",")] if len(sys.argv) > 3 else [5, 10, 20]
    extra = {k: value(v) for k, v in (a.split("=", 1) for a in sys.argv[4:])}  # <numerics key>=<value>
    for p in pressures:
        for r in ratios:
            for c in cells:
                print(json.dumps(measure(r, c, p, extra)), flush=True)
