"""The outputs of a calibration: the fit.json document, the printed summary and the plots
(``write_outputs``, called by ``calibration.run.calibrate`` in the process that writes)."""

from __future__ import annotations

import json

import jax
import numpy as np

import mpmjax

from .params import UNITS
from .profile import PROFILE_DEFINITION, plot_profiles
from .sweep import FIELD_KEYS
from .uncertainty import identifiability, identifiability_lines

__all__ = ["fit_document", "plot_fit", "summary_lines", "write_outputs"]


def _level_entries(ml) -> list:
    """fit.json's ``levels``: each level's cell size, size and fit."""
    return [
        {
            "cell_size_m": lv.cell_size_m,
            "n_particles": lv.n_particles,
            "n_steps": lv.n_steps,
            "params": lv.result.params,
            "loss_initial": lv.result.loss_initial,
            "loss_final": lv.result.loss_final,
            "iterations": lv.result.iterations,
            "converged": bool(lv.result.converged),
            "stop_reason": lv.result.reason,
            "wall_s": lv.result.wall_s,
            "cpu_s": lv.result.cpu_s,
            "evaluations": lv.result.evaluations,
            "loss_history": [float(v) for v in lv.result.history.min(axis=1)],
            "estimate": lv.estimate,
        }
        for lv in ml.levels
    ]


# what a one-level fit says about its std, in words (summary, fit.json, fit_profiles.png)
ONE_LEVEL_NOTE = (
    "resolution bias NOT ESTIMATED: one level (--levels 1); the std is statistical only and can be many times "
    "smaller than the grid's error (run the default two levels)"
)


def resolution_bias_text(ml) -> str:
    """fit.json's ``resolution_bias``: whether and how the grid's bias entered the std."""
    if ml.numerical is None:
        return ONE_LEVEL_NOTE
    hs = " -> ".join(f"{h:g}" for h in ml.numerical.cell_sizes_m)
    return f"estimated: std_numerical from {len(ml.numerical.cell_sizes_m)} levels (h = {hs} m)"


def _experiment_entries(exps, unc) -> list:
    """fit.json's ``experiments``: each experiment's kind, weight, size and noise scale."""
    return [
        {
            "name": e.name,
            "kind": type(e).__name__,
            "weight": e.weight,
            "n_residuals": e.n_residuals,
            "sigma_known": bool(e.sigma_known),
            "noise_scale": s,
        }
        for e, s in zip(exps, unc.noise_scale, strict=True)
    ]


