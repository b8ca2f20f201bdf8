"""Parameter uncertainty at the optimum: the Gauss-Newton (Fisher) approximation.

With normalised residuals r_e = (model - data)/sigma of each experiment e and their
Jacobian J_e = dr_e/dtheta (forward mode, ``jax.jacfwd``, one tangent per free
parameter), the Fisher information of independent Gaussian errors is

    F = sum_e J_e^T J_e / s_e^2,

where s_e^2 = 1 when the experiment's sigma is known (``sigma_known``), and otherwise the
residual variance estimated from the fit, s_e^2 = sum(r_e^2) / max(N_e - p, 1) (N_e
residuals, p free parameters): the data's own scatter sets the scale.  The covariance is
C = F^-1 (pseudo-inverse on the well-conditioned subspace), std_k = sqrt(C_kk), and the
correlation corr_kl = C_kl / (std_k std_l).

Identifiability: F is also analysed in relative (log-parameter) form, F_log = D F D with
D = diag(theta).  Its eigenvector of smallest eigenvalue is the combination of
parameters the data constrain least, reported as a power law prod theta_k^{a_k}
(e.g. alpha^0.7 T^0.7 when a profile constrains only alpha*T).  Warnings are raised for
|corr| > ``corr_warn`` (default 0.95), a relative standard deviation above
``rel_std_warn`` (default 0.5: a factor of ~1.6 either way), and a condition number of
F_log above 1e8 (numerically unidentifiable).  The approximation is local (linearised
model at the optimum) and assumes uncorrelated Gaussian errors; for strongly
non-linear or multi-modal cases, compare multi-start fits.

Which experiment pinned which parameter (:func:`identifiability`): the Fisher information of
independent experiments is additive, F = sum_e F_e, so the experiments added in turn give the
partial sums F_1, F_1 + F_2, ... and their standard deviations and correlations, all from the
one Jacobian above.  The loss weights w_e do not enter F: they steer the optimiser, while the
information is the data's (their sigma).

Numerical (discretisation) uncertainty: the residuals of a fit at a coarse grid are mostly
the grid's resolution error, which the Fisher matrix above does not see.  Fitting the same
data at several cell sizes h_1 > h_2 > ... > h_L (``calibration.multilevel``) measures it:
:func:`numerical_uncertainty` turns the fitted values per level into a numerical standard
deviation of the finest level's value, and :func:`combine` adds it to the statistical one,
std = sqrt(std_statistical^2 + std_numerical^2).

* Two levels: std_numerical = |theta_L - theta_{L-1}|, the shift between the last two
  levels.  If the fitted value converges as theta(h) = theta_inf + C h^p with p >= 1 and
  h_{L-1}/h_L = 2, the finest level's remaining error is shift / (2^p - 1) <= shift.
* Three or more levels: the last three give an observed order p per parameter (solved from
  (theta_1 - theta_2)/(theta_2 - theta_3) = (h_1^p - h_2^p)/(h_2^p - h_3^p)).  Where the two
  differences have the same sign and p lies in ``order_range`` (default 0.5 .. 6), the
  value is Richardson-extrapolated to theta_inf and std_numerical = |theta_L - theta_inf|
  (for p < 1 this is larger than the last shift).  Otherwise nothing is extrapolated, the
  reason is recorded, and std_numerical falls back to the last shift.

* At fixed parameters (the default with two or more levels, issue 32): the fine model's
  residuals R_f and Jacobian J_f at the coarse optimum theta_c (what the fine level's first
  Levenberg-Marquardt evaluation computes anyway) carried through the Gauss-Newton normal
  equations, dz = -(J_f^T J_f)^+ J_f^T R_f: the shift of the optimum that the change of the
  residuals between the grids implies to first order, with no re-optimisation, so that a refit
  which wanders along a flat valley or jumps to another basin does not inflate it.
  std_numerical = |(dtheta/dz) dz| (``linear``; the Gauss-Newton step in the parameters
  themselves, the same whatever the transform); the refit's own shift stays reported
  (``refit_std``) and the fitted value stays the refit's.  With three or more levels the
  Richardson estimate (above) is used where it applies, else the fixed-parameter one.

Goodness of fit (:func:`goodness_of_fit`): where an experiment's sigma is known, its residuals at an
optimum are the noise, so chi^2 = sum(r_e^2) over those experiments follows a chi^2 law with
nu = sum N_e - p degrees of freedom.  A chi^2 beyond its 1e-3 upper tail (``GOF_P_WARN``) says
the fit did not reach the data's noise level: stopped before the optimum, in another optimum, or
with a model (or grid) that cannot represent the data; the statistical std, which assumes that it
did, is then too small by about sqrt(chi^2 / nu) (the Birge ratio).  It is reported and warned
about, not applied: the numerical std of a multi-level fit already carries the grid's part.
Measured on the joint coverage twins (docs/calibration-coverage.md): a finer level stopped at its
iteration cap ended at 10x the noise floor's loss with alpha 2-4 total std from its truth.

A parameter is *poorly identified* when its statistical relative std exceeds ``rel_std_warn``
(or is not finite), or when its total relative std does: std / |theta| > 0.5 means the 2 sigma
interval reaches zero, i.e. it is wider than the value itself.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

import mpmjax

from .experiments import joint_residuals

__all__ = [
    "NumericalUncertainty",
    "Uncertainty",
    "combine",
    "fisher_by_experiment",
    "from_fisher",
    "gauss_newton",
    "identifiability",
    "identifiability_lines",
    "information_terms",
    "fixed_parameter_shift",
    "gauss_newton_step",
    "numerical_uncertainty",
]

# relative std above which a parameter is named poorly identified (statistical or total)
REL_STD_WARN = 0.5
# observed convergence orders accepted for Richardson extrapolation
ORDER_RANGE = (0.5, 6.0)
# upper-tail probability of chi^2 below which a fit is said not to have reached its data's noise level
GOF_P_WARN = 1e-3


class Uncertainty(NamedTuple):
    """names: free parameters (order of the arrays); theta: values [SI]; std: standard
    deviations [SI]; rel_std: std/|theta|; cov: covariance; corr: correlation matrix;
    fisher: F; noise_scale: s_e per experiment (1 when sigma is known); weakest: the least
    determined combination {name: exponent}; condition: condition number of F_log;
    warnings: human-readable warnings; poorly_identified: names whose relative std exceeds
    the threshold (or is not finite); fisher_parts: each experiment's F_e (they sum to F);
    experiment_names: their names."""

    names: tuple
    theta: np.ndarray
    std: np.ndarray
    rel_std: np.ndarray
    cov: np.ndarray
    corr: np.ndarray
    fisher: np.ndarray
    noise_scale: list
    weakest: dict
    condition: float
    warnings: list
    poorly_identified: tuple = ()
    fisher_parts: tuple = ()
    experiment_names: tuple = ()
    goodness: dict | None = None

    def as_dict(self):
        n = self.names
        return {
            "std": {k: float(s) for k, s in zip(n, self.std, strict=True)},
            "rel_std": {k: float(s) for k, s in zip(n, self.rel_std, strict=True)},
            "corr": {a: {b: float(self.corr[i, j]) for j, b in enumerate(n)} for i, a in enumerate(n)},
            "noise_scale": [float(s) for s in self.noise_scale],
            "weakest_combination": self.weakest,
            "condition_number_log": float(self.condition),
            "warnings": list(self.warnings),
            "poorly_identified": list(self.poorly_identified),
            "goodness_of_fit": self.goodness,
        }


def information_terms(experiments, pset, theta: dict):
    """The pieces of the Fisher matrix at ``theta`` (name -> value): (theta vector [SI] in the
    order of ``pset.free``, residual vectors r_e, their Jacobians J_e = dr_e/dtheta (forward
    mode, ``jax.jacfwd``), and the noise scale s_e per experiment (1 when ``sigma_known``,
    else sqrt(sum(r_e^2) / max(N_e - p, 1)))), so that F = sum_e J_e^T J_e / s_e^2."""
    names = pset.free
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    th = jnp.asarray([float(theta[k]) for k in names], dt)

    def res(vec):
        return joint_residuals(experiments, pset.values({k: vec[i] for i, k in enumerate(names)}))

    rs = [np.asarray(r, float) for r in res(th)]
    with mpmjax.flat_transfers():  # tangents batched, the stencil not: flat transfers (calibration.fit)
        Js = [np.asarray(J, float) for J in jax.jacfwd(res)(th)]
    p = len(names)
    scales = []
    for e, r, J in zip(experiments, rs, Js, strict=True):
        if not np.all(np.isfinite(J)):
            raise FloatingPointError(f"{getattr(e, 'name', 'experiment')}: non-finite Jacobian at {theta}")
        s2 = 1.0 if e.sigma_known else float(np.sum(r**2)) / max(r.size - p, 1)
        scales.append(float(np.sqrt(max(s2, np.finfo(float).tiny))))
    return np.asarray(th, float), rs, Js, scales


def fisher_by_experiment(experiments, pset, theta: dict):
    """Each experiment's Fisher information at ``theta``: (names, theta vector, [F_e], [s_e]) with
    F_e = J_e^T J_e / s_e^2 (module docstring), from one forward-mode Jacobian of all residuals."""
    thv, _, Js, scales = information_terms(experiments, pset, theta)
    return tuple(pset.free), thv, _fisher_parts(Js, scales), scales


def _fisher_parts(Js, scales) -> list:
    """F_e = J_e^T J_e / s_e^2 per experiment."""
    return [J.T @ J / s**2 for J, s in zip(Js, scales, strict=True)]


def goodness_of_fit(labels, residuals, known, p: int) -> dict | None:
    """chi^2 of the experiments whose sigma is known (module docstring): {"chi2", "dof", "reduced"
    (chi2 / dof), "p_value" (upper tail, float64 on the host whatever the model's precision),
    "experiments": {label: {"chi2", "n", "mean_square"}}} (a label used twice gets " (2)", ...);
    None when no experiment's sigma is known (their scale is then estimated from the residuals)."""
    per = {}
    for lb, r, k in zip(labels, residuals, known, strict=True):
        if not k:
            continue
        name, i = lb, 1
        while name in per:
            i += 1
            name = f"{lb} ({i})"
        r = np.asarray(r, float)
        per[name] = {"chi2": float(np.sum(r**2)), "n": int(r.size), "mean_square": float(np.mean(r**2)) if r.size else 0.0}
    if not per:
        return None
    chi2 = sum(e["chi2"] for e in per.values())
    dof = sum(e["n"] for e in per.values()) - p
    if dof < 1:
        return {"chi2": chi2, "dof": dof, "reduced": None, "p_value": None, "experiments": per}
    return {"chi2": chi2, "dof": dof, "reduced": chi2 / dof, "p_value": float(scipy.stats.chi2.sf(chi2, dof)),
            "experiments": per}


def _goodness_warning(g: dict | None) -> list:
    if g is None or g["p_value"] is None or g["p_value"] >= GOF_P_WARN:
        return []
    each = ", ".join(f"{k} {e['mean_square']:.3g}" for k, e in g["experiments"].items())
    return [
        f"the residuals exceed the noise their sigma allows: chi^2 = {g['chi2']:.4g} over {g['dof']} degrees of freedom "
        f"(chi^2/nu = {g['reduced']:.3g}, upper tail p = {g['p_value']:.2g}; mean squared normalised residual per "
        f"experiment: {each}, 1 at the noise level): the fit did not reach the data's noise level (stopped before the "
        "optimum, another optimum, or a model or grid that cannot represent the data), and the statistical std, "
        f"which assumes it did, is too small by about sqrt(chi^2/nu) = {math.sqrt(g['reduced']):.3g}"
    ]


def gauss_newton(
    experiments, pset, theta: dict, *, corr_warn: float = 0.95, rel_std_warn: float = REL_STD_WARN
) -> Uncertainty:
    """Gauss-Newton uncertainty of the free parameters of ``pset`` at ``theta`` (name ->
    value, e.g. ``FitResult.params``).  See the module docstring."""
    names = tuple(pset.free)
    thv, rs, Js, scales = information_terms(experiments, pset, theta)
    parts = _fisher_parts(Js, scales)
    unc = from_fisher(names, thv, sum(parts), corr_warn=corr_warn, rel_std_warn=rel_std_warn)
    labels = tuple(getattr(e, "name", f"experiment {i + 1}") for i, e in enumerate(experiments))
    g = goodness_of_fit(labels, rs, [bool(e.sigma_known) for e in experiments], len(names))
    return unc._replace(
        noise_scale=scales, fisher_parts=tuple(parts), experiment_names=labels, goodness=g,
        warnings=list(unc.warnings) + _goodness_warning(g),
    )


def from_fisher(names, thv, F, *, corr_warn: float = 0.95, rel_std_warn: float = REL_STD_WARN) -> Uncertainty:
    """Standard deviations, correlations, the weakest combination and the warnings of the
    Fisher matrix ``F`` of the parameters ``names`` at ``thv`` (module docstring)."""
    names = tuple(names)
    p = len(names)
    D = np.diag(np.abs(thv))
    Flog = D @ F @ D
    w, V = np.linalg.eigh(Flog)
    wmax = max(float(w[-1]), np.finfo(float).tiny)
    keep = w > wmax * 1e-12
    cond = float(wmax / w[0]) if w[0] > 0 else float("inf")
    # covariance of log-parameters on the determined subspace, then back to SI
    Clog = (V[:, keep] / w[keep]) @ V[:, keep].T
    cov = D @ Clog @ D
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if not keep.all():
        std = np.where(np.abs(V[:, ~keep]).max(axis=1) > 1e-3, np.inf, std)
    rel = std / np.maximum(np.abs(thv), np.finfo(float).tiny)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[~np.isfinite(corr)] = np.nan
    np.fill_diagonal(corr, 1.0)
    v0 = V[:, 0] / np.max(np.abs(V[:, 0]))
    weakest = {
        k: float(round(a, 3))
        for k, a in zip(names, v0 * np.sign(v0[np.argmax(np.abs(v0))]), strict=True)
        if abs(a) > 0.05
    }
    warns = []
    for i in range(p):
        for j in range(i + 1, p):
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > corr_warn:
                warns.append(
                    f"{names[i]} and {names[j]} are strongly correlated (r = {corr[i, j]:+.3f}): the data constrain "
                    f"a combination of them rather than each one"
                )
    poorly = tuple(k for k, r in zip(names, rel, strict=True) if not np.isfinite(r) or r > rel_std_warn)
    for k in poorly:
        warns.append(f"{k} is poorly identified: relative standard deviation {rel[names.index(k)]:.3g}")
    if cond > 1e8:
        warns.append(
            f"the relative Fisher matrix has condition number {cond:.3g} (> 1e8): not identifiable numerically"
        )
    if warns:
        combo = " * ".join(f"{k}^{a:g}" for k, a in weakest.items())
        warns.append(f"least determined combination: {combo} (relative std {1 / np.sqrt(max(w[0], 1e-300)):.3g})")
    return Uncertainty(names, thv, std, rel, cov, corr, F, [], weakest, cond, warns, poorly)


# relative std below which an experiment is said to pin a parameter (identifiability report)
PIN_REL_STD = 0.1


def identifiability(unc: Uncertainty, *, pin_rel_std: float = PIN_REL_STD) -> dict:
    """Which experiment pinned which parameter: the experiments of ``unc`` (a
    :func:`gauss_newton` result) added in turn, in their order, with the parameters' standard
    deviations and correlations after each addition.  The Fisher information of independent
    experiments is additive, so each step is the inverse of a partial sum of the experiments'
    F_e (no new model evaluation).  A parameter is *pinned by* the experiment whose addition
    first brought its relative std below ``pin_rel_std`` (default 0.1); ``None`` if none did.
    Returns a JSON-ready dict: ``steps`` (per experiment: ``added``, ``std``, ``rel_std``,
    ``corr``; std null where not determined), ``pinned_by``, ``pin_rel_std``."""
    if not unc.fisher_parts:
        raise ValueError("identifiability needs a gauss_newton result (it holds each experiment's Fisher matrix)")
    names = unc.names
    F = np.zeros_like(unc.fisher)
    steps, pinned = [], dict.fromkeys(names)

    def clean(v):
        return float(v) if np.isfinite(v) else None

    for label, Fe in zip(unc.experiment_names, unc.fisher_parts, strict=True):
        F = F + Fe
        u = from_fisher(names, unc.theta, F)
        steps.append(
            {
                "added": label,
                "std": {k: clean(v) for k, v in zip(names, u.std, strict=True)},
                "rel_std": {k: clean(v) for k, v in zip(names, u.rel_std, strict=True)},
                "corr": {a: {b: clean(u.corr[i, j]) for j, b in enumerate(names)} for i, a in enumerate(names)},
            }
        )
        for k, r in zip(names, u.rel_std, strict=True):
            if pinned[k] is None and np.isfinite(r) and r < pin_rel_std:
                pinned[k] = label
    return {"steps": steps, "pinned_by": pinned, "pin_rel_std": pin_rel_std}


def identifiability_lines(report: dict) -> list:
    """The identifiability report as text: per step the relative std of every parameter and
    the largest correlations, then which experiment pinned which parameter."""
    steps = report["steps"]
    names = list(steps[0]["std"])
    w = max(len(s["added"]) for s in steps) + 2
    out = ["  identifiability (experiments added in turn; relative std, then |corr| > 0.9):"]
    out.append("    " + "+ experiment".ljust(w) + " ".join(f"{k:>9s}" for k in names))
    for s in steps:
        rel = " ".join(f"{'inf' if s['rel_std'][k] is None else format(s['rel_std'][k], '.3g'):>9s}" for k in names)
        strong = [
            f"{a}-{b} {s['corr'][a][b]:+.3f}"
            for i, a in enumerate(names)
            for b in names[i + 1 :]
            if s["corr"][a][b] is not None and abs(s["corr"][a][b]) > 0.9
        ]
        out.append("    " + ("+ " + s["added"]).ljust(w) + rel + ("  " + ", ".join(strong) if strong else ""))
    pins = ", ".join(f"{k}: {v or 'none'}" for k, v in report["pinned_by"].items())
    out.append(f"  pinned by (relative std first < {report['pin_rel_std']:g}): {pins}")
    return out


class NumericalUncertainty(NamedTuple):
    """Discretisation uncertainty of fitted values from fits at several cell sizes (module
    docstring).  cell_sizes_m: the levels, coarse to fine; values: name -> fitted value per
    level; std: name -> numerical std of the finest level's value; method: name -> "shift",
    "richardson" or "linear" (at fixed parameters); order: name -> observed order p (None where
    not available); extrapolated: name -> Richardson value theta_inf (None where not
    extrapolated); reason: name -> why not extrapolated (None where it was); linear: name ->
    the signed shift of the last two levels at fixed parameters (None where not computed);
    refit_std: name -> what std would be from the refit values alone (the last shift, or the
    Richardson estimate)."""

    cell_sizes_m: tuple
    values: dict
    std: dict
    method: dict
    order: dict
    extrapolated: dict
    reason: dict
    linear: dict | None = None
    refit_std: dict | None = None

    def as_dict(self):
        d = {
            "cell_sizes_m": list(self.cell_sizes_m),
            "values_per_level": {k: list(v) for k, v in self.values.items()},
            "method": dict(self.method),
            "richardson": {
                k: {"extrapolated": self.extrapolated[k], "order": self.order[k], "why_not": self.reason[k]}
                for k in self.values
            },
        }
        if self.linear is not None:
            refit = {k: v[-1] - v[-2] for k, v in self.values.items()}
            d["estimators"] = {
                "fixed_parameters": {k: (abs(v) if v is not None else None) for k, v in self.linear.items()},
                "refit": dict(self.refit_std or {}),
                "definition": FIXED_PARAMETER_DEFINITION,
            }
            d["shift_linear"] = dict(self.linear)
            d["shift_refit"] = refit
            d["shift_nonlinear"] = {
                k: (refit[k] - v if v is not None else None) for k, v in self.linear.items()
            }
        return d


FIXED_PARAMETER_DEFINITION = (
    "fixed_parameters: |dtheta| with dtheta = (dtheta/dz) dz, dz = -(J_f^T J_f)^+ J_f^T R_f, the fine level's "
    "residuals R_f and Jacobian J_f (in the fit's transformed z) at the coarser level's optimum theta_c, carried "
    "through the Gauss-Newton normal equations (no re-optimisation; the same step as in the parameters "
    "themselves); refit: |theta_L - theta_(L-1)| of the refitted values (or the Richardson estimate with three "
    "levels); shift_nonlinear = shift_refit - shift_linear"
)


def _observed_order(h, d1, d2, lo, hi):
    """p with (h1^p - h2^p)/(h2^p - h3^p) = d1/d2 in [lo, hi] (bisection; the ratio grows
    with p for h1 > h2 > h3), or None with the reason."""
    q = d1 / d2

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p)

    if q <= 0:
        return None, "the differences between levels change sign (not in the asymptotic range)"
    if not g(lo) <= q <= g(hi):
        p_r = math.log(q) / math.log(h[1] / h[2]) if h[0] / h[1] == h[1] / h[2] else None
        shown = f"{p_r:.3g}" if p_r is not None else ("< " if q < g(lo) else "> ") + f"{lo if q < g(lo) else hi:g}"
        return None, f"observed order {shown} is outside {lo:g} .. {hi:g}"
    a, b = lo, hi
    for _ in range(200):
        m = 0.5 * (a + b)
        a, b = (m, b) if g(m) < q else (a, m)
    return 0.5 * (a + b), None


