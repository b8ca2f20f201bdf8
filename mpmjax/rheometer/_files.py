"""The rheometer's files (``write_outputs``): viscosity_vs_time.png, flow_curve.png, rheometer.csv
and rheometer.json of constant-shear tests at a few rates."""

from __future__ import annotations

import csv
import json
import math
import os

import jax
import jax.numpy as jnp
import numpy as np

from .._rheology import Coussot, Law, law_of
from ._physics import (
    RheometerResult,
    _as_float_params,
    constant_shear,
    critical_point,
    steady_flow_curve,
    validate_params,
)


# --------------------------------------------------------------------------------------
# Output files
# --------------------------------------------------------------------------------------

# The model line of rheometer.json, by law (other laws: the first line of their docstring).
_MODEL_TEXT = {
    "coussot": "Coussot et al. (2002): dlam/dt = 1/T - alpha gdot lam; mu = min(mu0 (1 + lam^n), mu_max); tau = mu gdot"
}


def _csv_columns(law: Law) -> tuple[str, ...]:
    """t_s, gamma_dot_1_s, the internal variables' labels, mu_pa_s, tau_pa."""
    return ("t_s", "gamma_dot_1_s", *(i.label for i in law.internals), "mu_pa_s", "tau_pa")


def _params_json(params):
    return {p.name: {"value": float(getattr(params, p.name)), "unit": p.unit} for p in law_of(params).params}


def _steady_entry(law: Law, params, r: float) -> dict:
    """Steady state at the rate r [1/s]: each internal variable ("<label>_ss"), mu, tau and,
    for a law with one internal variable, the relaxation time 1/|d rate/d y| there [s]."""
    g = jnp.asarray(r, dtype=params[0].dtype)
    tau_ss, mu_ss = steady_flow_curve(params, g)
    entry = {"gamma_dot_1_s": r}
    y_ss = law.steady_internal(params, g)
    for i in law.internals:
        entry[f"{i.label}_ss"] = float(y_ss[i.name])
    entry["mu_ss_pa_s"] = float(mu_ss)
    entry["tau_ss_pa"] = float(tau_ss)
    if len(law.internals) == 1:
        name = law.internals[0].name
        _, d = jax.jvp(
            lambda y: law.rate(params, g, {name: y})[name], (y_ss[name],), (jnp.ones_like(y_ss[name]),)
        )
        entry["relaxation_time_s"] = 1.0 / abs(float(d))
    return entry


def write_outputs(out_dir, params, rates, t_s) -> dict:
    """Run constant-shear tests at each rate and write the rheometer files.

    out_dir: folder (created if needed); params: any registered law's parameters (the
    law needs a steady state, ``Law.steady_internal``, for the flow curve); rates [1/s]
    (> 0); t_s [s] save times (> 0 for the log-log plot).  Writes

    * ``viscosity_vs_time.png``: mu(t) log-log, one curve per rate, steady values
      dotted (cf. thesis Figs. 7, 26, 31);
    * ``flow_curve.png``: tau_ss(gdot) log-log with the critical point (Coussot, n > 1) marked;
    * ``rheometer.csv``: columns t_s, gamma_dot_1_s, the internal variables (Coussot:
      lambda), mu_pa_s, tau_pa (one block of rows per rate);
    * ``rheometer.json``: parameters with units, rates, steady states, critical point,
      solver settings and the file list.

    Returns the JSON content as a dict.
    """
    # matplotlib only when files are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")

    params = _as_float_params(params)
    validate_params(params)
    law = law_of(params)()
    coussot = isinstance(law, Coussot)
    rates = [float(r) for r in np.atleast_1d(np.asarray(rates, dtype=float))]
    if not rates or any(not (math.isfinite(r) and r > 0) for r in rates):
        raise ValueError(f"rates = {rates} is invalid; allowed range: each > 0 1/s (finite)")
    t_arr = np.atleast_1d(np.asarray(t_s, dtype=float))
    if t_arr.ndim != 1 or np.any(~np.isfinite(t_arr)) or np.any(t_arr <= 0) or np.any(np.diff(t_arr) < 0):
        raise ValueError("t_s must be a 1-D, non-decreasing array of times > 0 s")
    os.makedirs(out_dir, exist_ok=True)

    res_all = constant_shear(params, jnp.asarray(rates), t_arr)  # one solve, (k, m)
    results = [
        RheometerResult(
            res_all.t_s,
            res_all.gamma_dot_1_s[i],
            {k: v[i] for k, v in res_all.internal.items()},
            res_all.mu_pa_s[i],
            res_all.tau_pa[i],
        )
        for i in range(len(rates))
    ]
    steady = [_steady_entry(law, params, r) for r in rates]

    crit, crit_note = _critical(law, params)
    gc, tc = (crit["gamma_dot_c_1_s"], crit["tau_c_pa"]) if crit else (None, None)

    files = ["viscosity_vs_time.png", "flow_curve.png", "rheometer.csv", "rheometer.json"]
    columns = _csv_columns(law)

    _write_csv(os.path.join(out_dir, "rheometer.csv"), law, columns, results)
    _plot_viscosity(os.path.join(out_dir, "viscosity_vs_time.png"), law, params, rates, results, steady)
    _plot_flow_curve(os.path.join(out_dir, "flow_curve.png"), law, params, rates, steady, gc, tc)

    doc = (type(law).__doc__ or law.name).strip().splitlines()[0]
    meta = {
        "model": _MODEL_TEXT.get(law.name, f"{law.name}: {doc}"),
        "params": _params_json(params),
        "rates_1_s": rates,
        "t_s": {"min": float(t_arr[0]), "max": float(t_arr[-1]), "count": int(t_arr.size)},
        "steady_state": steady,
        "critical_point": crit,
        "critical_point_note": crit_note,
        "identifiable_from_flow_curve": ["mu0", "n", "alpha*T"] if coussot else None,
        "solver": {
            "method": "diffrax.Kvaerno5",
            "controller": "PIDController",
            "rtol": 1e-10,
            "atol": 1e-12,
            "dtype": str(params[0].dtype),
        },
        "csv_columns": list(columns),
        "files": files,
    }
    with open(os.path.join(out_dir, "rheometer.json"), "w") as f:
        json.dump(meta, f, indent=2)
    return meta


