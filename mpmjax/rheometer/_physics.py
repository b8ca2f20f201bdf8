"""The rheometer's physics: parameters (``make_params``, ``validate_params``), the transient solves
(``constant_shear``, ``shear_history``) and the steady state (``steady_flow_curve``,
``critical_point``).  The model, its exact solutions and the numerics: ``mpmjax.rheometer``."""

from __future__ import annotations

import functools
from typing import NamedTuple

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .._rheology import BASE_VALUES, MODELS, Coussot, CoussotParams, Law, Param, law_of


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