def numerical_uncertainty(
    cell_sizes_m, values: dict, *, order_range=ORDER_RANGE, linear: dict | None = None
) -> NumericalUncertainty:
    """Numerical std of the finest level's fitted values (module docstring).

    cell_sizes_m: the levels' cell sizes [m], strictly decreasing (at least two); values:
    name -> sequence of the fitted value at each level; linear: optional name -> the signed
    shift of the last two levels at fixed parameters (:func:`fixed_parameter_shift`): then it
    is the std where Richardson does not apply (method "linear"), and the refit's own estimate
    is kept as ``refit_std``."""
    h = [float(x) for x in cell_sizes_m]
    if len(h) < 2 or any(not (b < a) for a, b in zip(h, h[1:])) or h[-1] <= 0:
        raise ValueError(f"cell sizes {h}: need at least two levels, strictly decreasing and > 0 [m]")
    std, method, order, extra, reason = {}, {}, {}, {}, {}
    for k, vs in values.items():
        v = [float(x) for x in vs]
        if len(v) != len(h):
            raise ValueError(f"{k}: {len(v)} values for {len(h)} levels")
        shift = abs(v[-1] - v[-2])
        std[k], method[k], order[k], extra[k] = shift, "shift", None, None
        if len(h) < 3:
            reason[k] = "two levels give no observed order"
            continue
        d1, d2 = v[-3] - v[-2], v[-2] - v[-1]
        if d1 == 0 or d2 == 0:
            reason[k] = "no change between two levels: no observed order"
            continue
        p, why = _observed_order(h[-3:], d1, d2, *order_range)
        reason[k] = why
        if p is None:
            continue
        c = d2 / (h[-2] ** p - h[-1] ** p)
        inf = v[-1] - c * h[-1] ** p
        std[k], method[k], order[k], extra[k] = abs(v[-1] - inf), "richardson", p, inf
    vals = {k: [float(x) for x in v] for k, v in values.items()}
    refit_std = dict(std)
    if linear is not None:
        linear = {k: (None if linear.get(k) is None or not math.isfinite(linear[k]) else float(linear[k]))
                  for k in values}
        for k in values:
            if method[k] != "richardson" and linear[k] is not None:
                std[k], method[k] = abs(linear[k]), "linear"
    return NumericalUncertainty(tuple(h), vals, std, method, order, extra, reason, linear,
                                refit_std if linear is not None else None)


