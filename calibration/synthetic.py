"""Synthetic (twin-experiment) profile data: run a scene with known parameters, add noise.

``python -m calibration.synthetic`` rewrites the synthetic files in ``data/`` (each with
its origin in a ``#`` header); see data/README.md.  Synthetic data are labelled
``synthetic`` in their file names.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import mpmjax

from .data import Profile, write_profiles_csv
from .experiments import ProfileExperiment, frames_for

__all__ = ["synthetic_profiles", "DATASETS", "main"]


def synthetic_profiles(scene, overrides, times_s, x_m, *, sigma_m: float, seed: int = 0, bandwidth_m=None):
    """Profiles h(x_m) [m] of ``scene`` (name or TOML path, with ``overrides``) at
    ``times_s`` [s] (the run ends at the last one; frames are aligned to the times), as
    the kernel height profile (bandwidth ``bandwidth_m``, default one cell) plus
    independent Gaussian noise of standard deviation ``sigma_m`` [m], clipped at h >= 0.
    Returns (profiles, setup) with ``sigma_m`` recorded in each profile."""
    cfg0 = mpmjax.load_scene(scene, overrides)
    t_end, nf = frames_for(list(times_s), cfg0["time.t_end_s"], cfg0["time.n_frames"])
    setup = mpmjax.build(mpmjax.load_scene(scene, list(overrides) + [f"time.t_end_s={t_end!r}", f"time.n_frames={nf}"]))
    x = np.asarray(x_m, float)
    dummy = [Profile(x, np.ones_like(x), float(t)) for t in times_s]
    exp = ProfileExperiment(setup, dummy, bandwidth_m=bandwidth_m)
    hs = [np.asarray(h, float) for h in exp.model_profiles({})]
    rng = np.random.default_rng(seed)
    out = []
    for t, h in zip(times_s, hs, strict=True):
        noisy = np.maximum(h + sigma_m * rng.standard_normal(h.shape), 0.0)
        out.append(Profile(x, noisy, float(t), np.full_like(x, sigma_m), source="synthetic"))
    return out, setup


ROOT = Path(__file__).resolve().parent.parent
# name: (scene, overrides, times [s], stations [m], sigma [m], seed, kernel bandwidth [m])
DATASETS = {
    "synthetic_twin_small_profiles.csv": (
        str(ROOT / "data" / "twin-small-dambreak.toml"),
        ["domain.cell_size_m=0.01"],
        (0.5, 1.0, 1.5),
        np.linspace(0.0, 0.9, 46),
        0.001,
        1,
        0.04,
    ),
    "synthetic_lab_dambreak_profiles.csv": (
        "dambreak-lab",
        [],
        (1.0, 2.0, 4.0),
        np.linspace(0.0, 1.5, 61),
        0.002,
        2,
        0.02,
    ),
}


def main(argv=None) -> int:
    names = list(argv if argv is not None else sys.argv[1:]) or list(DATASETS)
    for name in names:
        if name not in DATASETS:
            print(f"unknown dataset {name!r}; allowed: {', '.join(DATASETS)}", file=sys.stderr)
            return 2
        scene, ov, times, x, sigma, seed, bw = DATASETS[name]
        profs, setup = synthetic_profiles(scene, ov, times, x, sigma_m=sigma, seed=seed, bandwidth_m=bw)
        m = setup.params.material
        mat = ", ".join(f"{k} = {float(getattr(m, k)):g}" for k in type(m)._fields)
        header = (
            f"SYNTHETIC data (not measured): mpmjax twin experiment, written by `python -m calibration.synthetic`.\n"
            f"scene {Path(scene).name} with overrides {ov}; cell size {setup.scene.h} m, "
            f"{setup.scene.n_particles} particles, dt {setup.scene.dt:.4g} s.\n"
            f"material ({type(m).__name__}, SI): {mat}.\n"
            f"h = Gaussian-kernel height profile (bandwidth {bw} m) + N(0, sigma_m) noise (seed {seed}), "
            "clipped at 0.\ncolumns: x_m [m], h_m [m], t_s [s], sigma_m [m]"
        )
        write_profiles_csv(ROOT / "data" / name, profs, header)
        print(f"wrote data/{name}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
