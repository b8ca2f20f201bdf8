"""Profile likelihood: the check on the linearised (Gauss-Newton) standard deviations.

For Gaussian errors the negative log-likelihood is, up to a constant, chi^2 / 2 with

    chi^2(theta) = sum_e sum_i r_ei^2 / s_e^2

(r_e: an experiment's normalised residuals, s_e its noise scale: 1 when sigma is known, else
the scale ``gauss_newton`` estimated from the residuals at the estimate, held fixed here).
The fit's loss L = sum_e w_e mean(r_e^2) is chi^2 only up to the weights, so the profile
re-optimises chi^2 itself: each experiment is given the weight N_e / s_e^2 (N_e residuals),
which makes L = chi^2.

For each free parameter k: z_k (the optimiser's transformed coordinate, ``ParameterSet``;
for the default log transform z = ln theta - ln theta_init) is fixed on a grid of
``n_points`` values around the estimate, z_k = z_hat_k + sigma_zk * linspace(-w, w)
(sigma_zk: the Gauss-Newton std mapped to z; w = ``width_sigma``, default 4), and the other
parameters are re-optimised by :func:`calibration.fit.fit` (optax L-BFGS, at most
``max_iter`` iterations), all grid points of a parameter as the starts of one fit (one
compiled model) that begin at the estimate (z_k's gradient is stopped, so it stays at its grid value).  The
likelihood-ratio statistic is Delta chi^2 = chi^2 - chi^2_min (chi^2_min: the least value
found, at the estimate or on any profile), and the 95 % interval is where Delta chi^2 <= 3.84
(the 0.95 quantile of chi^2 with one degree of freedom).  Its ends are found on the signed
root sign(z - z_hat) sqrt(Delta chi^2) by linear interpolation between grid points: the
signed root is linear in z when chi^2 is quadratic, so for a model linear in z the interval
is exactly the Gauss-Newton one, z_hat +- 1.96 sigma_z.

The Gauss-Newton 95 % interval (about 2 sigma) is z_hat +- 1.96 sigma_z, mapped to SI.  Where
the profile interval is more than twice or less than half as wide as it, on either side, the
linearisation is not to be trusted and a warning says so; a side that does not reach 3.84
within the grid (w = 4 sigma: more than 4 / 1.96 = 2.04 times the Gauss-Newton half-width) is
open (None) and warned about too.

Cost: per parameter one ``fit`` of ``n_points`` starts (one compilation), i.e. about
p * n_points * (max_iter + line-search evaluations) loss-and-gradient evaluations.
"""

from __future__ import annotations

import copy
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .experiments import joint_loss
from .fit import fit
from .params import ParameterSet
from .uncertainty import gauss_newton

__all__ = [
    "CHI2_95",
    "PROFILE_DEFINITION",
    "ParameterProfile",
    "check_profile_options",
    "chi2_experiments",
    "plot_profiles",
    "profile_likelihood",
]

# 0.95 quantile of the chi-squared distribution with one degree of freedom (= 1.959964^2)
CHI2_95 = 3.841458820694124
# the profile and Gauss-Newton intervals "disagree" beyond this factor (either way, either side)
DISAGREE_FACTOR = 2.0
PROFILE_DEFINITION = (
    "profile_interval_95: where chi^2 - chi^2_min <= 3.84 with the parameter fixed and the others re-optimised; "
    "chi^2 = sum_e sum_i r_ei^2 / s_e^2 (s_e: the Gauss-Newton noise scale, 1 where sigma is known); null: "
    "beyond the grid; gauss_newton_interval_95: z_hat +- 1.96 sigma_z in the transformed coordinate, mapped back; "
    "a warning where the two half-widths differ by more than a factor of 2 on either side"
)


class ParameterProfile(NamedTuple):
    """The profile of one parameter.  name; theta_hat: the estimate [SI]; z_hat, sigma_z: its
    transformed coordinate and the Gauss-Newton std there; z: grid (n,); theta: grid [SI];
    delta_chi2: chi^2 - chi^2_min (n,); others: the re-optimised other parameters per grid point
    (name -> value [SI]); converged: whether the re-optimisation stopped on its criterion
    before ``max_iter`` (the batch of grid points stops together); interval_95: (lo, hi) [SI] (None: beyond the
    grid); gn_interval_95: (lo, hi) [SI], z_hat +- 1.96 sigma_z mapped back; side_ratio: profile
    half-width / Gauss-Newton half-width per side (None: open); warning: text or None."""

    name: str
    theta_hat: float
    z_hat: float
    sigma_z: float
    z: np.ndarray
    theta: np.ndarray
    delta_chi2: np.ndarray
    others: list
    converged: bool
    interval_95: tuple
    gn_interval_95: tuple
    side_ratio: tuple
    warning: str | None

    def as_dict(self, unit="SI"):
        return {
            "estimate": self.theta_hat,
            "unit": unit,
            "profile_interval_95": list(self.interval_95),
            "gauss_newton_interval_95": list(self.gn_interval_95),
            "side_ratio_profile_over_gauss_newton": list(self.side_ratio),
            "grid": [float(t) for t in self.theta],
            "delta_chi2": [float(d) for d in self.delta_chi2],
            "others": self.others,
            "converged": bool(self.converged),
            "warning": self.warning,
        }