def gauss_newton_step(R, J, rcond: float = 1e-6):
    """dz = -(J^T J)^+ J^T R by a truncated SVD of J: singular values below ``rcond`` times the
    largest are dropped, so a direction the data do not determine does not move (the same
    truncation as :func:`from_fisher`'s 1e-12 on the eigenvalues of J^T J)."""
    J = np.asarray(J, float)
    R = np.asarray(R, float)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    keep = sv > rcond * max(float(sv[0]) if sv.size else 0.0, np.finfo(float).tiny)
    return -(Vt[keep].T @ ((U[:, keep].T @ R) / sv[keep]))


def fixed_parameter_shift(pset, result, experiments, dtype=None) -> tuple:
    """The signed shift, name -> value [SI], of a refined level's optimum implied to first order
    by the change of the residuals between the grids at fixed parameters (module docstring):
    the Gauss-Newton step of the refined level's residuals from its starting point (the coarser
    optimum, ``pset``'s initial values).  With Levenberg-Marquardt (``result.residuals_initial``)
    it costs nothing: the fine level's first evaluation computed R_f and J_f there; otherwise one
    forward-mode Jacobian of ``experiments`` at that point.  Returns (shift, how)."""
    names = pset.free
    dt = dtype or (jnp.float64 if jax.config.jax_enable_x64 else jnp.float32)
    z0 = np.asarray(pset.z0(dt), float)
    th0 = {k: float(v) for k, v in pset.theta(jnp.asarray(z0, dt)).items()}
    rj = (getattr(result, "residuals_initial", None) or [None])[0]
    if rj is not None:
        R, J = rj
        dz = gauss_newton_step(R, J)
        # the step in the parameters themselves: dtheta = (dtheta/dz) dz, which is the Gauss-Newton
        # step of the residuals as functions of theta (J_theta = J_z (dtheta/dz)^-1), whatever the
        # transform; mapping z0 + dz through the transform instead would saturate at a bound
        D = np.diag(np.asarray(jax.jacfwd(pset.theta_vector)(jnp.asarray(z0, dt)), float))
        return {k: float(D[i] * dz[i]) for i, k in enumerate(names)}, "lm"
    thv, rs, Js, _ = information_terms(experiments, pset, th0)
    R = np.concatenate([np.sqrt(e.weight / r.size) * r.ravel() for e, r in zip(experiments, rs, strict=True)])
    J = np.concatenate(
        [np.sqrt(e.weight / r.size) * Jm.reshape(r.size, -1) for e, r, Jm in zip(experiments, rs, Js, strict=True)]
    )
    dth = gauss_newton_step(R, J)
    return {k: float(dth[i]) for i, k in enumerate(names)}, "gauss-newton"


