"""0-D rheometer: a rheology law's internal-variable kinetics at imposed shear rates, on diffrax.

The rheometer is generic over the registered laws (``mpmjax._rheology``): the law is the one
whose parameter NamedTuple is ``type(params)`` (``law_of``, default options), and

* kinetics          dy/dt = law.rate(params, gdot, y)     y: dict of internal variables
* viscosity         mu = law.mu(params, gdot, y)          [Pa s]
* shear stress      tau = mu * gdot                       [Pa]

with y(0) = the ``Internal.init`` parameter of each internal variable.  A law without
internal variables (Newtonian, Bingham, Herschel-Bulkley) needs no solve: its viscosity at a
constant rate is constant in time.  The steady flow curve uses ``law.steady_internal``.
Parameter units, defaults and allowed ranges are the laws' ``Param`` declarations.

The thesis model is Coussot (Coussot, Nguyen, Huynh & Bonn 2002, *J. Rheol.* 46(3); thesis
eqs. 2.13-2.15 and 3.7-3.9; ../shared/REFERENCE.md "Coussot"):

* structure kinetics   dlam/dt = 1/T - alpha * gdot * lam            [1/s]
* viscosity            mu = min(mu0 (1 + lam^n), mu_max)             [Pa s]

Parameters (``CoussotParams``; SI units): mu0 [Pa s] minimum viscosity, alpha [-]
destructuration coefficient, T [s] restructuring time, n [-] exponent, lambda0 [-]
initial structure, mu_max [Pa s] viscosity cap (thesis Annex 2 uses 5000 Pa s).  rho and
kappa are carried along but are not used by the 0-D rheometer.

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
lam_ss.  Fitting is done by ``calibration`` (``FlowCurveExperiment``,
``TransientExperiment`` and ``calibration.fit.fit``; docs/rheometer.md).

Numerics: the kinetics are solved with ``diffrax.diffeqsolve`` using ``Kvaerno5``
(an L-stable 5th-order ESDIRK method) and an adaptive ``PIDController``.  The Coussot ODE
is linear and its stiffness ratio grows with alpha*gdot*t_end (1e5 for gdot =
100 1/s, t_end = 1000 s): an explicit method such as Tsit5 would be held to
dt < ~3/(alpha gdot) by stability long after the transient has died out (~3e4
steps), while the implicit method takes steps that grow geometrically once lam is
at steady state (tens of steps).  Gradients use diffrax's default
``RecursiveCheckpointAdjoint`` (discretise-then-optimise), so ``jax.grad`` of any
output w.r.t. the parameters is the exact derivative of the computed solution; pass
``adjoint=diffrax.DirectAdjoint()`` for forward-mode derivatives too (``jax.jvp``,
``jax.jacfwd``), as ``calibration.TransientExperiment`` does.
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
from typing import NamedTuple

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from mpmjax._rheology import BASE_VALUES, MODELS, Coussot, CoussotParams, Law, Param, law_of

# BASE_PARAMS, MIZANI_PARAMS and MIZANI_FAST_PARAMS are module attributes built on
# access (see __getattr__), so they are not listed here.
__all__ = [
    "BASE_VALUES",
    "MIZANI_VALUES",
    "MIZANI_FAST_VALUES",
    "RheometerResult",
    "make_params",
    "validate_params",
    "constant_shear",
    "shear_history",
    "steady_flow_curve",
    "critical_point",
    "write_outputs",
    "add_arguments",
    "run_from_args",
]

# --------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------

# BASE_VALUES (the thesis's BASE lab material as plain floats: mu0 = 4 Pa s, alpha = 1,
# T = 0.5 s, n = 2.5, lambda0 = 1.5, mu_max = 5000 Pa s, rho = 1850 kg/m^3, kappa = 15 000 Pa;
# thesis §4.5 Table 8, Annex 2 for mu_max) is the Coussot declaration's, imported above.
# Mizani (2016b), thesis Table 5: mu0 = 1 Pa s, alpha*T = 0.36, n = 1.074.  The thesis
# gives only the product alpha*T; the split alpha = 0.36, T = 1 s is the one of its
# Table 10.  lambda0 = 0 (fully destructured fresh material, viscosity rising from mu0
# as in thesis Fig. 26) is our assumption; mu_max = 5000 Pa s from Annex 2.
MIZANI_VALUES = dict(mu0=1.0, alpha=0.36, T=1.0, n=1.074, lambda0=0.0, mu_max=5000.0, rho=1850.0, kappa=15000.0)
# "Fast-aging" variant, thesis Table 6 / Fig. 31: n = 1.75.
MIZANI_FAST_VALUES = dict(MIZANI_VALUES, n=1.75)

# Parameters that may be +inf: a viscosity cap (no cap).
_INF_ALLOWED = ("mu_max",)


def _law_class(law) -> type[Law]:
    """The law class of ``law``: None (Coussot), a registered name, a Law subclass or instance."""
    if law is None:
        return Coussot
    if isinstance(law, str):
        if law not in MODELS:
            raise ValueError(f"law = {law!r} is not a registered law; allowed: {', '.join(MODELS)}")
        return MODELS[law]
    if isinstance(law, Law):
        return type(law)
    if isinstance(law, type) and issubclass(law, Law):
        return law
    raise ValueError(f"law = {law!r} is invalid; allowed: a registered law name ({', '.join(MODELS)}) or Law class")


def make_params(*, law=None, dtype=None, **values):
    """Parameters of ``law`` (default Coussot) as 0-d arrays, from keyword values [SI].

    Defaults: for Coussot the thesis BASE lab case (``BASE_VALUES``: mu0 = 4 Pa s,
    alpha = 1, T = 0.5 s, n = 2.5, lambda0 = 1.5, mu_max = 5000 Pa s, rho = 1850 kg/m^3,
    kappa = 15 000 Pa; thesis §4.5 Table 8, Annex 2 for mu_max); for another law each
    parameter's declared default (``Param.default``), with rho and kappa (unused by the
    rheometer) from BASE.  ``law``: a registered name (``"coussot"``, ``"newtonian"``...),
    or a Law class or instance.  ``dtype`` defaults to JAX's default float (float64 with x64).
    """
    cls = _law_class(law)
    names = [p.name for p in cls.params]
    unknown = [k for k in values if k not in names]
    if unknown:
        raise ValueError(f"{', '.join(map(repr, unknown))}: not a parameter of {cls.name}; allowed: {', '.join(names)}")
    defaults = {p.name: p.default for p in cls.params if p.default is not None}
    defaults.update({k: BASE_VALUES[k] for k in ("rho", "kappa")})
    if cls is Coussot:
        defaults.update(BASE_VALUES)
    vals = {**defaults, **values}
    missing = [k for k in names if k not in vals]
    if missing:
        raise ValueError(f"{cls.name} needs a value for {', '.join(missing)} (no declared default)")
    dtype = dtype or jnp.result_type(float)
    return cls.params_type(**{k: jnp.asarray(vals[k], dtype=dtype) for k in names})


def __getattr__(name):
    # BASE_PARAMS etc. are built lazily so that their dtype follows jax_enable_x64.
    table = {"BASE_PARAMS": BASE_VALUES, "MIZANI_PARAMS": MIZANI_VALUES, "MIZANI_FAST_PARAMS": MIZANI_FAST_VALUES}
    if name in table:
        return make_params(**table[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _range_text(p: Param) -> str:
    """The allowed range of a declared parameter, e.g. "> 0 Pa s" or "> 0 and <= 10"."""
    parts = []
    if p.lo is not None:
        parts.append(f"{'>' if p.lo_open else '>='} {p.lo:g}")
    if p.hi is not None:
        parts.append(f"<= {p.hi:g}")
    text = " and ".join(parts) or "any value"
    return text + ("" if p.unit == "-" else f" {p.unit}")


def _in_range(p: Param, v):
    """Boolean array: v inside the declared range of ``p`` (finite, or +inf where allowed)."""
    ok = np.isfinite(v) | ((v == np.inf) if p.name in _INF_ALLOWED else False)
    if p.lo is not None:
        ok &= (v > p.lo) if p.lo_open else (v >= p.lo)
    if p.hi is not None:
        ok &= v <= p.hi
    return ok


def _concrete(x):
    """``np.ndarray`` of x, or None if x is a tracer (inside jit/grad)."""
    if isinstance(x, jax.core.Tracer):
        return None
    try:
        return np.asarray(x)
    except Exception:  # pragma: no cover - e.g. other abstract values
        return None


def validate_params(params) -> None:
    """Raise ``ValueError`` naming the field, its value and the allowed range.

    Checks every parameter against its declared range (``Param``: finite, lo, hi; for
    Coussot mu0, alpha, T, n, mu_max > 0, n <= 10, lambda0 >= 0; mu_max may be +inf for no
    cap) and, where a law has both, mu_max > mu0 (a cap below the minimum viscosity would
    make mu constant).  Traced (abstract) values are skipped.
    """
    law = law_of(params)
    for p in law.params:
        v = _concrete(getattr(params, p.name))
        if v is None:
            continue
        bad = ~_in_range(p, v)
        if np.any(bad):
            val = float(np.ravel(v)[np.argmax(np.ravel(bad))])
            raise ValueError(f"{p.name} = {val:g} is invalid; allowed range: {_range_text(p)} (finite)")
    if "mu0" in params._fields and "mu_max" in params._fields:
        mu0, mu_max = _concrete(params.mu0), _concrete(params.mu_max)
        if mu0 is not None and mu_max is not None and np.any(mu_max <= mu0):
            raise ValueError(
                f"mu_max = {float(np.max(mu_max)):g} Pa s is invalid; "
                f"allowed range: > mu0 = {float(np.max(mu0)):g} Pa s"
            )


def _as_float_params(params):
    dtype = jnp.result_type(float)
    return type(params)(*(jnp.asarray(x, dtype=dtype) for x in params))


# --------------------------------------------------------------------------------------
# Transient solves
# --------------------------------------------------------------------------------------


class RheometerResult(NamedTuple):
    """Rheometer output at the save times.

    t_s [s], gamma_dot_1_s [1/s] (imposed rate at each save time; right-continuous at
    steps), internal: the law's internal variables by name (``{"lam": ...}`` [-] for
    Coussot, the structure parameter; ``{}`` for a law without), mu_pa_s [Pa s] viscosity
    (capped at mu_max where the law has a cap), tau_pa [Pa] shear stress mu * gdot.
    ``lam`` is ``internal["lam"]`` (Coussot).
    """

    t_s: jnp.ndarray
    gamma_dot_1_s: jnp.ndarray
    internal: dict
    mu_pa_s: jnp.ndarray
    tau_pa: jnp.ndarray

    @property
    def lam(self):
        """The Coussot structure parameter lambda [-] (``internal["lam"]``)."""
        if "lam" not in self.internal:
            raise AttributeError(f"this law has no internal variable 'lam' (internal: {sorted(self.internal)})")
        return self.internal["lam"]


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


def _rate_at(t, times, rates):
    """Piecewise-constant, right-continuous schedule: rates[i] on [times[i], times[i+1])."""
    idx = jnp.searchsorted(times, t, side="right") - 1
    return rates[jnp.clip(idx, 0, rates.shape[0] - 1)]


@functools.cache
def _terms(law: Law):
    """The diffrax vector fields of ``law`` (one pair per law, so that repeated solves of one
    law reuse them): at a constant rate ``args = (params, gdot)``, and on a schedule
    ``args = (params, times, rates)``."""

    def constant(t, y, args):
        params, gdot = args
        return law.rate(params, gdot, y)

    def schedule(t, y, args):
        params, times, rates = args
        return law.rate(params, _rate_at(t, times, rates), y)

    return diffrax.ODETerm(constant), diffrax.ODETerm(schedule)


def _initial(law: Law, params, shape):
    """The internal variables at t = 0: each at its ``init`` parameter, broadcast to ``shape``."""
    return {i.name: jnp.broadcast_to(getattr(params, i.init), shape) for i in law.internals}


def _controller(rtol, atol, jump_ts=None):
    pid = diffrax.PIDController(rtol=rtol, atol=atol)
    if jump_ts is None:
        return pid
    return diffrax.ClipStepSizeController(pid, jump_ts=jump_ts)


def _result(law, params, t_s, gdot, internal):
    mu = law.mu(params, gdot, internal)
    shape = jnp.broadcast_shapes(jnp.shape(gdot), jnp.shape(mu), *(jnp.shape(v) for v in internal.values()))
    gdot = jnp.broadcast_to(gdot, shape)
    mu = jnp.broadcast_to(mu, shape)
    return RheometerResult(t_s=t_s, gamma_dot_1_s=gdot, internal=internal, mu_pa_s=mu, tau_pa=mu * gdot)


@functools.partial(jax.jit, static_argnames=("rtol", "atol", "max_steps", "adjoint"))
def _constant_shear_jit(params, gamma_dot, t_s, rtol, atol, max_steps, adjoint=None):
    law = law_of(params)()
    gdot = jnp.expand_dims(gamma_dot, -1)
    if not law.internals:  # nothing evolves: mu is constant in time at a constant rate
        return _result(law, params, t_s, jnp.broadcast_to(gdot, gamma_dot.shape + t_s.shape), {})
    sol = diffrax.diffeqsolve(
        _terms(law)[0],
        diffrax.Kvaerno5(),
        t0=jnp.zeros((), t_s.dtype),
        t1=t_s[-1],
        dt0=None,
        y0=_initial(law, params, gamma_dot.shape),
        args=(params, gamma_dot),
        saveat=diffrax.SaveAt(ts=t_s),
        stepsize_controller=_controller(rtol, atol),
        max_steps=max_steps,
        adjoint=diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
    )
    # (m,) + gdot.shape -> gdot.shape + (m,)
    internal = {k: jnp.moveaxis(v, 0, -1) for k, v in sol.ys.items()}
    return _result(law, params, t_s, gdot, internal)


def _check_times(t_s, name):
    v = _concrete(t_s)
    if v is None:
        return
    if v.ndim != 1 or v.size == 0:
        raise ValueError(f"{name} must be a non-empty 1-D array of times [s], got shape {v.shape}")
    if not np.all(np.isfinite(v)) or np.any(np.diff(v) < 0):
        raise ValueError(f"{name} must be finite and non-decreasing [s]")


def constant_shear(
    params,
    gamma_dot,
    t_s,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_steps: int = 4096,
    adjoint=None,
) -> RheometerResult:
    """Constant-shear-rate test (thesis Figs. 7, 26, 31; Coussot et al. 2002).

    Starts from the law's initial internal state (Coussot: lam(0) = params.lambda0) at
    t = 0 and imposes ``gamma_dot`` [1/s] (>= 0; 0 is rest/aging) for all t >= 0.  Solves
    dy/dt = law.rate (Coussot: dlam/dt = 1/T - alpha gdot lam, thesis eq. 2.14 / 3.9) with
    ``diffrax.Kvaerno5`` and an adaptive PID controller, and returns the internal
    variables, mu = law.mu (Coussot: min(mu0 (1 + lam^n), mu_max), eq. 2.15 / 3.7) and
    tau = mu gdot at the save times ``t_s`` [s] (1-D, non-decreasing, >= 0).  A law without
    internal variables is not integrated (mu is constant in time).

    ``gamma_dot`` may be a scalar (outputs of shape (m,)) or a 1-D array of k rates
    (outputs (k, m)); k rates are k independent tests solved as one decoupled system
    of k equations in a single solve (one compilation, error control on each).

    Jit-able (``params`` and ``gamma_dot`` are traced) and differentiable w.r.t.
    ``params`` and ``gamma_dot``.  ``adjoint``: a diffrax adjoint (default
    ``RecursiveCheckpointAdjoint``, reverse mode only; ``diffrax.DirectAdjoint()`` also
    allows forward mode).
    """
    params = _as_float_params(params)
    dtype = params[0].dtype
    t_s = jnp.asarray(t_s, dtype=dtype)
    _check_times(t_s, "t_s")
    gamma_dot = jnp.asarray(gamma_dot, dtype=dtype)
    if gamma_dot.ndim > 1:
        raise ValueError(f"gamma_dot must be a scalar or 1-D array of rates [1/s], got shape {gamma_dot.shape}")
    rtol, atol = _tolerances(rtol, atol, dtype)
    return _constant_shear_jit(params, gamma_dot, t_s, rtol, atol, int(max_steps), adjoint)


@functools.partial(jax.jit, static_argnames=("rtol", "atol", "max_steps", "adjoint"))
def _shear_history_jit(params, times, rates, t_save, rtol, atol, max_steps, adjoint=None):
    law = law_of(params)()
    gdot = _rate_at(t_save, times, rates)
    if not law.internals:
        return _result(law, params, t_save, gdot, {})
    jump_ts = times[1:] if times.shape[0] > 1 else None
    sol = diffrax.diffeqsolve(
        _terms(law)[1],
        diffrax.Kvaerno5(),
        t0=times[0],
        t1=t_save[-1],
        dt0=None,
        y0=_initial(law, params, ()),
        args=(params, times, rates),
        saveat=diffrax.SaveAt(ts=t_save),
        stepsize_controller=_controller(rtol, atol, jump_ts),
        max_steps=max_steps,
        adjoint=diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
    )
    return _result(law, params, t_save, gdot, sol.ys)


def shear_history(
    params,
    times_s,
    rates_1_s,
    t_save_s,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_steps: int = 4096,
    adjoint=None,
) -> RheometerResult:
    """Piecewise-constant shear-rate history (step tests, e.g. 100 1/s then 0.1 1/s).

    ``rates_1_s[i]`` [1/s] is imposed on [times_s[i], times_s[i+1]) and the last rate
    until the end; the internal variables start from their ``init`` parameters at
    times_s[0] (Coussot: lam = params.lambda0).  ``t_save_s`` [s] must lie in
    [times_s[0], ...] and be non-decreasing; the solve ends at ``t_save_s[-1]``.

    One ``diffeqsolve`` (Kvaerno5, adaptive PID) with the rate looked up from the
    schedule in the vector field; the step times ``times_s[1:]`` are passed as
    ``jump_ts`` to ``diffrax.ClipStepSizeController`` so the solver lands on each
    discontinuity instead of rejecting steps to find it, and the whole history is a
    single differentiable, jit-able solve (a sequence of solves would need one
    compilation per number of segments and Python-level glue).  ``adjoint``: as in
    :func:`constant_shear`.
    """
    params = _as_float_params(params)
    dtype = params[0].dtype
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
    return _shear_history_jit(params, times, rates, t_save, rtol, atol, int(max_steps), adjoint)


# --------------------------------------------------------------------------------------
# Steady state
# --------------------------------------------------------------------------------------


def steady_flow_curve(params, gamma_dot):
    """Steady flow curve of the law of ``params``: (tau_ss [Pa], mu_ss [Pa s]) at gdot [1/s] > 0.

    The internal variables at their steady state (``law.steady_internal``), mu_ss =
    law.mu there and tau_ss = mu_ss gdot.  Coussot (Coussot et al. 2002; REFERENCE.md):
    lam_ss = 1/(alpha T gdot), mu_ss = min(mu0 [1 + (alpha T gdot)^-n], mu_max).  A law
    without internal variables gives its plain flow curve; one with internal variables but
    no declared steady state raises ``NotImplementedError``.
    """
    law = law_of(params)()
    gdot = jnp.asarray(gamma_dot, dtype=jnp.result_type(*params, float))
    mu_ss = law.mu(params, gdot, law.steady_internal(params, gdot))
    return mu_ss * gdot, mu_ss


def critical_point(params: CoussotParams):
    """Minimum of the *uncapped* steady Coussot flow curve (viscosity bifurcation), n > 1.

    gdot_c = (n-1)^(1/n) / (alpha T) [1/s],  tau_c = mu0 n (n-1)^(1/n - 1) / (alpha T) [Pa]
    (Coussot et al. 2002; REFERENCE.md).  Below gdot_c no steady homogeneous flow is
    stable.  The cap mu_max is ignored: the point is a local minimum of the capped
    curve only if mu0 [1 + 1/(n-1)] < mu_max (true for all thesis parameter sets).

    Raises ``ValueError`` for another law than Coussot, and for a concrete n <= 1 (the
    flow curve is then monotonic); with a traced n the result is NaN there.
    """
    law = law_of(params)
    if not issubclass(law, Coussot):
        raise ValueError(
            f"critical_point is defined for the Coussot law only; got {law.name} ({type(params).__name__})"
        )
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
    # matplotlib only when files are written (optional heavy import)
    import matplotlib.pyplot as plt

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

    gc = tc = None
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

    files = ["viscosity_vs_time.png", "flow_curve.png", "rheometer.csv", "rheometer.json"]
    columns = _csv_columns(law)

    # CSV
    with open(os.path.join(out_dir, "rheometer.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for res in results:
            cols = [res.t_s, res.gamma_dot_1_s, *(res.internal[i.name] for i in law.internals), res.mu_pa_s, res.tau_pa]
            for row in zip(*(np.asarray(c) for c in cols)):
                w.writerow([f"{float(v):.12g}" for v in row])

    # Viscosity vs time
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
    fig.savefig(os.path.join(out_dir, "viscosity_vs_time.png"), dpi=120)
    plt.close(fig)

    # Flow curve
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
    fig.savefig(os.path.join(out_dir, "flow_curve.png"), dpi=120)
    plt.close(fig)

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


# --------------------------------------------------------------------------------------
# CLI hooks: `mpmjax rheometer` (the Coussot law)
# --------------------------------------------------------------------------------------

# The Coussot parameters the rheometer uses (rho and kappa are carried, not used), each with
# its option --name (underscores as dashes: --mu-max).
_CLI_PARAMS = tuple(p for p in Coussot.params if p.name not in ("rho", "kappa"))


def _flag(p: Param) -> str:
    return "--" + p.name.replace("_", "-")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``mpmjax rheometer`` options (defaults: thesis BASE lab case)."""
    for p in _CLI_PARAMS:
        parser.add_argument(
            _flag(p),
            dest=p.name,
            default=str(BASE_VALUES[p.name]),
            metavar="X",
            help=f"{p.doc.rstrip('.')} [{p.unit}] (default {BASE_VALUES[p.name]:g}, thesis BASE)",
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


def _parse_number(option, value):
    """A finite number > 0 from the command line."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = None
    if x is None or not (math.isfinite(x) and x > 0):
        raise _BadInput(f"{option}: invalid value {value!r}; allowed range: a finite number > 0")
    return x


def _parse_param(p: Param, value):
    """A value of the declared parameter ``p`` from the command line (its declared range)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = None
    if x is None or not (math.isfinite(x) and bool(_in_range(p, np.asarray(x)))):
        raise _BadInput(f"{_flag(p)}: invalid value {value!r}; allowed range: a finite number {_range_text(p)}")
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
        vals = {p.name: _parse_param(p, getattr(args, p.name, BASE_VALUES[p.name])) for p in _CLI_PARAMS}
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