class _Pinned(ParameterSet):
    """``pset`` with the gradient of one z coordinate stopped: that parameter stays at its
    starting value while ``fit`` optimises the others (its z rows are unchanged by L-BFGS, whose
    update has no component along a coordinate whose gradient is always zero)."""

    def __init__(self, pset: ParameterSet, name: str):
        self.__dict__.update(pset.__dict__)
        self._k = pset.free.index(name)

    def theta(self, z):
        z = z.at[self._k].set(jax.lax.stop_gradient(z[self._k]))
        return super().theta(z)


def chi2_experiments(experiments, scales):
    """Shallow copies of ``experiments`` weighted N_e / s_e^2, so that their joint loss is chi^2."""
    out = []
    for e, s in zip(experiments, scales, strict=True):
        c = copy.copy(e)
        c.weight = float(e.n_residuals) / float(s) ** 2
        out.append(c)
    return out


def _crossing(z, root, centre, side):
    """z where the signed root crosses side * sqrt(CHI2_95), walking outward from ``centre``
    (index of z_hat), by linear interpolation; None if it does not within the grid."""
    target = side * math.sqrt(CHI2_95)
    idx = range(centre, len(z)) if side > 0 else range(centre, -1, -1)
    prev = None
    for i in idx:
        if prev is not None and (root[i] - target) * side >= 0:
            a, b = root[prev], root[i]
            return float(z[prev] + (target - a) * (z[i] - z[prev]) / (b - a))
        prev = i
    return None


def check_profile_options(n_points, width_sigma, max_iter, prefix=""):
    """ValueError naming the option (``prefix`` + name), its value and the allowed range."""
    if int(n_points) != n_points or n_points < 3 or n_points % 2 == 0:
        raise ValueError(
            f"{prefix}points = {n_points!r}; allowed: an odd integer >= 3 (the estimate is the middle point)"
        )
    if not (width_sigma > 0 and math.isfinite(width_sigma)):
        raise ValueError(f"{prefix}width = {width_sigma!r}; allowed range: > 0 (Gauss-Newton standard deviations)")
    if int(max_iter) != max_iter or max_iter < 1:
        raise ValueError(f"{prefix}max-iter = {max_iter!r}; allowed range: integer >= 1")


