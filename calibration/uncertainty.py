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
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .experiments import joint_residuals

__all__ = ["Uncertainty", "gauss_newton"]


class Uncertainty(NamedTuple):
    """names: free parameters (order of the arrays); theta: values [SI]; std: standard
    deviations [SI]; rel_std: std/|theta|; cov: covariance; corr: correlation matrix;
    fisher: F; noise_scale: s_e per experiment (1 when sigma is known); weakest: the least
    determined combination {name: exponent}; condition: condition number of F_log;
    warnings: human-readable warnings."""

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
        }


def gauss_newton(experiments, pset, theta: dict, *, corr_warn: float = 0.95, rel_std_warn: float = 0.5) -> Uncertainty:
    """Gauss-Newton uncertainty of the free parameters of ``pset`` at ``theta`` (name ->
    value, e.g. ``FitResult.params``).  See the module docstring."""
    names = pset.free
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    th = jnp.asarray([float(theta[k]) for k in names], dt)

    def res(vec):
        return joint_residuals(experiments, pset.values({k: vec[i] for i, k in enumerate(names)}))

    rs = [np.asarray(r, float) for r in res(th)]
    Js = [np.asarray(J, float) for J in jax.jacfwd(res)(th)]
    p = len(names)
    F = np.zeros((p, p))
    scales = []
    for e, r, J in zip(experiments, rs, Js, strict=True):
        if not np.all(np.isfinite(J)):
            raise FloatingPointError(f"{getattr(e, 'name', 'experiment')}: non-finite Jacobian at {theta}")
        s2 = 1.0 if e.sigma_known else float(np.sum(r**2)) / max(r.size - p, 1)
        s2 = max(s2, np.finfo(float).tiny)
        scales.append(float(np.sqrt(s2)))
        F += J.T @ J / s2
    thv = np.asarray(th, float)
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
    for k, r in zip(names, rel, strict=True):
        if not np.isfinite(r) or r > rel_std_warn:
            warns.append(f"{k} is poorly identified: relative standard deviation {r:.3g}")
    if cond > 1e8:
        warns.append(
            f"the relative Fisher matrix has condition number {cond:.3g} (> 1e8): not identifiable numerically"
        )
    if warns:
        combo = " * ".join(f"{k}^{a:g}" for k, a in weakest.items())
        warns.append(f"least determined combination: {combo} (relative std {1 / np.sqrt(max(w[0], 1e-300)):.3g})")
    return Uncertainty(tuple(names), thv, std, rel, cov, corr, F, scales, weakest, cond, warns)
