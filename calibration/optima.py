"""The distinct optima of a multi-start fit, and whether the data can tell them apart.

``fit(..., n_starts=N)`` ends each start at its own point; :func:`distinct_optima` groups those
points into optima and compares them with the noise.  With Levenberg-Marquardt every start's
final residuals R and Jacobian J (in the fit's transformed parameters z) are known
(``FitResult.residuals_final``), so at no extra cost:

* chi^2 of each start: sum_e |r_e|^2 / s_e^2 (r_e the experiment's normalised residuals, s_e its
  noise scale: 1 when its sigma is known, else estimated from the best start's residuals as in
  ``calibration.uncertainty.gauss_newton``);
* the distance between two ends, in the Fisher metric of the best start:
  d^2 = dz^T F dz with F = sum_e J_e^T J_e / s_e^2.  If the loss were the Gauss-Newton quadratic
  around the best optimum, a point at distance d^2 would lie d^2 above it in chi^2.

Ends closer than d^2 = 1 (inside the best optimum's one-sigma ellipsoid) are the same optimum.
Two optima *disagree* when they lie further apart than the 95 % Gauss-Newton region
(d^2 > chi^2_p(0.95), p free parameters) and are *within the noise level* when their chi^2
differ by less than that same quantile: the data cannot tell them apart, although the
linearised uncertainty says they can, so the reported std (a local, one-basin figure) is too
small.  ``warnings`` says so.  Without the residuals (``lbfgs`` / ``adam``) the optima are
grouped by their values (relative difference < 1e-3) and only their losses are compared.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats

__all__ = ["OPTIMA_DEFINITION", "SAME_OPTIMUM_D2", "distinct_optima"]

# ends closer than this (Fisher metric of the best start) are one optimum
SAME_OPTIMUM_D2 = 1.0
# the probability of the Gauss-Newton region and of the chi^2 difference called "the noise level"
NOISE_LEVEL = 0.95

OPTIMA_DEFINITION = (
    "optima: the starts' end points grouped into distinct optima (Fisher distance d2 = dz^T F dz >= 1 from every "
    "other, F at the best start), best first; chi2_above_best: their chi^2 minus the best's (residuals over their "
    "noise scale); d2_from_best: their Fisher distance from the best; a warning names two optima that disagree "
    "(d2 > chi2_p(0.95)) while their chi^2 differ by less than chi2_p(0.95): the data cannot tell them apart"
)


def _segments(experiments, R):
    sizes = [int(e.n_residuals) for e in experiments]
    if sum(sizes) != R.size:
        return [slice(0, R.size)], [1.0], [1]
    out, a = [], 0
    for n in sizes:
        out.append(slice(a, a + n))
        a += n
    return out, [float(e.weight) for e in experiments], sizes


def distinct_optima(result, experiments, pset) -> dict | None:
    """The distinct optima of the multi-start fit ``result`` (``calibration.fit.FitResult``) of
    ``experiments``: a JSON-ready dict {"optima": [...], "warnings": [...], "threshold_chi2",
    "definition"} (module docstring), or None for a single start."""
    n = len(result.finals)
    if n < 2:
        return None
    names = list(pset.free)
    p = len(names)
    q = float(scipy.stats.chi2.ppf(NOISE_LEVEL, p))
    losses = np.asarray(result.final_losses, float)
    order = [int(k) for k in np.argsort(np.where(np.isfinite(losses), losses, np.inf))]
    best = order[0]
    rj = result.residuals_final
    have = rj is not None and all(x is not None for x in rj)
    groups, warns = [], []
    if have:
        segs, weights, sizes = _segments(experiments, np.asarray(rj[best][0]))
        known = [bool(getattr(e, "sigma_known", True)) for e in experiments] if len(segs) == len(experiments) else [
            all(bool(getattr(e, "sigma_known", True)) for e in experiments)]

        def normalised(R):  # the experiments' own residuals r_e from R = concat sqrt(w_e / N_e) r_e
            return [np.asarray(R)[s] * math.sqrt(nn / w) for s, w, nn in zip(segs, weights, sizes, strict=True)]

        rb = normalised(rj[best][0])
        s2 = [1.0 if kn else max(float(np.sum(r**2)) / max(r.size - p, 1), np.finfo(float).tiny)
              for kn, r in zip(known, rb, strict=True)]
        Jb = normalised(rj[best][1])
        F = sum(J.T @ J / s for J, s in zip(Jb, s2, strict=True))
        chi2 = [sum(float(np.sum(r**2)) / s for r, s in zip(normalised(rj[k][0]), s2, strict=True)) for k in range(n)]
        z = [np.asarray(pset.z_of_theta(result.finals[k]), float) for k in range(n)]

        def d2(a, b):
            dz = z[a] - z[b]
            return float(dz @ F @ dz)

        for k in order:
            g = next((g for g in groups if d2(k, g[0]) < SAME_OPTIMUM_D2), None)
            if g is None:
                groups.append([k])
            else:
                g.append(k)
        optima = [
            {"params": dict(result.finals[g[0]]), "loss": float(losses[g[0]]), "starts": sorted(g),
             "chi2_above_best": chi2[g[0]] - chi2[best], "d2_from_best": d2(g[0], best)}
            for g in groups
        ]
        for i, a in enumerate(groups):
            for b in groups[i + 1:]:
                dd, dc = d2(a[0], b[0]), abs(chi2[a[0]] - chi2[b[0]])
                if dd > q and dc < q:
                    va = ", ".join(f"{k} = {result.finals[a[0]][k]:.4g}" for k in names)
                    vb = ", ".join(f"{k} = {result.finals[b[0]][k]:.4g}" for k in names)
                    warns.append(
                        f"two optima within the noise level disagree: ({va}; loss {losses[a[0]]:.5g}, starts "
                        f"{sorted(a)}) and ({vb}; loss {losses[b[0]]:.5g}, starts {sorted(b)}) differ in chi^2 by "
                        f"{dc:.3g} < {q:.3g} (chi2_{p}(0.95)) but lie d^2 = {dd:.3g} apart in the Fisher metric: the "
                        "data cannot tell them apart, and the Gauss-Newton std (one optimum) understates the "
                        "uncertainty"
                    )
    else:
        for k in order:
            g = next(
                (g for g in groups if all(
                    abs(result.finals[k][nm] - result.finals[g[0]][nm]) <= 1e-3 * abs(result.finals[g[0]][nm])
                    for nm in names)),
                None,
            )
            if g is None:
                groups.append([k])
            else:
                g.append(k)
        optima = [{"params": dict(result.finals[g[0]]), "loss": float(losses[g[0]]), "starts": sorted(g),
                   "chi2_above_best": None, "d2_from_best": None} for g in groups]
    return {"optima": optima, "warnings": warns, "threshold_chi2": q, "n_starts": n,
            "compared_with_noise": bool(have), "definition": OPTIMA_DEFINITION}
