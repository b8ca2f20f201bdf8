"""Experiment design: rank candidate measurements by the information they add (D-optimal).

At the current estimate theta (name -> value), the Fisher information of the experiments in
hand is I_current = sum_e J_e^T J_e / s_e^2 (``calibration.uncertainty.information_terms``:
J_e the Jacobian of the normalised residuals, s_e the noise scale, 1 where sigma is known),
here in relative (log-parameter) coordinates, J_log = J diag(theta), so that every entry is
"per unit of ln theta" and the prior below means the same for every parameter.  A candidate
measurement c is an experiment whose data are not taken yet: its residual Jacobian does not
depend on the data, only on the model at theta and on the candidate's stated noise (sigma
known), so I_c = J_c^T J_c needs nothing but the simulator.  Its D-optimal gain is

    gain_c = ln det(I_0 + I_current + I_c) - ln det(I_0 + I_current)        [nats]

(the log of the factor by which the volume of the confidence ellipsoid shrinks, squared;
exp(gain/2) is the volume ratio).  I_0 = diag(1 / ln(prior_factor)^2) is a weak prior,
"each parameter known to a factor ``prior_factor`` (default 10) at one sigma before any
data", without which a parameter the current data do not constrain at all would make every
log det -inf.  The ln det of the current information alone is reported too.  Relative
standard deviations before / after are sqrt(diag((I_0 + I)^-1)) (ln theta, i.e. std / theta);
the parameter a candidate *pins* is the one with the largest relative reduction of its std,
1 - std_after / std_before.

Candidates (:class:`Candidate`): an experiment with ``residuals(values)`` (any of
``calibration.experiments``'s, or anything with the same interface) and rows: which of its
residuals belong to the candidate.  Candidates that share a simulation are one experiment
with several row ranges (all profile times of one dam break), so each simulation's Jacobian
is computed once, in forward mode (one tangent per parameter, ``jax.jacfwd``).  Builders:

* :func:`profile_candidates`: height profiles of the scene at given times [s] with stations
  every ``spacing_m`` [m] and noise ``sigma_m`` [m] (:class:`ProfileRequest`; optionally the
  final runout, noise [m]); one simulation for all of them.  With ``rest_s``: the same dam
  break repeated after a rest time, its initial structure lambda0 + rest_s / T
  (:class:`AfterRest`; one simulation per rest time).
* :func:`rheometer_candidate`: a constant-shear transient (``TransientExperiment``) at the given
  shear rates [1/s], sampled at ``n_times`` log-spaced times up to ``t_end_s`` [s], noise
  ``sigma_ln`` in ln mu, started after ``rest_s`` [s] of rest (Coussot: initial structure
  lambda0 + rest_s / T, so rest-then-shear gives the stress overshoot);
  ``flow_curve_candidate``: steady points (``FlowCurveExperiment``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .data import Profile
from .experiments import FlowCurveExperiment, ProfileExperiment, TransientExperiment, structure_after_rest
from .uncertainty import information_terms

__all__ = [
    "AfterRest",
    "Candidate",
    "DesignResult",
    "ProfileRequest",
    "design",
    "flow_curve_candidate",
    "profile_candidates",
    "rheometer_candidate",
]


class Candidate(NamedTuple):
    """A measurement not yet made: ``label`` (short text), ``kind`` ("profile", "runout",
    "transient", "flow_curve", "dambreak_after_rest"), ``spec`` (what it measures, with units,
    as written to design.json), ``experiment`` (its residual model; the data are placeholders)
    and ``rows`` (slice of that experiment's residuals that are this candidate's; None: all)."""

    label: str
    kind: str
    spec: dict
    experiment: object
    rows: slice | None = None


class DesignResult(NamedTuple):
    """names: parameters (order of the arrays); theta: estimate [SI]; prior_factor; logdet_current:
    ln det(I_0 + I_current); std_before: relative std (ln theta) with the current data; ranking:
    candidate indices, best first; gains: D-optimal gain per candidate [nats]; std_after: (n_c, p)
    relative std with each candidate added; pins: name per candidate; info_current: I_current (log
    coordinates); info: I_c per candidate; candidates: the :class:`Candidate` list."""

    names: tuple
    theta: np.ndarray
    prior_factor: float
    logdet_current: float
    std_before: np.ndarray
    ranking: list
    gains: np.ndarray
    std_after: np.ndarray
    pins: list
    info_current: np.ndarray
    info: list
    candidates: list

    def as_dict(self, units=None):
        units = units or {}
        n = self.names
        rows = []
        for rank, c in enumerate(self.ranking, 1):
            cand = self.candidates[c]
            rows.append(
                {
                    "rank": rank,
                    "label": cand.label,
                    "kind": cand.kind,
                    "spec": cand.spec,
                    "d_optimal_gain_nats": float(self.gains[c]),
                    "pins": self.pins[c],
                    "rel_std_after": {k: float(s) for k, s in zip(n, self.std_after[c], strict=True)},
                    "std_after": {
                        k: float(s * t) for k, s, t in zip(n, self.std_after[c], self.theta, strict=True)
                    },
                }
            )
        return {
            "parameters": list(n),
            "estimate": {k: float(t) for k, t in zip(n, self.theta, strict=True)},
            "units": {k: units.get(k, "SI") for k in n},
            "prior_factor": self.prior_factor,
            "logdet_current": self.logdet_current,
            "rel_std_before": {k: float(s) for k, s in zip(n, self.std_before, strict=True)},
            "std_before": {k: float(s * t) for k, s, t in zip(n, self.std_before, self.theta, strict=True)},
            "candidates": rows,
            "definition": (
                "gain = ln det(I0 + I_current + I_candidate) - ln det(I0 + I_current) [nats], I = J^T J / s^2 of the "
                "normalised residuals in ln(parameter) coordinates, I0 = I / ln(prior_factor)^2; rel_std = "
                "sqrt(diag((I0 + I)^-1)), std = rel_std * estimate; pins: the parameter whose std falls most "
                "(relative)"
            ),
        }


class AfterRest:
    """``experiment`` run from the structure reached after ``rest_s`` [s] at rest: Coussot
    dlambda/dt = 1/T at zero shear, so lambda0 -> lambda0 + rest_s / T (lambda0 and T: the
    values being calibrated where they are, else the experiment's material's).  Same
    interface as the wrapped experiment (``residuals``, ``sigma_known``, ``weight``, ...)."""

    def __init__(self, experiment, rest_s: float, material):
        if not (math.isfinite(rest_s) and rest_s >= 0):
            raise ValueError(f"rest_s = {rest_s!r}; allowed range: >= 0 [s]")
        fields = type(material)._fields
        if "lambda0" not in fields or "T" not in fields:
            raise ValueError(
                f"a rest time needs a thixotropic law with lambda0 and T (Coussot); the material is "
                f"{type(material).__name__}"
            )
        self.inner, self.rest_s, self._base = experiment, float(rest_s), material
        self.name = f"{getattr(experiment, 'name', 'experiment')} after {rest_s:g} s rest"
        self.sigma_known, self.weight = experiment.sigma_known, experiment.weight
        self.n_residuals = experiment.n_residuals

    def residuals(self, values: dict):
        lam = values.get("lambda0", self._base.lambda0)
        T = values.get("T", self._base.T)
        return self.inner.residuals({**values, "lambda0": structure_after_rest(lam, self.rest_s, T)})


def _stations(setup, spacing_m, x_range_m):
    sc = setup.scene
    lo, hi = (sc.lo[0], sc.hi[0]) if x_range_m is None else (float(x_range_m[0]), float(x_range_m[1]))
    if not (spacing_m > 0 and math.isfinite(spacing_m)):
        raise ValueError(f"station spacing_m = {spacing_m!r}; allowed range: > 0 [m]")
    if not (sc.lo[0] <= lo < hi <= sc.hi[0]):
        raise ValueError(
            f"x_range_m = [{lo:g}, {hi:g}]; allowed: lo < hi within the scene's domain {sc.lo[0]:g} .. {sc.hi[0]:g} m"
        )
    n = int(math.floor((hi - lo) / spacing_m + 1e-9)) + 1
    if n < 2:
        raise ValueError(f"station spacing_m = {spacing_m:g} leaves fewer than 2 stations in {lo:g} .. {hi:g} m")
    return lo + spacing_m * np.arange(n)


class ProfileRequest(NamedTuple):
    """One candidate height profile: at ``t_s`` [s], stations every ``spacing_m`` [m] across
    ``x_range_m`` ((lo, hi) [m]; None: the scene's domain), noise ``sigma_m`` [m]."""

    t_s: float
    spacing_m: float
    sigma_m: float
    x_range_m: tuple | None = None


def profile_candidates(setup, requests, *, runout_sigma_m=None, bandwidth_m=None, rest_s=None, label="profile"):
    """Candidates: one height profile per :class:`ProfileRequest` and, with ``runout_sigma_m``
    [m], the final runout (at the scene's end); one ProfileExperiment, i.e. one simulation, for
    all of them.  ``setup``'s frames must include the times (``experiments.frames_for``).  With
    ``rest_s`` [s]: the dam break started after that rest (:class:`AfterRest`)."""
    profs, meta = [], []
    kind = "profile" if rest_s is None else "dambreak_after_rest"
    extra = {} if rest_s is None else {"rest_s": float(rest_s)}
    if rest_s is not None:
        label = f"dam break after {float(rest_s):g} s rest:"
    for q in requests:
        if not (q.sigma_m is not None and q.sigma_m > 0 and math.isfinite(q.sigma_m)):
            raise ValueError(f"profile sigma_m = {q.sigma_m!r}; allowed range: > 0 [m]")
        x = _stations(setup, float(q.spacing_m), q.x_range_m)
        profs.append(Profile(x, np.ones_like(x), float(q.t_s), np.full_like(x, float(q.sigma_m))))
        spec = {"t_s": float(q.t_s), "spacing_m": float(q.spacing_m), "stations": int(x.size),
                "sigma_m": float(q.sigma_m), **extra}
        meta.append((f"{label} t = {float(q.t_s):g} s, every {float(q.spacing_m):g} m", spec))
    if not profs and runout_sigma_m is None:
        raise ValueError(f"{label}: no profile time and no runout")
    if runout_sigma_m is not None and not (runout_sigma_m > 0 and math.isfinite(runout_sigma_m)):
        raise ValueError(f"runout sigma_m = {runout_sigma_m!r}; allowed range: > 0 [m]")
    exp = ProfileExperiment(
        setup, profs, bandwidth_m=bandwidth_m, sigma_m=1.0, sigma_known=True,
        runout_m=None if runout_sigma_m is None else 0.0, runout_sigma_m=runout_sigma_m, name=label,
    )
    if rest_s is not None:
        exp = AfterRest(exp, float(rest_s), setup.params.material)
    out, i = [], 0
    for p, (lab, spec) in zip(profs, meta, strict=True):
        out.append(Candidate(lab, kind, spec, exp, slice(i, i + p.x_m.size)))
        i += p.x_m.size
    if runout_sigma_m is not None:
        spec = {"sigma_m": float(runout_sigma_m), "t_s": float(setup.scene.t_end), **extra}
        out.append(Candidate(f"{label} runout at t = {setup.scene.t_end:g} s", "runout", spec, exp, slice(i, i + 1)))
    return out


def rheometer_candidate(material, rates_1_s, *, t_end_s=60.0, n_times=30, sigma_ln=0.05, rest_s=0.0, times_s=None):
    """A constant-shear transient at each rate in ``rates_1_s`` [1/s], sampled at ``times_s`` [s]
    (default ``n_times`` log-spaced from t_end_s/1000 to ``t_end_s``), noise ``sigma_ln`` (relative),
    after ``rest_s`` [s] of rest (0: from lambda0)."""
    g = np.atleast_1d(np.asarray(rates_1_s, float))
    if not (t_end_s > 0 and math.isfinite(t_end_s)):
        raise ValueError(f"transient t_end_s = {t_end_s!r}; allowed range: > 0 [s]")
    if int(n_times) != n_times or n_times < 1:
        raise ValueError(f"transient n_times = {n_times!r}; allowed range: integer >= 1")
    if not (sigma_ln > 0 and math.isfinite(sigma_ln)):
        raise ValueError(f"transient sigma_ln = {sigma_ln!r}; allowed range: > 0 (relative std of mu)")
    t = np.geomspace(t_end_s / 1000, t_end_s, int(n_times)) if times_s is None else np.asarray(times_s, float)
    name = f"transient at {', '.join(f'{r:g}' for r in g)} 1/s" + (f" after {rest_s:g} s rest" if rest_s else "")
    exp = TransientExperiment(material, t, g, np.ones((g.size, t.size)), sigma_ln=float(sigma_ln), name=name)
    spec = {"rates_1_s": [float(r) for r in g], "t_end_s": float(t[-1]), "n_times": int(t.size),
            "sigma_ln": float(sigma_ln), "rest_s": float(rest_s)}
    if rest_s:
        return Candidate(name, "transient", spec, AfterRest(exp, float(rest_s), material))
    return Candidate(name, "transient", spec, exp)


def flow_curve_candidate(material, rates_1_s, *, sigma_ln=0.05):
    """Steady flow-curve points at ``rates_1_s`` [1/s], noise ``sigma_ln`` (relative, in tau)."""
    g = np.atleast_1d(np.asarray(rates_1_s, float))
    name = f"flow curve, {g.size} rates {g.min():g} .. {g.max():g} 1/s"
    exp = FlowCurveExperiment(material, g, np.ones_like(g), sigma_ln=float(sigma_ln), name=name)
    return Candidate(name, "flow_curve", {"rates_1_s": [float(r) for r in g], "sigma_ln": float(sigma_ln)}, exp)


def _log_jacobians(experiments, pset, theta):
    """Whitened Jacobians in ln(theta): J_e diag(theta) / s_e, one per experiment."""
    th, _, Js, scales = information_terms(experiments, pset, theta)
    return [J * th[None, :] / s for J, s in zip(Js, scales, strict=True)]


def _logdet(M, what):
    sign, ld = np.linalg.slogdet(M)
    if sign <= 0:
        raise FloatingPointError(f"{what}: the information matrix is not positive definite")
    return float(ld)


def design(experiments, pset, theta: dict, candidates, *, prior_factor: float = 10.0) -> DesignResult:
    """Rank ``candidates`` (list of :class:`Candidate`) by D-optimal gain over the information of
    ``experiments`` (may be empty; experiments, or Candidates for measurements in hand that share a
    simulation with the candidates, so that it runs once) at the estimate ``theta`` (name -> value
    [SI] of the free parameters of ``pset``).  See the module docstring."""
    if not candidates:
        raise ValueError("no candidate measurement to rank")
    if not (prior_factor > 1 and math.isfinite(prior_factor)):
        raise ValueError(f"prior_factor = {prior_factor!r}; allowed range: > 1 (a factor, at one sigma)")
    names = pset.free
    p = len(names)
    th = np.asarray([float(theta[k]) for k in names])
    if np.any(th <= 0):
        raise ValueError(f"design works in ln(parameter): every estimate must be > 0; got {dict(zip(names, th))}")
    I0 = np.eye(p) / math.log(prior_factor) ** 2
    in_hand = [e for e in experiments if isinstance(e, Candidate)]
    plain = [e for e in experiments if not isinstance(e, Candidate)]
    Icur = np.zeros((p, p))
    if plain:
        for J in _log_jacobians(plain, pset, theta):
            Icur += J.T @ J
    # one Jacobian per distinct experiment (candidates that share a simulation share it, also with
    # measurements in hand given as Candidates); candidates state their noise: whitened with s = 1
    exps, index = [], {}
    for c in in_hand + list(candidates):
        if not c.experiment.sigma_known:
            raise ValueError(f"candidate {c.label}: its noise must be stated (sigma_known)")
        if id(c.experiment) not in index:
            index[id(c.experiment)] = len(exps)
            exps.append(c.experiment)
    Jall = _log_jacobians(exps, pset, theta)

    def rows(c):
        J = Jall[index[id(c.experiment)]]
        return J if c.rows is None else J[c.rows]

    for c in in_hand:
        Icur += rows(c).T @ rows(c)
    A = I0 + Icur
    ld0 = _logdet(A, "current data and prior")
    cov0 = np.linalg.inv(A)
    sd0 = np.sqrt(np.diag(cov0))
    gains, sda, pins, infos = [], [], [], []
    for c in candidates:
        J = rows(c)
        Ic = J.T @ J
        B = A + Ic
        gains.append(_logdet(B, c.label) - ld0)
        sd = np.sqrt(np.diag(np.linalg.inv(B)))
        sda.append(sd)
        pins.append(names[int(np.argmax(1.0 - sd / sd0))])
        infos.append(Ic)
    gains = np.asarray(gains)
    ranking = [int(i) for i in np.argsort(-gains, kind="stable")]
    return DesignResult(tuple(names), th, float(prior_factor), ld0, sd0, ranking, gains, np.asarray(sda), pins,
                        Icur, infos, list(candidates))


def table_lines(res: DesignResult) -> list:
    """The ranking as text: rank, gain, the pinned parameter and every relative std after."""
    n = res.names
    head = f"{'rank':>4s} {'gain [nats]':>11s} {'pins':>8s} " + " ".join(f"{k:>9s}" for k in n) + "  candidate"
    lines = [
        "relative std (std / value) of each parameter, now and with each candidate added; "
        f"prior: a factor {res.prior_factor:g} at 1 sigma",
        head,
        f"{'':>4s} {'':>11s} {'now':>8s} " + " ".join(f"{s:9.3g}" for s in res.std_before),
    ]
    for r, c in enumerate(res.ranking, 1):
        lines.append(
            f"{r:4d} {res.gains[c]:11.3f} {res.pins[c]:>8s} " + " ".join(f"{s:9.3g}" for s in res.std_after[c])
            + f"  {res.candidates[c].label}"
        )
    return lines


def plot_design(res: DesignResult, path, top: int = 20):
    """design.png: D-optimal gain per candidate (bars, best at the top), labelled with the pinned
    parameter and its relative std before -> after."""
    # matplotlib only when plots are written (optional heavy import)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = res.ranking[:top]
    fig, ax = plt.subplots(figsize=(8, 0.4 * len(order) + 1.4))
    y = np.arange(len(order))[::-1]
    ax.barh(y, [res.gains[c] for c in order], color="C0")
    ax.set_yticks(y, [res.candidates[c].label for c in order], fontsize=7)
    for yy, c in zip(y, order, strict=True):
        k = res.names.index(res.pins[c])
        ax.text(res.gains[c], yy, f"  pins {res.pins[c]}: {res.std_before[k]:.2g} -> {res.std_after[c][k]:.2g}",
                va="center", fontsize=7)
    ax.set_xlabel("D-optimal gain: ln det(I + I_candidate) - ln det(I)  [nats]")
    ax.set_title("what to measure next (relative std of the pinned parameter, before -> after)", fontsize=9)
    ax.set_xlim(0, max(1e-9, float(np.max(res.gains))) * 1.6)
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")  # long candidate labels
    plt.close(fig)

