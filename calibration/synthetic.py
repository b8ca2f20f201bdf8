"""Synthetic (twin-experiment) profile data: run a scene with known parameters, add noise.

``python -m calibration.synthetic`` rewrites the synthetic files in ``data/`` (each with
its origin in a ``#`` header); see data/README.md.  ``python -m calibration.synthetic
joint-twin DIR`` writes the joint twin's four files (docs/calibration.md, "Joint experiments")
to DIR.  Synthetic data are labelled
``synthetic`` in their file names.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import mpmjax

from .data import Profile, ShearTest, write_profiles_csv, write_table_csv
from .experiments import (
    ProfileExperiment,
    RestTimeExperiment,
    RunoutSeriesExperiment,
    ShearHistoryExperiment,
    frames_for,
    overshoot_test,
)

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
    if names[0] == "joint-twin":
        if len(names) != 2:
            print("usage: python -m calibration.synthetic joint-twin OUT_DIR", file=sys.stderr)
            return 2
        for k, p in write_joint_twin(names[1], JOINT_TRUTH).items():
            print(f"wrote {p} ({k})", file=sys.stderr)
        return 0
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




# ------------------------------------------------------------------------------------------
# The joint twin (issue 15 item 2): four experiment kinds that together identify all five
# Coussot parameters.  Its truth is deliberately not the material of any file in data/.
# ------------------------------------------------------------------------------------------
JOINT_TRUTH = {"mu0": 3.0, "alpha": 1.6, "T": 0.8, "n": 2.2, "lambda0": 1.4}
JOINT_SCENE = str(ROOT / "data" / "twin-small-dambreak.toml")
# data times of the dam-break experiments [s]; the rests of the repeated releases [s]
JOINT_TIMES_S = (0.2, 0.4, 0.6)
JOINT_REST_S = (1.0, 3.0)
# noise: profiles 1 mm, fronts 3 mm, rheometer stresses 3 % (sigma of ln tau)
JOINT_SIGMA = {"profiles": 0.001, "runout-series": 0.003, "rest-times": 0.003, "transient": 0.03}


def joint_shear_tests():
    """The twin's rheometer protocol (``calibration.data.ShearTest`` rows, stresses to be filled):
    pre-shear at 100 1/s for 5 s (erasing the loading history, so these tests say nothing about
    lambda0), rest 0.5, 2 or 10 s, start-up at 0.5 or 5 1/s with the stress sampled from 0.05 to
    20 s after it (the overshoot and its relaxation), plus two steps down, 100 -> 20 -> 1 1/s
    (5 s at 20 1/s).  Every test has three rate stretches and 12 measured rows, so the seven are
    one ``vmap`` batch of one compiled solve."""
    ta = np.geomspace(0.05, 20.0, 12)
    tests = [
        overshoot_test(f"{i + 1}", preshear_1_s=100.0, preshear_s=5.0, rest_s=rest, rate_1_s=rate, t_after_s=ta)
        for i, (rest, rate) in enumerate((r, g) for r in (0.5, 2.0, 10.0) for g in (0.5, 5.0))
    ]
    step = overshoot_test("7", preshear_1_s=100.0, preshear_s=5.0, rest_s=5.0, rate_1_s=1.0, t_after_s=ta)
    tests.append(ShearTest("7", step.t_s, np.where(step.gamma_dot_1_s == 0, 20.0, step.gamma_dot_1_s), step.tau_pa))
    return tests


def joint_twin(
    truth=None, *, cell_size_m=0.03, data_cell_size_m=None, seed=5, noise=True, stations=31, times_s=JOINT_TIMES_S,
    model_data=True,
):
    """Synthetic data of the joint twin and the experiments that fit them.

    The dam break is ``data/twin-small-dambreak.toml`` run to the last of ``times_s`` (frames
    every 0.1 s) with the Coussot parameters ``truth`` (default ``JOINT_TRUTH``): height
    profiles at ``times_s`` (default ``JOINT_TIMES_S``) on
    ``stations`` stations over 0 .. 0.9 m (kernel bandwidth 0.06 m), the front
    (``free_surface_front``) at every frame, the same release after rests of ``JOINT_REST_S``
    (initial structure lambda0 + t_rest/T) with its front at every frame, and the rheometer
    tests of :func:`joint_shear_tests`.  Data are made at ``data_cell_size_m`` (default the fit's
    ``cell_size_m``) plus N(0, sigma) noise (``JOINT_SIGMA``; heights clipped at 0; ln-normal for
    stresses) with ``seed``.  ``model_data=False`` skips the data runs and puts placeholders
    (1 cm heights, 0.3 m fronts, 1 Pa stresses) in their place: enough for a Fisher analysis at
    the truth with the sigmas known, which does not depend on the data values.  Returns (experiments in the order profiles, runout series, rest
    times, transients; the fit's setup, whose material is the truth; the data as dict of kind ->
    numpy arrays, for writing files)."""
    truth = dict(JOINT_TRUTH if truth is None else truth)
    keys = {"mu0": "material.mu0_pa_s", "alpha": "material.alpha", "T": "material.T_s", "n": "material.n",
            "lambda0": "material.lambda0"}
    times_s = tuple(float(t) for t in times_s)
    n_frames = int(round(max(times_s) / 0.1))
    base = [f"{keys[k]}={v!r}" for k, v in truth.items()]
    base += [f"time.t_end_s={0.1 * n_frames!r}", f"time.n_frames={n_frames}"]

    def setup_at(h):
        return mpmjax.build(mpmjax.load_scene(JOINT_SCENE, base + [f"domain.cell_size_m={h!r}"]))

    fit_setup = setup_at(cell_size_m)
    data_setup = fit_setup if data_cell_size_m in (None, cell_size_m) else setup_at(data_cell_size_m)
    rng = np.random.default_rng(seed)
    sig = JOINT_SIGMA
    bw = 0.06
    x = np.linspace(0.0, 0.9, stations)
    frame_t = np.arange(1, n_frames + 1) * 0.1

    def noisy(a, s):
        return np.asarray(a, float) + (s * rng.standard_normal(np.shape(a)) if noise else 0.0)

    # the model at the truth, at the data's resolution
    tests0 = joint_shear_tests()
    if model_data:
        pe = ProfileExperiment(data_setup, [Profile(x, np.ones_like(x), t) for t in times_s], bandwidth_m=bw)
        h = [np.maximum(noisy(v, sig["profiles"]), 0.0) for v in pe.model_profiles({})]
        fr = RunoutSeriesExperiment(data_setup, frame_t, np.full(n_frames, 0.3), bandwidth_m=bw).model_fronts({})
        rests = [
            RunoutSeriesExperiment(data_setup, frame_t, np.full(n_frames, 0.3), bandwidth_m=bw, rest_time_s=tr)
            .model_fronts({})
            for tr in JOINT_REST_S
        ]
        taus = ShearHistoryExperiment(data_setup.params.material, tests0).model({})
    else:
        h = [np.full_like(x, 0.01) for _ in times_s]
        fr = np.full(n_frames, 0.3)
        rests = [np.full(n_frames, 0.3) for _ in JOINT_REST_S]
        taus = [np.ones(int(np.isfinite(t.tau_pa).sum())) for t in tests0]
    fr = noisy(fr, sig["runout-series"])
    rests = [noisy(f, sig["rest-times"]) for f in rests]
    tests = []
    for t, tau in zip(tests0, taus, strict=True):
        full = np.full(t.t_s.shape, np.nan)
        ln = np.log(np.asarray(tau, float))
        full[np.isfinite(t.tau_pa)] = np.exp(ln + (sig["transient"] * rng.standard_normal(ln.shape) if noise else 0.0))
        tests.append(ShearTest(t.label, t.t_s, t.gamma_dot_1_s, full, None, "synthetic"))

    profiles = [Profile(x, hk, t, np.full_like(x, sig["profiles"]), "synthetic") for t, hk in
                zip(times_s, h, strict=True)]
    exps = [
        ProfileExperiment(fit_setup, profiles, bandwidth_m=bw, name="profiles"),
        RunoutSeriesExperiment(fit_setup, frame_t, fr, sigma_m=sig["runout-series"], bandwidth_m=bw,
                               name="runout series"),
        RestTimeExperiment(fit_setup, [(tr, frame_t, f, sig["rest-times"]) for tr, f in
                                       zip(JOINT_REST_S, rests, strict=True)], bandwidth_m=bw, name="rest times"),
        ShearHistoryExperiment(fit_setup.params.material, tests, sigma_ln=sig["transient"], name="transients"),
    ]
    data = {"profiles": profiles, "runout-series": (frame_t, fr), "rest-times": list(zip(JOINT_REST_S, rests)),
            "transient": tests}
    return exps, fit_setup, data


def write_joint_twin(out_dir, truth=None, **kw) -> dict:
    """Write the joint twin's data (:func:`joint_twin`, same keywords) as the files of
    ``mpmjax calibrate``: profiles.csv, runout_series.csv, rest_times.csv, transients.csv, each
    labelled SYNTHETIC with its truth in a ``#`` header.  Returns {kind: path}."""
    truth = dict(JOINT_TRUTH if truth is None else truth)
    _, setup, d = joint_twin(truth, **kw)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    head = (
        f"SYNTHETIC data (not measured): mpmjax joint twin, calibration.synthetic.write_joint_twin.\n"
        f"scene twin-small-dambreak.toml at h = {setup.scene.h} m; Coussot truth {truth}; noise sigma "
        f"{JOINT_SIGMA} (m for heights and fronts, ln tau for stresses), seed {kw.get('seed', 5)}."
    )
    names = {"profiles": "profiles", "runout-series": "runout_series", "rest-times": "rest_times", "transient": "transients"}
    paths = {k: out / f"{v}.csv" for k, v in names.items()}
    write_profiles_csv(paths["profiles"], d["profiles"], head + "\ncolumns: x_m [m], h_m [m], t_s [s], sigma_m [m]")
    t, f = d["runout-series"]
    write_table_csv(paths["runout-series"], {"t_s": t, "x_front_m": f, "sigma_m": np.full(t.size, JOINT_SIGMA["runout-series"])},
                    head + "\ncolumns: t_s [s], x_front_m [m] (free-surface front), sigma_m [m]")
    rows = [(tr, tk, fk) for tr, fr in d["rest-times"] for tk, fk in zip(t, fr, strict=True)]
    a = np.asarray(rows, float)
    write_table_csv(paths["rest-times"], {"t_rest_s": a[:, 0], "t_s": a[:, 1], "x_front_m": a[:, 2],
                                          "sigma_m": np.full(len(rows), JOINT_SIGMA["rest-times"])},
                    head + "\ncolumns: t_rest_s [s] (rest before the release), t_s [s] (since the release), "
                    "x_front_m [m], sigma_m [m]")
    tests = d["transient"]
    cols = {
        "test": np.concatenate([np.full(ts.t_s.size, float(ts.label)) for ts in tests]),
        "t_s": np.concatenate([ts.t_s for ts in tests]),
        "gamma_dot_1_s": np.concatenate([ts.gamma_dot_1_s for ts in tests]),
        "tau_pa": np.concatenate([ts.tau_pa for ts in tests]),
    }
    cols["sigma_ln"] = np.full(cols["t_s"].size, JOINT_SIGMA["transient"])
    write_table_csv(paths["transient"], cols, head + "\ncolumns: test, t_s [s], gamma_dot_1_s [1/s] (the rate on "
                    "(previous t_s, t_s]), tau_pa [Pa] (empty: a schedule row), sigma_ln [-]")
    return paths


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
