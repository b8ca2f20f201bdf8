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

The physics is in ``_physics`` and the files ``write_outputs`` writes in ``_files``; both
re-exported here.  The ``mpmjax rheometer`` command (its options and handler) is
``mpmjax.cli._rheometer``.
"""

from __future__ import annotations

from .._rheology import BASE_VALUES
from ._files import write_outputs
from ._physics import (
    MIZANI_FAST_VALUES,
    MIZANI_VALUES,
    RheometerResult,
    constant_shear,
    critical_point,
    make_params,
    shear_history,
    steady_flow_curve,
    validate_params,
)

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
]


def __getattr__(name):
    # BASE_PARAMS etc. are built lazily so that their dtype follows jax_enable_x64.
    table = {"BASE_PARAMS": BASE_VALUES, "MIZANI_PARAMS": MIZANI_VALUES, "MIZANI_FAST_PARAMS": MIZANI_FAST_VALUES}
    if name in table:
        return make_params(**table[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