def fit_document(ml, pset, warnings, wall, method, scene_name, overrides, levels, bandwidth_m, data, profiles,
                 profiles_lr) -> dict:
    """The fit.json document of a multilevel fit ``ml`` (``fit_multilevel``) of ``pset``."""
    res, unc, exps, comb = ml.result, ml.uncertainty, ml.experiments, ml.combined
    finest = f"domain.cell_size_m={levels[-1]!r}"
    doc = {
        "params": res.params,
        "std": comb["std"],
        "std_statistical": comb["std_statistical"],
        "std_numerical": comb["std_numerical"],
        "rel_std": comb["rel_std"],
        "poorly_identified": comb["poorly_identified"],
        "std_numerical_refit": (
            None if ml.numerical is None or ml.numerical.refit_std is None else dict(ml.numerical.refit_std)
        ),
        "std_definition": (
            "std = sqrt(std_statistical^2 + std_numerical^2); std_statistical: Gauss-Newton at the finest level; "
            "std_numerical: the shift of the optimum between the last two levels at fixed parameters (the fine "
            "level's residual change at the coarser optimum carried through the Gauss-Newton normal equations, "
            "method 'linear'), or with three levels where the observed order allows, |finest - Richardson "
            "extrapolate| (numerical_uncertainty.method); std_numerical_refit: the refitted values' own shift "
            "(the estimator before issue 32); null with one level"
        ),
        "resolution_bias": resolution_bias_text(ml),
        "numerical_uncertainty": None if ml.numerical is None else ml.numerical.as_dict(),
        "levels": _level_entries(ml),
        "loss_initial": ml.levels[0].result.loss_initial,
        "loss_final": res.loss_final,
        "iterations": res.iterations,
        "wall_s": wall,
        "converged": bool(res.converged),
        "stop_reason": res.reason,
        "units": {k: UNITS.get(k, "SI") for k in pset.specs},
        "initial": {k: pset.specs[k].init for k in pset.free},
        "fixed": {k: s.init for k, s in pset.specs.items() if s.fixed},
        "specs": pset.bounds_table(),
        "uncertainty": {**unc.as_dict(), "warnings": warnings},
        "identifiability": identifiability(unc),
        "experiments": _experiment_entries(exps, unc),
        "loss_definition": "sum over experiments of weight * mean(((model - data) / sigma)^2), dimensionless",
        "loss_history": [float(v) for v in res.history.min(axis=1)],
        "method": method,
        "gradient": res.gradient,
        "starts": ml.levels[0].result.starts,
        "finals": ml.levels[0].result.finals,
        "final_losses": [float(v) for v in ml.levels[0].result.final_losses],
        "best_start": ml.levels[0].result.best_start,
        "optima": ml.optima,
        "compile_s": res.compile_s,
        "n_processes": jax.process_count(),
        "n_devices": jax.device_count(),
        "cpu_s": res.cpu_s,
        "compile_cpu_s": res.compile_cpu_s,
        "evaluations": res.evaluations,
        "scene": scene_name,
        "scene_overrides": overrides
        + [finest]
        + [f"{FIELD_KEYS[k]}={v!r}" for k, v in res.params.items() if k in FIELD_KEYS],
        "bandwidth_m": bandwidth_m,
        "data": str(data),
        "profile_times_s": [p.t_s for p in profiles],
        "frame_time_offsets_s": list(exps[0].time_offsets_s),
        "sigma_known": exps[0].sigma_known,
        "code_version": mpmjax.__version__,
    }
    if profiles_lr is not None:
        doc["profile_interval_95"] = {k: list(p.interval_95) for k, p in profiles_lr.items()}
        doc["profile_likelihood"] = {
            "definition": PROFILE_DEFINITION,
            **{k: p.as_dict(UNITS.get(k, "SI")) for k, p in profiles_lr.items()},
        }
    return doc


def write_outputs(result, out, log) -> None:
    """Write fit.json and the plots of ``result`` (a ``calibration.run.CalibrationResult``) to
    ``out`` and print the summary through ``log``."""
    doc, pset, ml, profiles_lr = result.document, result.parameters, result.multilevel, result.profile_likelihood
    if profiles_lr is not None:
        plot_profiles(
            profiles_lr, out / "profile_likelihood.png", {k: UNITS.get(k, "SI") for k in pset.free},
            {k: pset.specs[k].transform for k in pset.free},
        )
    mpmjax.atomic_write_text(out / "fit.json", json.dumps(doc, indent=1))
    (out / "fit_progress.json").unlink(missing_ok=True)
    plot_fit(out, result.experiments[0], pset, ml, result.profiles, doc)
    for lv in ml.levels:
        r = lv.result
        log(
            f"calibrate: h = {lv.cell_size_m:g} m: loss {r.loss_initial:.4g} -> {r.loss_final:.4g} in {r.iterations} "
            f"iterations ({'converged: ' + r.reason if r.converged else 'not converged'}), "
            + ", ".join(f"{k} = {v:.5g}" for k, v in r.params.items())
        )
    log(f"calibrate: {result.wall_s:.1f} s; at h = {result.levels[-1]:g} m:")
    for line in summary_lines(doc) + identifiability_lines(doc["identifiability"]):
        log(line)
    log(
        f"wrote {out / 'fit.json'}, {out / 'fit_profiles.png'}, {out / 'loss_history.png'}"
        + (f", {out / 'profile_likelihood.png'}" if profiles_lr is not None else "")
    )


def _fmt(v):
    return "inf" if v is None else f"{v:.3g}"


