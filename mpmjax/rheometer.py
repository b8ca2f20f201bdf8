"""0-D rheometer for the Coussot (2002) thixotropic model, integrated with diffrax.

Model (Coussot, Nguyen, Huynh & Bonn 2002, *J. Rheol.* 46(3); thesis eqs. 2.13-2.15
and 3.7-3.9; ../shared/REFERENCE.md "Coussot"):

* structure kinetics   dlam/dt = 1/T - alpha * gdot * lam            [1/s]
* viscosity            mu = min(mu0 (1 + lam^n), mu_max)             [Pa s]
* shear stress         tau = mu * gdot                               [Pa]

Parameters (``CoussotParams`` from ``mpmjax._rheology``; SI units):
mu0 [Pa s] minimum viscosity, alpha [-] destructuration coefficient, T [s]
restructuring time, n [-] exponent, lambda0 [-] initial structure, mu_max [Pa s]
viscosity cap (thesis Annex 2 uses 5000 Pa s).  rho and kappa are carried along but
are not used by the 0-D rheometer.

Exact solution at a constant shear rate (REFERENCE.md), used by the tests:

    lam(t) = lam_ss + (lam0 - lam_ss) exp(-alpha gdot t),   lam_ss = 1/(alpha T gdot)
    mu_ss  = mu0 [1 + (alpha T gdot)^-n]
    tau_ss = mu0 gdot [1 + (alpha T gdot)^-n]

For n > 1 the steady flow curve tau_ss(gdot) has a minimum (viscosity bifurcation,
Coussot et al. 2002) at

    gdot_c = (n-1)^(1/n) / (alpha T),   tau_c = mu0 n (n-1)^(1/n - 1) / (alpha T).

Identifiability: the steady flow curve depends on alpha and T only through the
product alpha*T, so flow-curve data identify mu0, n and alpha*T (plus mu_max where
the cap is reached) but never alpha and T separately.  Transient (time-resolved)
data identify alpha through the relaxation rate alpha*gdot and then T through
lam_ss.

Numerics: the kinetics are solved with ``diffrax.diffeqsolve`` using ``Kvaerno5``
(an L-stable 5th-order ESDIRK method) and an adaptive ``PIDController``.  The ODE
is linear and its stiffness ratio grows with alpha*gdot*t_end (1e5 for gdot =
100 1/s, t_end = 1000 s): an explicit method such as Tsit5 would be held to
dt < ~3/(alpha gdot) by stability long after the transient has died out (~3e4
steps), while the implicit method takes steps that grow geometrically once lam is
at steady state (tens of steps).  Gradients use diffrax's default
``RecursiveCheckpointAdjoint`` (discretise-then-optimise), so ``jax.grad`` of any
output w.r.t. the parameters is the exact derivative of the computed solution.
Piecewise-constant shear histories are one solve whose vector field looks the
rate up in the schedule; the step times are passed as ``jump_ts`` to
``diffrax.ClipStepSizeController`` (diffrax 0.7 moved ``jump_ts`` there from
``PIDController``), so the solver steps exactly to each discontinuity and
restarts its FSAL stage after it instead of rejecting steps to locate it.

Use float64 (``jax.config.update("jax_enable_x64", True)``) for accuracy; in
float32 the tolerances are raised to rtol = atol = 1e-4 (errors ~1e-3 in lam).
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import os
import sys
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optax

from mpmjax._rheology import CoussotParams, coussot_mu

# BASE_PARAMS, MIZANI_PARAMS and MIZANI_FAST_PARAMS are module attributes built on
# access (see __getattr__), so they are not listed here.
__all__ = [
    "BASE_VALUES",
    "MIZANI_VALUES",
    "MIZANI_FAST_VALUES",
    "PARAM_UNITS",
    "RheometerResult",
    "FitResult",
    "make_params",
    "validate_params",
    "constant_shear",
    "shear_history",
    "steady_flow_curve",
    "critical_point",
    "fit",
    "write_outputs",
    "add_arguments",
    "run_from_args",
]

# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------

PARAM_UNITS = {
    "rho": "kg/m^3",
    "kappa": "Pa",
    "mu0": "Pa s",
    "alpha": "-",
    "T": "s",
    "n": "-",
    "lambda0": "-",
    "mu_max": "Pa s",
}

_FITTABLE = ("mu0", "alpha", "T", "n", "lambda0", "mu_max")


def make_params(
    mu0: float = 4.0,
    alpha: float = 1.0,
    T: float = 0.5,
    n: float = 2.5,
    lambda0: float = 1.5,
    mu_max: float = 5000.0,
    rho: float = 1850.0,
    kappa: float = 15000.0,
    dtype=None,
) -> CoussotParams:
    """Build ``CoussotParams`` of 0-d arrays (defaults: thesis BASE lab case).

    BASE (thesis §4.5, Table 8; Annex 2 for mu_max): mu0 = 4 Pa s, alpha = 1,
    T = 0.5 s, n = 2.5, lambda0 = 1.5, mu_max = 5000 Pa s, rho = 1850 kg/m^3,
    kappa = 15 000 Pa.  ``dtype`` defaults to JAX's default float (float64 with x64).
    """
    dtype = dtype or jnp.result_type(float)
    vals = dict(rho=rho, kappa=kappa, mu0=mu0, alpha=alpha, T=T, n=n, lambda0=lambda0, mu_max=mu_max)
    return CoussotParams(**{k: jnp.asarray(v, dtype=dtype) for k, v in vals.items()})


# Parameter values (plain floats; pass to make_params(**...)).
BASE_VALUES = dict(mu0=4.0, alpha=1.0, T=0.5, n=2.5, lambda0=1.5, mu_max=5000.0, rho=1850.0, kappa=15000.0)
# Mizani (2016b), thesis Table 5: mu0 = 1 Pa s, alpha*T = 0.36, n = 1.074.  The thesis
# gives only the product alpha*T; the split alpha = 0.36, T = 1 s is the one of its
# Table 10.  lambda0 = 0 (fully destructured fresh material, viscosity rising from mu0
# as in thesis Fig. 26) is our assumption; mu_max = 5000 Pa s from Annex 2.
MIZANI_VALUES = dict(mu0=1.0, alpha=0.36, T=1.0, n=1.074, lambda0=0.0, mu_max=5000.0, rho=1850.0, kappa=15000.0)
# "Fast-aging" variant, thesis Table 6 / Fig. 31: n = 1.75.
MIZANI_FAST_VALUES = dict(MIZANI_VALUES, n=1.75)


def __getattr__(name):
    # BASE_PARAMS etc. are built lazily so that their dtype follows jax_enable_x64.
    table = {"BASE_PARAMS": BASE_VALUES, "MIZANI_PARAMS": MIZANI_VALUES, "MIZANI_FAST_PARAMS": MIZANI_FAST_VALUES}
    if name in table:
        return make_params(**table[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# Allowed ranges: (lower, inclusive?) ; all must also be finite.
_RANGES = {
    "mu0": (0.0, False, "> 0 Pa s"),
    "alpha": (0.0, False, "> 0"),
    "T": (0.0, False, "> 0 s"),
    "n": (0.0, False, "> 0"),
    "lambda0": (0.0, True, ">= 0"),
    "mu_max": (0.0, False, "> 0 Pa s"),
    "rho": (0.0, False, "> 0 kg/m^3"),
    "kappa": (0.0, False, "> 0 Pa"),
}


def _concrete(x):
    """``np.ndarray`` of x, or None if x is a tracer (inside jit/grad)."""
    if isinstance(x, jax.core.Tracer):
        return None
    try:
        return np.asarray(x)
    except Exception:  # pragma: no cover - e.g. other abstract values
        return None


def validate_params(params: CoussotParams) -> None:
    """Raise ``ValueError`` naming the field, its value and the allowed range.

    Checks finiteness and signs (mu0, alpha, T, n, mu_max > 0; lambda0 >= 0; mu_max may
    be +inf for no cap) and mu_max > mu0 (a cap below the minimum viscosity would make mu constant).
    Traced (abstract) values are skipped.
    """
    for name, (lo, inclusive, text) in _RANGES.items():
        v = _concrete(getattr(params, name))
        if v is None:
            continue
        finite = np.isfinite(v) | ((v == np.inf) if name == "mu_max" else False)  # mu_max = inf: no cap
        bad = ~finite | ((v < lo) if inclusive else (v <= lo))
        if np.any(bad):
            val = float(np.ravel(v)[np.argmax(np.ravel(bad))])
            raise ValueError(f"{name} = {val:g} is invalid; allowed range: {text} (finite)")
    mu0, mu_max = _concrete(params.mu0), _concrete(params.mu_max)
    if mu0 is not None and mu_max is not None and np.any(mu_max <= mu0):
        raise ValueError(
            f"mu_max = {float(np.max(mu_max)):g} Pa s is invalid; allowed range: > mu0 = {float(np.max(mu0)):g} Pa s"
        )


def _as_float_params(params: CoussotParams) -> CoussotParams:
    dtype = jnp.result_type(float)
    return CoussotParams(*(jnp.asarray(x, dtype=dtype) for x in params))


# --------------------------------------------------------------------------------------
# Transient solves
# --------------------------------------------------------------------------------------


class RheometerResult(NamedTuple):
    """Rheometer output at the save times.

    t_s [s], gamma_dot_1_s [1/s] (imposed rate at each save time; right-continuous at
    steps), lam [-] structure parameter, mu_pa_s [Pa s] viscosity (capped at mu_max),
    tau_pa [Pa] shear stress mu * gdot.
    """

    t_s: jnp.ndarray
    gamma_dot_1_s: jnp.ndarray
    lam: jnp.ndarray
    mu_pa_s: jnp.ndarray
    tau_pa: jnp.ndarray


def _tolerances(rtol, atol, dtype):
    """Requested tolerances, floored for the working precision.

    float64: rtol >= 100 eps (2.2e-14), atol >= eps.  float32: rtol, atol >= 1e-4;
    tighter float32 requests make the implicit stage solves stall at 100 1/s (the
    solve then fails with max_steps reached), so use float64 for accurate work.
    """
    if jnp.finfo(dtype).bits >= 64:
        eps = float(jnp.finfo(dtype).eps)
        return max(float(rtol), 100.0 * eps), max(float(atol), eps)
    return max(float(rtol), 1e-4), max(float(atol), 1e-4)


def _rhs_constant(t, lam, args):
    """Coussot kinetics at constant gdot: dlam/dt = 1/T - alpha gdot lam [1/s]."""
    params, gdot = args
    return 1.0 / params.T - params.alpha * gdot * lam


def _rate_at(t, times, rates):
    """Piecewise-constant, right-continuous schedule: rates[i] on [times[i], times[i+1])."""
    idx = jnp.searchsorted(times, t, side="right") - 1
    return rates[jnp.clip(idx, 0, rates.shape[0] - 1)]


def _rhs_schedule(t, lam, args):
    params, times, rates = args
    return 1.0 / params.T - params.alpha * _rate_at(t, times, rates) * lam


def _controller(rtol, atol, jump_ts=None):
    pid = diffrax.PIDController(rtol=rtol, atol=atol)
    if jump_ts is None:
        return pid
    return diffrax.ClipStepSizeController(pid, jump_ts=jump_ts)


def _result(params, t_s, gdot, lam):
    mu = coussot_mu(lam, params.mu0, params.n, params.mu_max)
    gdot = jnp.broadcast_to(gdot, lam.shape)
    return RheometerResult(t_s=t_s, gamma_dot_1_s=gdot, lam=lam, mu_pa_s=mu, tau_pa=mu * gdot)


@functools.partial(jax.jit, static_argnames=("rtol", "atol", "max_steps"))
def _constant_shear_jit(params, gamma_dot, t_s, rtol, atol, max_steps):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_rhs_constant),
        diffrax.Kvaerno5(),
        t0=jnp.zeros((), t_s.dtype),
        t1=t_s[-1],
        dt0=None,
        y0=jnp.broadcast_to(params.lambda0, gamma_dot.shape),
        args=(params, gamma_dot),
        saveat=diffrax.SaveAt(ts=t_s),
        stepsize_controller=_controller(rtol, atol),
        max_steps=max_steps,
    )
    lam = jnp.moveaxis(sol.ys, 0, -1)  # (m,) + gdot.shape -> gdot.shape + (m,)
    return _result(params, t_s, jnp.expand_dims(gamma_dot, -1), lam)


def _check_times(t_s, name):
    v = _concrete(t_s)
    if v is None:
        return
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array of times [s], got shape {v.shape}")
    if not np.all(np.isfinite(v)) or np.any(np.diff(v) < 0):
        raise ValueError(f"{name} must be finite and non-decreasing [s]")


def constant_shear(
    params: CoussotParams,
    gamma_dot,
    t_s,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_steps: int = 4096,
) -> RheometerResult:
    """Constant-shear-rate test (thesis Figs. 7, 26, 31; Coussot et al. 2002).

    Starts from lam(0) = params.lambda0 at t = 0 and imposes ``gamma_dot`` [1/s]
    (>= 0; 0 is rest/aging) for all t >= 0.  Solves dlam/dt = 1/T - alpha gdot lam
    (thesis eq. 2.14 / 3.9) with ``diffrax.Kvaerno5`` and an adaptive PID controller,
    and returns lam, mu = min(mu0 (1 + lam^n), mu_max) (eq. 2.15 / 3.7) and
    tau = mu gdot at the save times ``t_s`` [s] (1-D, non-decreasing, >= 0).

    ``gamma_dot`` may be a scalar (outputs of shape (m,)) or a 1-D array of k rates
    (outputs (k, m)); k rates are k independent tests solved as one decoupled system
    of k equations in a single solve (one compilation, error control on each).

    Jit-able (``params`` and ``gamma_dot`` are traced) and differentiable w.r.t.
    ``params`` and ``gamma_dot`` (``RecursiveCheckpointAdjoint``).
    """
    params = _as_float_params(params)
    dtype = params.mu0.dtype
    t_s = jnp.asarray(t_s, dtype=dtype)
    _check_times(t_s, "t_s")
    gamma_dot = jnp.asarray(gamma_dot, dtype=dtype)
    if gamma_dot.ndim > 1:
        raise ValueError(f"gamma_dot must be a scalar or 1-D array of rates [1/s], got shape {gamma_dot.shape}")
    rtol, atol = _tolerances(rtol, atol, dtype)
    return _constant_shear_jit(params, gamma_dot, t_s, rtol, atol, int(max_steps))


@functools.partial(jax.jit, static_argnames=("rtol", "atol", "max_steps"))
def _shear_history_jit(params, times, rates, t_save, rtol, atol, max_steps):
    jump_ts = times[1:] if times.shape[0] > 1 else None
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_rhs_schedule),
        diffrax.Kvaerno5(),
        t0=times[0],
        t1=t_save[-1],
        dt0=None,
        y0=params.lambda0,
        args=(params, times, rates),
        saveat=diffrax.SaveAt(ts=t_save),
        stepsize_controller=_controller(rtol, atol, jump_ts),
        max_steps=max_steps,
    )
    return _result(params, t_save, _rate_at(t_save, times, rates), sol.ys)


def shear_history(
    params: CoussotParams,
    times_s,
    rates_1_s,
    t_save_s,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_steps: int = 4096,
) -> RheometerResult:
    """Piecewise-constant shear-rate history (step tests, e.g. 100 1/s then 0.1 1/s).

    ``rates_1_s[i]`` [1/s] is imposed on [times_s[i], times_s[i+1]) and the last rate
    until the end; lam(times_s[0]) = params.lambda0.  ``t_save_s`` [s] must lie in
    [times_s[0], ...] and be non-decreasing; the solve ends at ``t_save_s[-1]``.

    One ``diffeqsolve`` (Kvaerno5, adaptive PID) with the rate looked up from the
    schedule in the vector field; the step times ``times_s[1:]`` are passed as
    ``jump_ts`` to ``diffrax.ClipStepSizeController`` so the solver lands on each
    discontinuity instead of rejecting steps to find it, and the whole history is a
    single differentiable, jit-able solve (a sequence of solves would need one
    compilation per number of segments and Python-level glue).
    """
    params = _as_float_params(params)
    dtype = params.mu0.dtype
    times = jnp.atleast_1d(jnp.asarray(times_s, dtype=dtype))
    rates = jnp.atleast_1d(jnp.asarray(rates_1_s, dtype=dtype))
    t_save = jnp.atleast_1d(jnp.asarray(t_save_s, dtype=dtype))
    _check_times(times, "times_s")
    _check_times(t_save, "t_save_s")
    if times.shape != rates.shape:
        raise ValueError(f"times_s and rates_1_s must have the same length, got {times.shape[0]} and {rates.shape[0]}")
    tv, sv = _concrete(times), _concrete(t_save)
    if tv is not None and np.any(np.diff(tv) <= 0):
        raise ValueError("times_s must be strictly increasing [s]")
    if tv is not None and sv is not None and sv[0] < tv[0]:
        raise ValueError(f"t_save_s starts at {sv[0]:g} s, before the first step time {tv[0]:g} s")
    rtol, atol = _tolerances(rtol, atol, dtype)
    return _shear_history_jit(params, times, rates, t_save, rtol, atol, int(max_steps))


# --------------------------------------------------------------------------------------
# Steady state
# --------------------------------------------------------------------------------------


def steady_flow_curve(params: CoussotParams, gamma_dot):
    """Steady flow curve (Coussot et al. 2002; REFERENCE.md).

    lam_ss = 1/(alpha T gdot), mu_ss = min(mu0 [1 + (alpha T gdot)^-n], mu_max) [Pa s],
    tau_ss = mu_ss gdot [Pa], for gdot [1/s] > 0.  Returns (tau_ss, mu_ss).
    """
    gdot = jnp.asarray(gamma_dot, dtype=jnp.result_type(params.mu0, float))
    lam_ss = 1.0 / (params.alpha * params.T * gdot)
    mu_ss = coussot_mu(lam_ss, params.mu0, params.n, params.mu_max)
    return mu_ss * gdot, mu_ss


def critical_point(params: CoussotParams):
    """Minimum of the *uncapped* steady flow curve (viscosity bifurcation), n > 1.

    gdot_c = (n-1)^(1/n) / (alpha T) [1/s],  tau_c = mu0 n (n-1)^(1/n - 1) / (alpha T) [Pa]
    (Coussot et al. 2002; REFERENCE.md).  Below gdot_c no steady homogeneous flow is
    stable.  The cap mu_max is ignored: the point is a local minimum of the capped
    curve only if mu0 [1 + 1/(n-1)] < mu_max (true for all thesis parameter sets).

    Raises ``ValueError`` for a concrete n <= 1 (the flow curve is then monotonic);
    with a traced n the result is NaN there.
    """
    n = params.n
    nv = _concrete(n)
    if nv is not None and np.any(nv <= 1.0):
        raise ValueError(
            f"critical_point needs n > 1 (allowed range: n > 1); got n = {float(np.min(nv)):g}: "
            "the steady flow curve is monotonic for n <= 1"
        )
    aT = params.alpha * params.T
    nm1 = jnp.where(n > 1.0, n - 1.0, jnp.nan)
    gdot_c = nm1 ** (1.0 / n) / aT
    tau_c = params.mu0 * n * nm1 ** (1.0 / n - 1.0) / aT
    return gdot_c, tau_c


# --------------------------------------------------------------------------------------
# Fitting
# --------------------------------------------------------------------------------------


class FitResult(NamedTuple):
    """Output of :func:`fit`.

    params: fitted ``CoussotParams``; loss_history: loss before each optimiser step
    (length ``steps``); loss_initial / loss_final: loss at the initial / fitted params
    (mean squared natural-log residual, dimensionless); fitted: names of the fitted fields.
    """

    params: CoussotParams
    loss_history: np.ndarray
    loss_initial: float
    loss_final: float
    fitted: tuple


def _prepare_data(data: Mapping[str, Any], kind: str, dtype):
    g = data.get("gamma_dot_1_s")
    if g is None:
        raise ValueError("data needs 'gamma_dot_1_s' [1/s]")
    g = jnp.atleast_1d(jnp.asarray(g, dtype=dtype))
    if kind == "flow_curve":
        if "tau_pa" in data:
            y = jnp.log(jnp.asarray(data["tau_pa"], dtype=dtype))
            return {"gdot": g, "log_y": y, "what": "tau"}
        if "mu_pa_s" in data:
            y = jnp.log(jnp.asarray(data["mu_pa_s"], dtype=dtype))
            return {"gdot": g, "log_y": y, "what": "mu"}
        raise ValueError("flow_curve data needs 'tau_pa' [Pa] or 'mu_pa_s' [Pa s]")
    if kind == "transient":
        if "t_s" not in data or "mu_pa_s" not in data:
            raise ValueError("transient data needs 't_s' [s], 'gamma_dot_1_s' [1/s] and 'mu_pa_s' [Pa s]")
        t = jnp.asarray(data["t_s"], dtype=dtype)
        mu = jnp.asarray(data["mu_pa_s"], dtype=dtype).reshape(g.shape[0], t.shape[0])
        _check_times(t, "data['t_s']")
        return {"gdot": g, "t": t, "log_y": jnp.log(mu), "what": "mu"}
    raise ValueError(f"kind = {kind!r} is invalid; allowed: 'flow_curve' or 'transient'")


def _loss(params, d, kind, rtol, atol, max_steps):
    """Mean squared log residual (i.e. squared relative error to first order)."""
    if kind == "flow_curve":
        tau, mu = steady_flow_curve(params, d["gdot"])
        model = tau if d["what"] == "tau" else mu
    else:
        model = _constant_shear_jit(params, d["gdot"], d["t"], rtol, atol, max_steps).mu_pa_s
    return jnp.mean((jnp.log(model) - d["log_y"]) ** 2)


def fit(
    data: Mapping[str, Any],
    init_params: CoussotParams,
    fit: Sequence[str] = ("mu0", "alpha", "T", "n"),
    kind: str = "flow_curve",
    steps: int = 500,
    learning_rate: float = 0.05,
    optimizer: str = "adam",
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 4096,
) -> FitResult:
    """Fit Coussot parameters to rheometer data with optax.

    data (SI units):
      * kind="flow_curve": {"gamma_dot_1_s": (m,), "tau_pa": (m,)} or "mu_pa_s" (m,)
        instead of "tau_pa" - steady states, compared with :func:`steady_flow_curve`.
      * kind="transient": {"t_s": (m,), "gamma_dot_1_s": (k,), "mu_pa_s": (k, m)} - k
        constant-shear tests each started from lambda0 at t = 0 (:func:`constant_shear`).

    Loss: mean of (ln model - ln data)^2 (squared relative error to first order).
    The fields named in ``fit`` (any of mu0, alpha, T, n, lambda0, mu_max) are
    optimised as logarithms, so they stay positive; all others are held at
    ``init_params``.  ``optimizer``: "adam" (``optax.adam(learning_rate)``) or "lbfgs"
    (``optax.lbfgs`` with its zoom line search; learning_rate unused).  ``steps``
    optimiser iterations run inside one jitted ``lax.scan``.

    Flow-curve data identify only mu0, n and alpha*T (and mu_max if the cap is hit):
    fitting both alpha and T then moves log(alpha) and log(T) by identical amounts,
    so alpha/T stays at its initial value.
    """
    names = tuple(fit)
    for k in names:
        if k not in _FITTABLE:
            raise ValueError(f"cannot fit {k!r}; allowed: {', '.join(_FITTABLE)}")
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"fit must name distinct parameters, got {names}")
    if optimizer not in ("adam", "lbfgs"):
        raise ValueError(f"optimizer = {optimizer!r} is invalid; allowed: 'adam' or 'lbfgs'")
    steps = int(steps)
    if steps < 1:
        raise ValueError(f"steps = {steps} is invalid; allowed range: >= 1")
    p0 = _as_float_params(init_params)
    validate_params(p0)
    for k in names:
        if float(getattr(p0, k)) <= 0.0:
            raise ValueError(f"initial {k} = {float(getattr(p0, k)):g} must be > 0 to be fitted in log space")
    dtype = p0.mu0.dtype
    rtol, atol = _tolerances(rtol, atol, dtype)
    d = _prepare_data(data, kind, dtype)

    def to_params(theta):
        return p0._replace(**{k: jnp.exp(theta[i]) for i, k in enumerate(names)})

    def loss_fn(theta):
        return _loss(to_params(theta), d, kind, rtol, atol, int(max_steps))

    theta0 = jnp.log(jnp.stack([getattr(p0, k) for k in names]))

    if optimizer == "adam":
        opt = optax.adam(learning_rate)
        vg = jax.value_and_grad(loss_fn)

        def step(carry, _):
            theta, state = carry
            loss, g = vg(theta)
            updates, state = opt.update(g, state, theta)
            return (optax.apply_updates(theta, updates), state), loss

    else:
        opt = optax.lbfgs()
        vg_state = optax.value_and_grad_from_state(loss_fn)

        def step(carry, _):
            theta, state = carry
            loss, g = vg_state(theta, state=state)
            updates, new_state = opt.update(g, state, theta, value=loss, grad=g, value_fn=loss_fn)
            new_theta = optax.apply_updates(theta, updates)
            # Once converged (zero gradient) the line search can return NaN: keep theta.
            ok = jnp.all(jnp.isfinite(new_theta))
            theta = jnp.where(ok, new_theta, theta)
            state = jax.tree.map(lambda a, b: jnp.where(ok, a, b), new_state, state)
            return (theta, state), loss

    @jax.jit
    def run(theta0):
        (theta, _), hist = jax.lax.scan(step, (theta0, opt.init(theta0)), None, length=steps)
        return theta, hist, loss_fn(theta0), loss_fn(theta)

    theta, hist, loss_initial, loss_final = run(theta0)
    return FitResult(
        params=to_params(theta),
        loss_history=np.asarray(hist),
        loss_initial=float(loss_initial),
        loss_final=float(loss_final),
        fitted=names,
    )


# --------------------------------------------------------------------------------------
# Output files
# --------------------------------------------------------------------------------------

_CSV_COLUMNS = ("t_s", "gamma_dot_1_s", "lambda", "mu_pa_s", "tau_pa")


def _params_json(params: CoussotParams):
    return {k: {"value": float(getattr(params, k)), "unit": PARAM_UNITS[k]} for k in CoussotParams._fields}


def write_outputs(out_dir, params: CoussotParams, rates, t_s) -> dict:
    """Run constant-shear tests at each rate and write the rheometer files.

    out_dir: folder (created if needed); rates [1/s] (> 0); t_s [s] save times (> 0 for
    the log-log plot).  Writes

    * ``viscosity_vs_time.png``: mu(t) log-log, one curve per rate, steady values
      dotted (cf. thesis Figs. 7, 26, 31);
    * ``flow_curve.png``: tau_ss(gdot) log-log with the critical point (n > 1) marked;
    * ``rheometer.csv``: columns t_s, gamma_dot_1_s, lambda, mu_pa_s, tau_pa
      (one block of rows per rate);
    * ``rheometer.json``: parameters with units, rates, steady states, critical point,
      solver settings and the file list.

    Returns the JSON content as a dict.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = _as_float_params(params)
    validate_params(params)
    rates = [float(r) for r in np.atleast_1d(np.asarray(rates, dtype=float))]
    if not rates or any(not (math.isfinite(r) and r > 0) for r in rates):
        raise ValueError(f"rates = {rates} is invalid; allowed range: each > 0 1/s (finite)")
    t_arr = np.atleast_1d(np.asarray(t_s, dtype=float))
    if t_arr.ndim != 1 or np.any(~np.isfinite(t_arr)) or np.any(t_arr <= 0) or np.any(np.diff(t_arr) < 0):
        raise ValueError("t_s must be a 1-D, non-decreasing array of times > 0 s")
    os.makedirs(out_dir, exist_ok=True)

    res_all = constant_shear(params, jnp.asarray(rates), t_arr)  # one solve, (k, m)
    results = [RheometerResult(res_all.t_s, *(x[i] for x in res_all[1:])) for i in range(len(rates))]
    steady = []
    for r in rates:
        tau_ss, mu_ss = steady_flow_curve(params, r)
        steady.append(
            {
                "gamma_dot_1_s": r,
                "lambda_ss": 1.0 / (float(params.alpha) * float(params.T) * r),
                "mu_ss_pa_s": float(mu_ss),
                "tau_ss_pa": float(tau_ss),
                "relaxation_time_s": 1.0 / (float(params.alpha) * r),
            }
        )

    n = float(params.n)
    if n > 1.0:
        gc, tc = (float(x) for x in critical_point(params))
        mu_c_uncapped = float(params.mu0) * (1.0 + 1.0 / (n - 1.0))
        crit = {
            "gamma_dot_c_1_s": gc,
            "tau_c_pa": tc,
            "mu_ss_c_pa_s": min(mu_c_uncapped, float(params.mu_max)),
            "cap_active": mu_c_uncapped >= float(params.mu_max),
        }
    else:
        gc = tc = None
        crit = None

    files = ["viscosity_vs_time.png", "flow_curve.png", "rheometer.csv", "rheometer.json"]

    # CSV
    with open(os.path.join(out_dir, "rheometer.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(_CSV_COLUMNS)
        for res in results:
            cols = [np.asarray(getattr(res, k)) for k in ("t_s", "gamma_dot_1_s", "lam", "mu_pa_s", "tau_pa")]
            for row in zip(*cols):
                w.writerow([f"{float(v):.12g}" for v in row])

    # Viscosity vs time
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for res, r, st in zip(results, rates, steady):
        (line,) = ax.loglog(np.asarray(res.t_s), np.asarray(res.mu_pa_s), label=f"{r:g} 1/s")
        ax.axhline(st["mu_ss_pa_s"], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("time t [s]")
    ax.set_ylabel("viscosity mu [Pa s]")
    ax.set_title(
        f"Coussot (2002): mu0={float(params.mu0):g} Pa s, alpha={float(params.alpha):g}, "
        f"T={float(params.T):g} s, n={n:g}, lambda0={float(params.lambda0):g}",
        fontsize=8,
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(title="shear rate", fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "viscosity_vs_time.png"), dpi=120)
    plt.close(fig)

    # Flow curve
    lo = min(rates + ([gc] if gc else [])) / 30.0
    hi = max(rates + ([gc] if gc else [])) * 30.0
    g = np.logspace(np.log10(lo), np.log10(hi), 400)
    tau_g, _ = steady_flow_curve(params, g)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    ax.loglog(g, np.asarray(tau_g), "k-", label="steady tau_ss")
    tau_free, _ = steady_flow_curve(params._replace(mu_max=jnp.asarray(np.inf, params.mu_max.dtype)), g)
    if not np.allclose(np.asarray(tau_free), np.asarray(tau_g)):
        ax.loglog(g, np.asarray(tau_free), color="0.6", ls="--", lw=0.8, label="without cap mu_max")
    ax.loglog(rates, [s["tau_ss_pa"] for s in steady], "o", mfc="none", label="rheometer rates")
    if gc is not None:
        ax.loglog([gc], [tc], "r*", ms=12, label=f"critical point ({gc:.3g} 1/s, {tc:.3g} Pa)")
        ax.axvline(gc, color="r", ls=":", lw=0.8)
    ax.set_xlabel("shear rate gdot [1/s]")
    ax.set_ylabel("steady shear stress tau_ss [Pa]")
    ax.set_title("Coussot steady flow curve tau_ss = mu0 gdot [1 + (alpha T gdot)^-n] (capped)", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out_dir, "flow_curve.png"), dpi=120)
    plt.close(fig)

    meta = {
        "model": (
            "Coussot et al. (2002): dlam/dt = 1/T - alpha gdot lam; mu = min(mu0 (1 + lam^n), mu_max); tau = mu gdot"
        ),
        "params": _params_json(params),
        "rates_1_s": rates,
        "t_s": {"min": float(t_arr[0]), "max": float(t_arr[-1]), "count": int(t_arr.size)},
        "steady_state": steady,
        "critical_point": crit,
        "critical_point_note": None if crit else f"no flow-curve minimum for n = {n:g} <= 1",
        "identifiable_from_flow_curve": ["mu0", "n", "alpha*T"],
        "solver": {
            "method": "diffrax.Kvaerno5",
            "controller": "PIDController",
            "rtol": 1e-10,
            "atol": 1e-12,
            "dtype": str(params.mu0.dtype),
        },
        "csv_columns": list(_CSV_COLUMNS),
        "files": files,
    }
    with open(os.path.join(out_dir, "rheometer.json"), "w") as f:
        json.dump(meta, f, indent=2)
    return meta


# --------------------------------------------------------------------------------------
# CLI hooks: `mpmjax rheometer`
# --------------------------------------------------------------------------------------

_CLI_FIELDS = (
    ("mu0", "--mu0", "minimum viscosity mu0 [Pa s]"),
    ("alpha", "--alpha", "destructuration coefficient alpha [-]"),
    ("T", "--T", "restructuring time T [s]"),
    ("n", "--n", "exponent n [-]"),
    ("lambda0", "--lambda0", "initial structure lambda0 [-]"),
    ("mu_max", "--mu-max", "viscosity cap mu_max [Pa s]"),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``mpmjax rheometer`` options (defaults: thesis BASE lab case)."""
    for field, flag, help_ in _CLI_FIELDS:
        parser.add_argument(
            flag,
            dest=field,
            default=str(BASE_VALUES[field]),
            metavar="X",
            help=f"{help_} (default {BASE_VALUES[field]:g}, thesis BASE)",
        )
    parser.add_argument(
        "--rates",
        default="0.1,1,10,100",
        metavar="LIST",
        help="comma-separated constant shear rates [1/s], each > 0 (default 0.1,1,10,100)",
    )
    parser.add_argument(
        "--t-end",
        dest="t_end",
        default="1000",
        metavar="S",
        help="end time [s] > 0; save times are log-spaced over 5 decades up to it (default 1000)",
    )
    parser.add_argument("--out", default="rheometer_out", metavar="DIR", help="output folder (default rheometer_out)")


class _BadInput(Exception):
    pass


def _parse_number(option, value, *, allow_zero=False):
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = None
    ok = x is not None and math.isfinite(x) and (x >= 0 if allow_zero else x > 0)
    if not ok:
        rng = ">= 0" if allow_zero else "> 0"
        raise _BadInput(f"{option}: invalid value {value!r}; allowed range: a finite number {rng}")
    return x


def _parse_rates(value):
    items = list(value) if isinstance(value, (list, tuple)) else str(value).split(",")
    rates = []
    for item in items:
        try:
            rates.append(_parse_number("--rates", item.strip() if isinstance(item, str) else item))
        except _BadInput:
            raise _BadInput(
                f"--rates: invalid value {str(value)!r} (item {str(item).strip()!r}); allowed range: "
                "a comma-separated list of finite numbers > 0 [1/s], e.g. 0.1,1,10,100"
            ) from None
    if not rates:
        raise _BadInput(f"--rates: invalid value {str(value)!r}; allowed range: at least one rate > 0 [1/s]")
    return rates


def run_from_args(args) -> int:
    """Run ``mpmjax rheometer``; return 0 on success, 2 on invalid input.

    Invalid input is reported on stderr (option, value, allowed range), without a
    traceback.  Enables float64 in JAX for this process (the CLI is a one-shot run).
    """
    try:
        vals = {}
        for field, flag, _ in _CLI_FIELDS:
            raw = getattr(args, field, BASE_VALUES[field])
            vals[field] = _parse_number(flag, raw, allow_zero=(field == "lambda0"))
        if vals["mu_max"] <= vals["mu0"]:
            raise _BadInput(
                f"--mu-max: invalid value {vals['mu_max']:g}; allowed range: > --mu0 = {vals['mu0']:g} [Pa s]"
            )
        rates = _parse_rates(getattr(args, "rates", "0.1,1,10,100"))
        t_end = _parse_number("--t-end", getattr(args, "t_end", 1000.0))
        out = str(getattr(args, "out", "rheometer_out"))
        if os.path.exists(out) and not os.path.isdir(out):
            raise _BadInput(f"--out: {out!r} exists and is not a directory")
    except _BadInput as e:
        print(f"mpmjax rheometer: error: {e}", file=sys.stderr)
        return 2

    jax.config.update("jax_enable_x64", True)
    params = make_params(**vals)
    t_s = np.logspace(math.log10(t_end) - 5.0, math.log10(t_end), 200)
    try:
        meta = write_outputs(out, params, rates, t_s)
    except OSError as e:
        print(f"mpmjax rheometer: error: --out {out!r}: {e}", file=sys.stderr)
        return 2
    crit = meta["critical_point"]
    print(f"wrote {', '.join(meta['files'])} to {out}")
    for s in meta["steady_state"]:
        g, m, t = s["gamma_dot_1_s"], s["mu_ss_pa_s"], s["tau_ss_pa"]
        print(f"  gdot = {g:g} 1/s: mu_ss = {m:.6g} Pa s, tau_ss = {t:.6g} Pa")
    if crit:
        print(f"  critical point: gdot_c = {crit['gamma_dot_c_1_s']:.6g} 1/s, tau_c = {crit['tau_c_pa']:.6g} Pa")
    else:
        print(f"  {meta['critical_point_note']}")
    return 0