def profile_likelihood(
    experiments,
    pset: ParameterSet,
    theta: dict,
    unc=None,
    *,
    n_points: int = 9,
    width_sigma: float = 4.0,
    max_iter: int = 10,
    names=None,
    progress=False,
) -> dict:
    """Profile likelihood of each free parameter of ``pset`` (or of ``names``) at the estimate
    ``theta`` (name -> value [SI], e.g. ``FitResult.params``); see the module docstring.
    unc: ``gauss_newton(experiments, pset, theta)`` (computed when not given).  Returns
    name -> :class:`ParameterProfile`."""
    check_profile_options(n_points, width_sigma, max_iter)
    names = tuple(pset.free if names is None else names)
    bad = [k for k in names if k not in pset.free]
    if bad:
        raise ValueError(f"profile of {bad}: not fitted parameters; allowed: {', '.join(pset.free)}")
    unc = gauss_newton(experiments, pset, theta) if unc is None else unc
    exps = chi2_experiments(experiments, unc.noise_scale)
    z_hat = np.asarray(pset.z_of_theta(theta), float)
    # dtheta/dz at the estimate: the Gauss-Newton std mapped to the transformed coordinate
    dtheta_dz = np.asarray(jax.jacfwd(pset.theta_vector)(jnp.asarray(z_hat)), float).diagonal()
    chi2_hat = float(joint_loss(exps, pset.values({k: float(theta[k]) for k in pset.free})))
    runs = {}
    for k in names:
        i = pset.free.index(k)
        sz = float(unc.std[i] / abs(dtheta_dz[i]))
        if not (math.isfinite(sz) and sz > 0):
            raise ValueError(
                f"profile of {k}: its Gauss-Newton std is {unc.std[i]!r}, so there is no scale for the grid; "
                "fix the parameter or add data that constrain it"
            )
        zg = z_hat[i] + sz * np.linspace(-width_sigma, width_sigma, int(n_points))
        starts = np.repeat(z_hat[None, :], len(zg), axis=0)
        starts[:, i] = zg
        if len(pset.free) == 1:
            vals = [float(joint_loss(exps, pset.values(pset.theta(jnp.asarray(s))))) for s in starts]
            finals = [{k: float(pset.theta(jnp.asarray(s))[k])} for s in starts]
            conv = True
        else:
            r = fit(exps, _Pinned(pset, k), max_iter=max_iter, z_starts=starts, progress=progress)
            vals, finals = [float(v) for v in r.final_losses], r.finals
            conv = r.iterations < max_iter
        runs[k] = (sz, zg, np.asarray(vals), finals, conv)
    chi2_min = min([chi2_hat] + [float(np.min(v[2])) for v in runs.values()])
    out = {}
    for k, (sz, zg, vals, finals, conv) in runs.items():
        i = pset.free.index(k)
        spec = pset.specs[k]
        d = vals - chi2_min
        c = len(zg) // 2
        root = np.sign(zg - zg[c]) * np.sqrt(np.maximum(d, 0.0))
        root[c] = 0.0
        lo_z, hi_z = _crossing(zg, root, c, -1), _crossing(zg, root, c, +1)
        half = 1.959963984540054 * sz
        to_theta = lambda zz: float(spec.to_theta(jnp.asarray(zz)))  # noqa: E731
        interval = (None if lo_z is None else to_theta(lo_z), None if hi_z is None else to_theta(hi_z))
        gn = (to_theta(z_hat[i] - half), to_theta(z_hat[i] + half))
        ratio = (None if lo_z is None else (z_hat[i] - lo_z) / half, None if hi_z is None else (hi_z - z_hat[i]) / half)
        warn = None
        sides = ("lower", "upper")
        open_sides = [s for s, r in zip(sides, ratio, strict=True) if r is None]
        far = [f"{s} {r:.2f}x" for s, r in zip(sides, ratio, strict=True) if r is not None and not (
            1 / DISAGREE_FACTOR <= r <= DISAGREE_FACTOR)]
        if open_sides or far:
            what = []
            if far:
                what.append("profile/Gauss-Newton half-width " + ", ".join(far))
            if open_sides:
                what.append(
                    f"the profile stays below 3.84 on the {' and '.join(open_sides)} side(s) to the grid's end "
                    f"({width_sigma:g} sigma, > {width_sigma / 1.96:.2f}x the Gauss-Newton half-width)"
                )
            warn = (
                f"{k}: the likelihood-ratio 95 % interval and the Gauss-Newton one differ by more than a factor of "
                f"{DISAGREE_FACTOR:g} ({'; '.join(what)}): the linearised std is not to be trusted"
            )
        out[k] = ParameterProfile(
            k, float(theta[k]), float(z_hat[i]), sz, zg, np.asarray([to_theta(z) for z in zg]), d,
            [{n: v for n, v in f.items() if n != k} for f in finals], conv, interval, gn,
            tuple(None if r is None else float(r) for r in ratio), warn,
        )
    return out


def plot_profiles(profiles: dict, path, units=None, transforms=None):
    """profile_likelihood.png: Delta chi^2 against each parameter, the Gauss-Newton quadratic
    ((z - z_hat) / sigma_z)^2 dashed, the 3.84 level and both 95 % intervals."""
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units, transforms = units or {}, transforms or {}
    n = len(profiles)
    fig, axes = plt.subplots(1, n, figsize=(3.4 * n, 3.2), squeeze=False)
    for ax, (k, p) in zip(axes[0], profiles.items(), strict=True):
        ax.plot(p.theta, p.delta_chi2, "o-", ms=4, label="profile (others re-optimised)")
        # the quadratic lives on z; draw it at the grid's theta (monotone map), finely
        zf = np.linspace(p.z[0], p.z[-1], 200)
        tf = np.interp(zf, p.z, p.theta)
        ax.plot(tf, ((zf - p.z_hat) / p.sigma_z) ** 2, "--", lw=1, label="Gauss-Newton quadratic")
        ax.axhline(CHI2_95, color="k", lw=0.8, ls=":")
        for lim, c in ((p.interval_95, "C0"), (p.gn_interval_95, "C1")):
            for v in lim:
                if v is not None:
                    ax.axvline(v, color=c, lw=0.8, alpha=0.6)
        if transforms.get(k, "log") == "log" and p.theta[-1] / p.theta[0] > 10:
            ax.set_xscale("log")  # only where the grid spans a decade: short log axes label badly
        ax.set_xlabel(f"{k} [{units.get(k, 'SI')}]")
        ax.set_ylim(0, max(2 * CHI2_95, float(np.nanmax(p.delta_chi2)) * 1.05))
        ax.set_title(("WARNING: " if p.warning else "") + f"{k}: 95 % where < 3.84", fontsize=8)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("Delta chi^2 (likelihood ratio)")
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