def summary_lines(doc) -> list:
    """The fitted values with total, statistical and numerical std, the Richardson
    extrapolates and the poorly identified names: the printed summary (also the text of
    fit_profiles.png)."""
    num = doc.get("numerical_uncertainty")
    out = []
    for k, v in doc["params"].items():
        s = (
            f"  {k} = {v:.5g} +- {_fmt(doc['std'][k])} [{doc['units'].get(k, 'SI')}] "
            f"(statistical {_fmt(doc['std_statistical'][k])}"
        )
        if num is None:
            s += ", numerical not estimated)"
        else:
            how = {"shift": "shift", "richardson": "Richardson estimate", "linear": "shift at fixed parameters"}[
                num["method"][k]]
            s += f", numerical {_fmt(doc['std_numerical'][k])} from the {how}"
            refit = (doc.get("std_numerical_refit") or {}).get(k)
            s += f"; refit shift {_fmt(refit)})" if num["method"][k] == "linear" and refit is not None else ")"
        if k in doc["poorly_identified"]:
            s += "  POORLY IDENTIFIED"
        out.append(s)
    for k, p in doc.get("profile_likelihood", {}).items():
        if k == "definition":
            continue
        lo, hi = (_fmt(v) for v in p["profile_interval_95"])
        glo, ghi = (_fmt(v) for v in p["gauss_newton_interval_95"])
        out.append(
            f"  {k}: 95 % profile-likelihood interval {lo} .. {hi}, Gauss-Newton {glo} .. {ghi}"
            + ("  DISAGREE (factor > 2)" if p["warning"] else "")
        )
    opt = doc.get("optima")
    if opt is not None:
        n_opt = len(opt["optima"])
        word = "optima" if n_opt > 1 else "optimum"
        out.append(f"  {opt['n_starts']} starts, {n_opt} distinct {word} at the first level:")
        for o in opt["optima"]:
            vals = ", ".join(f"{k} = {v:.4g}" for k, v in o["params"].items())
            extra = (
                "" if o["chi2_above_best"] is None
                else f", chi2 +{o['chi2_above_best']:.3g}, d2 {o['d2_from_best']:.3g}"
            )
            out.append(f"    loss {o['loss']:.5g} (starts {', '.join(map(str, o['starts']))}{extra}): {vals}")
    if num is None:
        out.append("  " + ONE_LEVEL_NOTE)
    else:
        for k, r in num["richardson"].items():
            if r["extrapolated"] is not None:
                out.append(f"  Richardson: {k} -> {r['extrapolated']:.5g} (h -> 0, observed order {r['order']:.2f})")
            else:
                out.append(f"  Richardson: {k} not extrapolated: {r['why_not']}")
    return out


def plot_fit(out, exp, pset, ml, profiles, doc):
    """fit_profiles.png (data, fitted and initial profiles, the summary) and loss_history.png."""
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = ml.result
    init = {k: pset.specs[k].init for k in pset.free}
    h_init = [np.asarray(h) for h in exp.model_profiles(pset.values(init))]
    h_fit = [np.asarray(h) for h in exp.model_profiles(pset.values(res.params))]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, p in enumerate(profiles):
        c = colors[i % len(colors)]
        lab = "final" if p.t_s is None else f"t = {p.t_s:g} s"
        if p.sigma_m is not None:
            ax.errorbar(p.x_m, p.h_m, yerr=p.sigma_m, fmt="o", ms=3, color=c, label=f"data {lab}")
        else:
            ax.plot(p.x_m, p.h_m, "o", ms=3, color=c, label=f"data {lab}")
        ax.plot(p.x_m, h_fit[i], "-", color=c, label=f"fitted {lab}")
        ax.plot(p.x_m, h_init[i], ":", color=c, lw=1, label=f"initial guess {lab}" if i == 0 else None)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("height h [m]")
    hs = " -> ".join(f"{lv.cell_size_m:g}" for lv in ml.levels)
    ax.set_title(
        f"fitted at h = {hs} m: value +- total std (statistical, numerical)" if len(ml.levels) > 1
        else f"fitted at h = {hs} m (one level): value +- statistical std; resolution bias NOT estimated",
        fontsize=9,
    )
    ax.text(
        0.99, 0.97, "\n".join(ln.strip() for ln in summary_lines(doc)), transform=ax.transAxes, ha="right", va="top",
        fontsize=6.5, family="monospace", bbox={"boxstyle": "round", "fc": "white", "alpha": 0.85},
    )
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "fit_profiles.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 3.4))
    it0 = 0
    for lv in ml.levels:
        hist = lv.result.history
        ax.semilogy(it0 + np.arange(hist.shape[0]), hist, lw=1, label=f"h = {lv.cell_size_m:g} m")
        it0 += hist.shape[0] - 1
    ax.set_xlabel("iteration (all levels)")
    ax.set_ylabel("loss (dimensionless)")
    ax.set_title(f"loss {ml.levels[0].result.loss_initial:.3g} -> {res.loss_final:.3g}")
    if len(ml.levels) > 1:
        ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(out / "loss_history.png", dpi=110)
    plt.close(fig)