def combine(unc: Uncertainty, numerical: NumericalUncertainty | None, *, rel_std_warn: float = REL_STD_WARN) -> dict:
    """Statistical (``unc``, at the finest level) and numerical std combined per parameter:
    {"std_statistical", "std_numerical", "std", "rel_std"}: name -> value (None where not
    finite or not estimated), and "poorly_identified": the names flagged statistically
    (``unc.poorly_identified``) or whose total relative std exceeds ``rel_std_warn``."""
    stat = {k: float(s) for k, s in zip(unc.names, unc.std, strict=True)}
    num = {k: (float(numerical.std[k]) if numerical is not None else None) for k in unc.names}
    tot = {k: math.sqrt(stat[k] ** 2 + (num[k] or 0.0) ** 2) for k in unc.names}
    th = dict(zip(unc.names, (float(t) for t in unc.theta), strict=True))
    rel = {k: tot[k] / max(abs(th[k]), np.finfo(float).tiny) for k in unc.names}
    poorly = [k for k in unc.names if k in unc.poorly_identified or not math.isfinite(rel[k]) or rel[k] > rel_std_warn]

    def clean(d):
        return {k: (v if v is not None and math.isfinite(v) else None) for k, v in d.items()}

    return {
        "std_statistical": clean(stat),
        "std_numerical": clean(num) if numerical is not None else dict.fromkeys(unc.names),
        "std": clean(tot),
        "rel_std": clean(rel),
        "poorly_identified": poorly,
    }