def _critical(law: Law, params) -> tuple[dict | None, str | None]:
    """rheometer.json's critical point (Coussot with n > 1: the flow curve's minimum) and, where
    there is none, the note saying why."""
    coussot = isinstance(law, Coussot)
    crit = None
    crit_note = None
    if not coussot:
        crit_note = f"the critical point is computed for the Coussot law only (law: {law.name})"
    elif float(params.n) > 1.0:
        n = float(params.n)
        gc, tc = (float(x) for x in critical_point(params))
        mu_c_uncapped = float(params.mu0) * (1.0 + 1.0 / (n - 1.0))
        crit = {
            "gamma_dot_c_1_s": gc,
            "tau_c_pa": tc,
            "mu_ss_c_pa_s": min(mu_c_uncapped, float(params.mu_max)),
            "cap_active": mu_c_uncapped >= float(params.mu_max),
        }
    else:
        crit_note = f"no flow-curve minimum for n = {float(params.n):g} <= 1"
    return crit, crit_note


def _write_csv(path, law: Law, columns, results) -> None:
    """rheometer.csv: ``columns``, one block of rows per rate's ``RheometerResult``."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for res in results:
            cols = [res.t_s, res.gamma_dot_1_s, *(res.internal[i.name] for i in law.internals), res.mu_pa_s, res.tau_pa]
            for row in zip(*(np.asarray(c) for c in cols)):
                w.writerow([f"{float(v):.12g}" for v in row])


def _plot_viscosity(path, law: Law, params, rates, results, steady) -> None:
    """viscosity_vs_time.png: mu(t) log-log, one curve per rate, steady values dotted."""
    # matplotlib only when files are written (optional heavy import)
    import matplotlib.pyplot as plt

    shown = ", ".join(
        f"{p.name}={float(getattr(params, p.name)):g}" + ("" if p.unit == "-" else f" {p.unit}")
        for p in law.params
        if p.name not in ("rho", "kappa")
    )
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for res, r, st in zip(results, rates, steady):
        (line,) = ax.loglog(np.asarray(res.t_s), np.asarray(res.mu_pa_s), label=f"{r:g} 1/s")
        ax.axhline(st["mu_ss_pa_s"], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("viscosity mu [Pa s]")
    ax.set_title(f"{law.name}: {shown}", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(title="shear rate", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_flow_curve(path, law: Law, params, rates, steady, gc, tc) -> None:
    """flow_curve.png: tau_ss(gdot) log-log, the rates measured, the critical point ``(gc, tc)`` if any."""
    # matplotlib only when files are written (optional heavy import)
    import matplotlib.pyplot as plt

    lo = min(rates + ([gc] if gc else [])) / 30.0
    hi = max(rates + ([gc] if gc else [])) * 30.0
    g = np.logspace(np.log10(lo), np.log10(hi), 400)
    tau_g, _ = steady_flow_curve(params, g)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    ax.loglog(g, np.asarray(tau_g), "k-", label="steady tau_ss")
    if "mu_max" in params._fields:
        tau_free, _ = steady_flow_curve(params._replace(mu_max=jnp.asarray(np.inf, params.mu_max.dtype)), g)
        if not np.allclose(np.asarray(tau_free), np.asarray(tau_g)):
            ax.loglog(g, np.asarray(tau_free), color="0.6", ls="--", lw=0.8, label="without cap mu_max")
    ax.loglog(rates, [s["tau_ss_pa"] for s in steady], "o", mfc="none", label="rheometer rates")
    if gc is not None:
        ax.loglog([gc], [tc], "r*", ms=12, label=f"critical point ({gc:.3g} 1/s, {tc:.3g} Pa)")
        ax.axvline(gc, color="r", ls=":", lw=0.8)
    ax.set_xlabel("shear rate gdot [1/s]")
    ax.set_ylabel("steady shear stress tau_ss [Pa]")
    ax.set_title(f"{law.name}: steady flow curve tau_ss = mu_ss(gdot) gdot", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
