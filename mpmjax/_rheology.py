"""Rheology plug-ins: effective viscosity laws, each defined in one place.

A law is a small frozen (hashable, static) dataclass, a subclass of :class:`Law`, paired
with a ``NamedTuple`` of parameters that are traced arrays, so that ``jax.grad`` and
``jax.vmap`` reach them.  Besides the physics, a law *declares*:

* ``params``: its parameters (:class:`Param`: NamedTuple field, scene key, unit, default,
  allowed range, and calibration's default search bounds).  The scene schema
  (``mpmjax scenes --keys``, docs/scenes.md), ``make_params``, calibration's parameter
  specs and sweep's name -> key mapping, the rheometer's units and the result files all
  read these declarations; nothing else lists a parameter's name, unit, default or range;
* ``options``: static choices (:class:`Option`, e.g. the Bingham variant), scene keys too;
* ``internals``: its internal variables (:class:`Internal`: name in the state, name in the
  outputs, unit, the parameter giving the initial value);
* ``rate(params, shear, internal)``: d(internal)/dt [1/s] at a shear rate, which the 0-D
  rheometer integrates with diffrax;
* ``update_internal(params, shear, internal, dt)``: the internal variables after one MPM
  step at constant shear (an exact or unconditionally stable update, never explicit Euler
  by default);
* ``mu(params, shear, internal)``: the effective viscosity [Pa s] at a state;
* ``max_viscosity(params)``: the largest viscosity the law can produce (for the viscous
  time-step limit), and ``max_viscosity_params``: the parameters it reads (named in errors);
* optionally ``steady_internal(params, shear)``: the steady internal state at a constant
  shear rate, for steady flow curves.
* optionally ``ordered_params``: (lower, upper) parameter pairs the scene must keep in
  order (Coussot: ``mu0 <= mu_max``); a scene that breaks one is refused, naming both keys.

The MPM step never branches on the law: it calls ``init_internal`` and ``viscosity``
(update the internal variables where the material ages, then ``mu``), and builds the
Cauchy stress ``sigma = -p I + s`` itself, where ``s`` is the deviatoric stress from
``mu_eff`` (``_constitutive.deviatoric_update``).

Adding a law: subclass :class:`Law` in one file (a module of your own is fine) and call
``mpmjax.register_law(MyLaw)``; ``material.model = "my_law"`` then works in scenes, and
the law runs through ``build``, ``simulate``, ``sweep``, the rheometer and ``calibrate``
(docs/api.md, "Adding a rheology").  A parameter name means one parameter everywhere: two
laws that share a name (``mu_max``) share the :class:`Param` object.

Shear measures (see ../shared/REFERENCE.md, thesis eqs. 3.8-3.9 and Annex 1):

* ``"standard"``: gamma_dot = sqrt(2 d':d') [1/s]; equals the imposed rate in
  simple shear.
* ``"thesis"``: |0.5 * II_d'| = d':d'/4, which is gamma_dot**2/8 in simple
  shear.  It is *not* a rate; it is kept only to reproduce the thesis.

Units: SI throughout (Pa, Pa s, s, kg/m^3).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, NamedTuple

import jax.numpy as jnp

# Smallest shear measure used in divisions (1/s).  Below it the regularised laws
# use their analytic limit, so gradients stay finite at rest.
_GDOT_EPS = 1e-12


# --------------------------------------------------------------------------------------
# Declarations
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Param:
    """One material parameter, declared once.

    name: field of the law's parameter NamedTuple (and calibration's parameter name);
    key: scene key (``material.*``, the SI unit in its name); unit: SI unit; doc: meaning;
    default: value where a scene omits the key (None: required, unless ``optional``); lo / lo_open /
    hi: the allowed range (inclusive unless ``lo_open``); bounds: calibration's default search
    range (lo, hi) [SI], wide enough to hold every value in the thesis and the literature
    it cites, with margin.  ``optional``: the key may be left out where the step does not use the
    parameter (``unused_parameters``; the scene's value is then None, and the parameter ``UNUSED``); the
    schema's validation requires it everywhere else.
    """

    name: str
    key: str
    unit: str
    doc: str
    default: float | None = None
    lo: float | None = None
    lo_open: bool = False
    hi: float | None = None
    bounds: tuple[float, float] | None = None
    optional: bool = False


def unused_parameters(cfg) -> dict[str, str]:
    """Name -> why, for the material parameters the step of the validated scene ``cfg`` does not read:
    the bulk modulus ``KAPPA`` except with the particles' pressure (``numerics.pressure = "explicit"``) in
    the full formulation.  There an ``optional`` parameter may be left out (the schema's validation
    requires it everywhere else), and none can be fitted or varied (``mpmjax.unused_parameters``)."""
    if cfg["model.formulation"] == "depth-averaged":
        why = "the depth-averaged step (model.formulation = 'depth-averaged') has no bulk modulus"
    elif cfg["numerics.pressure"] == "incompressible":
        why = (
            "numerics.pressure = 'incompressible' solves the pressure on the grid, so the bulk modulus "
            "(material.bulk_modulus_pa) does not enter; set numerics.pressure=explicit to vary it"
        )
    else:
        return {}
    return {KAPPA.name: why}


# the value an ``optional`` parameter the scene left out takes in ``Params``: the step does not read it (for
# kappa: the grid pressure and the depth-averaged model keep the volume without it; incompressible, kappa = inf)
UNUSED = math.inf


@dataclasses.dataclass(frozen=True)
class Option:
    """A static choice of a law (a field of its dataclass), set by the scene key ``key``."""

    name: str
    key: str
    default: str
    choices: tuple[str, ...]
    doc: str


@dataclasses.dataclass(frozen=True)
class Internal:
    """An internal variable: ``name`` in ``State.internal``, ``label`` in the result files,
    ``unit``, ``doc``, and ``init``: the parameter whose value it starts from."""

    name: str
    label: str
    unit: str
    doc: str
    init: str


# Parameters shared by every law.
# at least 1 kg/m^3 (any fluid or slurry has more): 1e-300 passed the old "> 0" and, in float64 with the grid
# pressure, made the nodal masses of a 4 cm grid about 1e-304, whose inverses overflow: NaN at the first step
RHO = Param("rho", "material.density_kg_m3", "kg/m^3", "Reference density rho.", lo=1.0, bounds=(100.0, 2e4))
KAPPA = Param(
    "kappa",
    "material.bulk_modulus_pa",
    "Pa",
    "Bulk modulus kappa of the Tait EOS: the particles' pressure with numerics.pressure = explicit (and its "
    "Maxwell modulus, unless numerics.maxwell_shear_modulus_pa is set), where it is required. The grid pressure "
    "(numerics.pressure = incompressible) and the depth-averaged model (model.formulation = depth-averaged) do not "
    "use it, and there it may be left out.",
    lo=0.0,
    lo_open=True,
    bounds=(1.0, 1e12),
    optional=True,
)
# Newtonian, Bingham.
VISCOSITY = Param(
    "mu",
    "material.viscosity_pa_s",
    "Pa s",
    "Newtonian viscosity, or Bingham plastic viscosity.",
    1.0,
    lo=0.0,
    lo_open=True,
    bounds=(1e-4, 1e6),
)
YIELD_STRESS = Param(
    "tau_y", "material.yield_stress_pa", "Pa", "Yield stress tau_y (Bingham, Herschel-Bulkley).", 0.0, lo=0.0,
    bounds=(1e-3, 1e6),
)  # fmt: skip
ALPHA_B = Param(
    "alpha_b", "material.alpha_b", "-", "Bi-viscosity ratio below yield.", 100.0, lo=1.0, lo_open=True,
    bounds=(1.1, 1e6),
)  # fmt: skip
PAPANASTASIOU_M = Param(
    "m", "material.papanastasiou_m_s", "s", "Papanastasiou regularisation time m.", 100.0, lo=0.0, lo_open=True,
    bounds=(1e-3, 1e5),
)  # fmt: skip
# Herschel-Bulkley.
CONSISTENCY = Param(
    "K", "material.consistency_pa_sn", "Pa s^n", "Herschel-Bulkley consistency K.", 1.0, lo=0.0, lo_open=True,
    bounds=(1e-4, 1e6),
)  # fmt: skip
FLOW_INDEX = Param(
    "n_hb", "material.flow_index", "-", "Herschel-Bulkley flow index.", 1.0, lo=0.0, lo_open=True, hi=3.0,
    bounds=(0.05, 3.0),
)  # fmt: skip
# Coussot (defaults: the thesis's BASE lab case, §4.5 Table 8; mu_max from Annex 2).
MU0 = Param(
    "mu0", "material.mu0_pa_s", "Pa s", "Coussot minimum viscosity mu0.", 4.0, lo=0.0, lo_open=True,
    bounds=(1e-3, 1e4),
)  # fmt: skip
ALPHA = Param(
    "alpha", "material.alpha", "-", "Coussot destructuration coefficient alpha.", 1.0, lo=0.0, lo_open=True,
    bounds=(1e-4, 1e3),
)  # fmt: skip
RESTRUCTURING_TIME = Param(
    "T", "material.T_s", "s", "Coussot restructuring time T.", 0.5, lo=0.0, lo_open=True, bounds=(1e-3, 1e6)
)
EXPONENT = Param("n", "material.n", "-", "Coussot exponent n.", 2.5, lo=0.0, lo_open=True, hi=10.0, bounds=(0.05, 10.0))
LAMBDA0 = Param(
    "lambda0", "material.lambda0", "-", "Coussot initial structure lambda0.", 1.5, lo=0.0, bounds=(1e-4, 1e4)
)
MU_MAX = Param(
    "mu_max", "material.mu_max_pa_s", "Pa s", "Viscosity cap mu_max (Coussot, Herschel-Bulkley).", 5000.0, lo=0.0,
    lo_open=True, bounds=(1e-2, 1e8),
)  # fmt: skip

BINGHAM_VARIANT = Option(
    "variant", "material.bingham_variant", "papanastasiou", ("papanastasiou", "biviscosity"), "Bingham law."
)
LAMBDA_INTEGRATOR = Option(
    "integrator",
    "material.lambda_integrator",
    "exact",
    ("exact", "euler"),
    "Structure update: exact exponential, or the thesis's explicit Euler.",
)
SHEAR_MEASURE = Option(
    "shear_measure",
    "material.shear_measure",
    "standard",
    ("standard", "thesis"),
    "standard: sqrt(2 d':d'); thesis: d':d'/4 (eq. 3.8 and Annex 1).",
)

# The thesis's BASE lab material (§4.5 Table 8, Annex 2 for mu_max): the Coussot defaults
# above with the lab tailings' density and bulk modulus.
BASE_DENSITY_KG_M3 = 1850.0
BASE_BULK_MODULUS_PA = 15000.0


# --------------------------------------------------------------------------------------
# Parameter pytrees
# --------------------------------------------------------------------------------------


class NewtonianParams(NamedTuple):
    """Weakly compressible Newtonian fluid.

    rho: reference density [kg/m^3]; kappa: bulk modulus of the Tait EOS [Pa];
    mu: dynamic viscosity [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu: jnp.ndarray


class BinghamParams(NamedTuple):
    """Bingham fluid (bi-viscosity or Papanastasiou).

    tau_y: yield stress [Pa]; mu: plastic viscosity [Pa s];
    alpha_b: bi-viscosity ratio below yield [-] (thesis, Hosseini et al. 2006,
    >= 100 recommended); m: Papanastasiou regularisation time [s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu: jnp.ndarray
    tau_y: jnp.ndarray
    alpha_b: jnp.ndarray
    m: jnp.ndarray


class HerschelBulkleyParams(NamedTuple):
    """Regularised Herschel-Bulkley: tau = tau_y + K gdot^n_hb.

    K: consistency [Pa s^n_hb]; n_hb: flow index [-]; m: Papanastasiou time [s];
    mu_max: viscosity cap [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    tau_y: jnp.ndarray
    K: jnp.ndarray
    n_hb: jnp.ndarray
    m: jnp.ndarray
    mu_max: jnp.ndarray


class CoussotParams(NamedTuple):
    """Coussot (2002) thixotropy: dlam/dt = 1/T - alpha gdot lam, mu = mu0 (1 + lam^n).

    mu0: minimum viscosity [Pa s]; alpha: destructuration coefficient [-];
    T: characteristic restructuring time [s]; n: exponent [-];
    lambda0: initial structure [-]; mu_max: viscosity cap [Pa s].
    """

    rho: jnp.ndarray
    kappa: jnp.ndarray
    mu0: jnp.ndarray
    alpha: jnp.ndarray
    T: jnp.ndarray
    n: jnp.ndarray
    lambda0: jnp.ndarray
    mu_max: jnp.ndarray


# --------------------------------------------------------------------------------------
# Formulas
# --------------------------------------------------------------------------------------


def _safe_inv(x):
    """1/x with x floored at _GDOT_EPS (x >= 0)."""
    return 1.0 / jnp.maximum(x, _GDOT_EPS)


def _one_minus_exp_over(a, t):
    """(1 - exp(-a t)) / a for a >= 0, continuous (-> t) and differentiable at a = 0."""
    small = a * t < 1e-6
    a_safe = jnp.where(small, 1.0, a)
    return jnp.where(small, t * (1.0 - 0.5 * a * t), -jnp.expm1(-a_safe * t) / a_safe)


def coussot_lambda_exact(lam, gdot, dt, alpha, T):
    """Exact update of dlam/dt = 1/T - alpha gdot lam over dt at constant gdot.

    lam(t+dt) = lam exp(-alpha gdot dt) + (1 - exp(-alpha gdot dt)) / (alpha gdot T),
    which is lam_ss + (lam - lam_ss) exp(-alpha gdot dt) with lam_ss = 1/(alpha T gdot),
    and reduces to lam + dt/T at gdot = 0 (REFERENCE.md).  Positive and bounded for any dt.
    """
    a = alpha * gdot
    return lam * jnp.exp(-a * dt) + _one_minus_exp_over(a, dt) / T


def coussot_lambda_euler(lam, gdot, dt, alpha, T):
    """Thesis eq. 3.9 (explicit Euler); unstable once alpha gdot dt > 1.  Comparison only."""
    return lam + dt * (1.0 / T - alpha * gdot * lam)


def coussot_mu(lam, mu0, n, mu_max):
    """mu = min(mu0 (1 + lam^n), mu_max) [Pa s] (thesis eq. 3.7 plus its cap)."""
    lam_pos = jnp.maximum(lam, 0.0)
    return jnp.minimum(mu0 * (1.0 + lam_pos**n), mu_max)


# --------------------------------------------------------------------------------------
# Laws
# --------------------------------------------------------------------------------------


class Law:
    """Base of the rheology laws (see the module docstring for the protocol).

    Subclasses are frozen dataclasses whose fields are their ``options``; they set the class
    attributes ``name``, ``params_type``, ``params``, and, where they apply, ``options``,
    ``internals``, ``max_viscosity_params``, and implement ``mu`` and ``max_viscosity``
    (plus ``rate`` and ``update_internal`` when they have internal variables).
    """

    name: ClassVar[str]
    params_type: ClassVar[type]
    params: ClassVar[tuple[Param, ...]]
    options: ClassVar[tuple[Option, ...]] = ()
    internals: ClassVar[tuple[Internal, ...]] = ()
    max_viscosity_params: ClassVar[tuple[str, ...]] = ()
    # the parameter holding the law's yield stress [Pa], if it has one (the incompressible step's default
    # Maxwell modulus is at least MAXWELL_YIELD_FACTOR times it: ``_build.time_step_limits``)
    yield_stress_param: ClassVar[str | None] = None
    # (lower, upper) parameter pairs that must satisfy lower <= upper (Coussot: mu0 <= mu_max,
    # a cap below the base viscosity would hold the whole material at the cap); checked by the
    # scene validation, which names both keys
    ordered_params: ClassVar[tuple[tuple[str, str], ...]] = ()

    @property
    def internal_fields(self) -> tuple[str, ...]:
        return tuple(i.name for i in self.internals)

    def init_internal(self, params, n: int) -> dict:
        """Internal variables of ``n`` fresh particles: each at its ``init`` parameter."""
        out = {}
        for i in self.internals:
            v = getattr(params, i.init)
            out[i.name] = jnp.full((n,), v, dtype=jnp.result_type(v))
        return out

    def rate(self, params, shear, internal) -> dict:
        """d(internal)/dt [1/s per unit of each variable] at the shear measure ``shear``."""
        return {}

    def update_internal(self, params, shear, internal, dt) -> dict:
        """The internal variables after ``dt`` at constant ``shear``."""
        if self.internals:
            raise NotImplementedError(f"{type(self).__name__} has internal variables and must define update_internal")
        return internal

    def mu(self, params, shear, internal):
        """Effective viscosity [Pa s] at the shear measure ``shear`` and state ``internal``."""
        raise NotImplementedError

    def max_viscosity(self, params):
        """The largest viscosity [Pa s] the law can produce."""
        raise NotImplementedError

    def yield_stress(self, params):
        """The law's yield stress [Pa] (0 for a law without one)."""
        return getattr(params, self.yield_stress_param) if self.yield_stress_param else 0.0

    def steady_internal(self, params, shear) -> dict:
        """The internal state reached at a constant shear rate (steady flow curve)."""
        if self.internals:
            raise NotImplementedError(f"{type(self).__name__} declares no steady state (steady_internal)")
        return {}

    def viscosity(self, params, shear, internal, dt, aging):
        """One MPM step: the internal variables advance over ``dt`` where ``aging`` is True
        (material past the aging gate; elsewhere they are held) and the viscosity follows.
        Returns ``(mu_eff, internal)``."""
        if not self.internals:
            return self.mu(params, shear, internal), internal
        new = self.update_internal(params, shear, internal, dt)
        new = {k: jnp.where(aging, new[k], internal[k]) for k in internal}
        return self.mu(params, shear, new), new


@dataclasses.dataclass(frozen=True)
class Newtonian(Law):
    """Constant viscosity."""

    name: ClassVar[str] = "newtonian"
    params_type: ClassVar[type] = NewtonianParams
    params: ClassVar[tuple[Param, ...]] = (RHO, KAPPA, VISCOSITY)
    max_viscosity_params: ClassVar[tuple[str, ...]] = ("mu",)

    def mu(self, params, shear, internal):
        return jnp.full_like(shear, params.mu)

    def max_viscosity(self, params):
        return params.mu


@dataclasses.dataclass(frozen=True)
class Bingham(Law):
    """Bingham plastic.

    variant = "biviscosity": the thesis's model (Hosseini et al. 2006, eqs. 3.12-3.13).
      With the standard measure, mu_eff = alpha_b mu below gdot_c = tau_y/((alpha_b-1) mu)
      and mu + tau_y/gdot above (continuous at gdot_c).  With the thesis measure the
      thesis's own switch is reproduced: alpha_b mu below II < tau_y/(2 alpha_b mu), else
      mu + tau_y/(2 II).
    variant = "papanastasiou": mu_eff = mu + tau_y (1 - exp(-m gdot))/gdot, smooth, for
      gradients (Papanastasiou 1987).
    """

    variant: str = "papanastasiou"
    shear_measure: str = "standard"
    name: ClassVar[str] = "bingham"
    params_type: ClassVar[type] = BinghamParams
    params: ClassVar[tuple[Param, ...]] = (RHO, KAPPA, VISCOSITY, YIELD_STRESS, ALPHA_B, PAPANASTASIOU_M)
    options: ClassVar[tuple[Option, ...]] = (BINGHAM_VARIANT, SHEAR_MEASURE)
    max_viscosity_params: ClassVar[tuple[str, ...]] = ("mu", "tau_y", "m", "alpha_b")
    yield_stress_param: ClassVar[str | None] = "tau_y"

    def mu(self, params, shear, internal):
        mu, ty = params.mu, params.tau_y
        if self.variant == "papanastasiou":
            reg = ty * _one_minus_exp_over(shear, params.m)
            return mu + reg
        ab = params.alpha_b
        if self.shear_measure == "thesis":
            below = shear < ty / (2.0 * ab * mu)
            above_mu = mu + ty * 0.5 * _safe_inv(shear)
        else:
            below = shear < ty / ((ab - 1.0) * mu)
            above_mu = mu + ty * _safe_inv(shear)
        return jnp.where(below, ab * mu, above_mu)

    def max_viscosity(self, params):
        if self.variant == "papanastasiou":
            return params.mu + params.tau_y * params.m
        return params.alpha_b * params.mu


@dataclasses.dataclass(frozen=True)
class HerschelBulkley(Law):
    """Regularised Herschel-Bulkley: mu_eff = K gdot^(n-1) + tau_y (1 - e^{-m gdot})/gdot,
    capped at mu_max (the power-law term diverges at rest when n < 1)."""

    name: ClassVar[str] = "herschel_bulkley"
    params_type: ClassVar[type] = HerschelBulkleyParams
    params: ClassVar[tuple[Param, ...]] = (RHO, KAPPA, YIELD_STRESS, CONSISTENCY, FLOW_INDEX, PAPANASTASIOU_M, MU_MAX)
    max_viscosity_params: ClassVar[tuple[str, ...]] = ("mu_max",)
    yield_stress_param: ClassVar[str | None] = "tau_y"

    def mu(self, params, shear, internal):
        g = jnp.maximum(shear, _GDOT_EPS)
        mu = params.K * g ** (params.n_hb - 1.0) + params.tau_y * _one_minus_exp_over(shear, params.m)
        return jnp.minimum(mu, params.mu_max)

    def max_viscosity(self, params):
        return params.mu_max


@dataclasses.dataclass(frozen=True)
class Coussot(Law):
    """Coussot (2002) thixotropic fluid (thesis §3.4.1).

    dlam/dt = 1/T - alpha gdot lam, mu = min(mu0 (1 + lam^n), mu_max).
    integrator = "exact": exact exponential update at constant shear over a step (default).
    integrator = "euler": the thesis's explicit Euler (eq. 3.9), for comparison only.
    Where ``aging`` is False (material not yet past the aging gate) lam is held at its
    current value: the material neither ages nor de-structures (thesis §3.4.2).
    """

    integrator: str = "exact"
    name: ClassVar[str] = "coussot"
    params_type: ClassVar[type] = CoussotParams
    params: ClassVar[tuple[Param, ...]] = (RHO, KAPPA, MU0, ALPHA, RESTRUCTURING_TIME, EXPONENT, LAMBDA0, MU_MAX)
    options: ClassVar[tuple[Option, ...]] = (LAMBDA_INTEGRATOR,)
    internals: ClassVar[tuple[Internal, ...]] = (Internal("lam", "lambda", "-", "structure parameter", "lambda0"),)
    max_viscosity_params: ClassVar[tuple[str, ...]] = ("mu_max",)
    ordered_params: ClassVar[tuple[tuple[str, str], ...]] = (("mu0", "mu_max"),)

    def rate(self, params, shear, internal):
        return {"lam": 1.0 / params.T - params.alpha * shear * internal["lam"]}

    def update_internal(self, params, shear, internal, dt):
        update = coussot_lambda_exact if self.integrator == "exact" else coussot_lambda_euler
        return {"lam": update(internal["lam"], shear, dt, params.alpha, params.T)}

    def mu(self, params, shear, internal):
        return coussot_mu(internal["lam"], params.mu0, params.n, params.mu_max)

    def max_viscosity(self, params):
        return params.mu_max

    def steady_internal(self, params, shear):
        return {"lam": 1.0 / (params.alpha * params.T * shear)}


# --------------------------------------------------------------------------------------
# Registry
# --------------------------------------------------------------------------------------

# law name -> class, in the order the scene schema lists them
MODELS: dict[str, type[Law]] = {}
# Every material Param and Option, in the order of the scene-key table (docs/scenes.md).
MATERIAL_KEYS: list[Param | Option] = [
    RHO,
    KAPPA,
    VISCOSITY,
    YIELD_STRESS,
    BINGHAM_VARIANT,
    ALPHA_B,
    PAPANASTASIOU_M,
    CONSISTENCY,
    FLOW_INDEX,
    MU0,
    ALPHA,
    RESTRUCTURING_TIME,
    EXPONENT,
    LAMBDA0,
    MU_MAX,
    LAMBDA_INTEGRATOR,
    SHEAR_MEASURE,
]
_listeners: list = []  # called after the registry changes (the scene schema rebuilds itself)


def _check_law(cls) -> None:
    for attr in ("name", "params_type", "params"):
        if not hasattr(cls, attr):
            raise TypeError(f"{cls.__name__}: a law must set the class attribute {attr!r}")
    fields = tuple(cls.params_type._fields)
    names = tuple(p.name for p in cls.params)
    if sorted(fields) != sorted(names):
        raise TypeError(f"{cls.__name__}: params declare {names} but {cls.params_type.__name__} has fields {fields}")
    if "rho" not in names or "kappa" not in names:
        raise TypeError(f"{cls.__name__}: every law takes rho and kappa (declare RHO and KAPPA)")
    for pair in cls.ordered_params:
        if len(pair) != 2 or not set(pair) <= set(names):
            raise TypeError(f"{cls.__name__}: ordered_params {pair!r} must name two of its parameters {names}")
    for i in cls.internals:
        if i.init not in names:
            raise TypeError(f"{cls.__name__}: internal {i.name!r} starts from {i.init!r}, which is not a parameter")
    by_name = {p.name: p for p in MATERIAL_KEYS if isinstance(p, Param)}
    by_key = {p.key: p for p in MATERIAL_KEYS}
    for p in cls.params + cls.options:
        other = by_key.get(p.key)
        if other is not None and other != p:
            raise TypeError(f"{cls.__name__}: scene key {p.key!r} is already declared differently: {other}")
        if isinstance(p, Param) and p.name in by_name and by_name[p.name] != p:
            raise TypeError(
                f"{cls.__name__}: parameter {p.name!r} is already declared differently ({by_name[p.name]}); "
                "a name means one parameter everywhere: reuse that Param or choose another name"
            )


def register(cls: type[Law]) -> type[Law]:
    """Add a law (a :class:`Law` subclass) to the registry; its parameters and options become
    scene keys.  Returns the class (usable as a decorator)."""
    _check_law(cls)
    if cls.name in MODELS and MODELS[cls.name] is not cls:
        raise ValueError(f"a law named {cls.name!r} is already registered ({MODELS[cls.name].__name__})")
    MODELS[cls.name] = cls
    for p in cls.params + cls.options:
        if p not in MATERIAL_KEYS:
            MATERIAL_KEYS.insert(len(MATERIAL_KEYS) - 1, p)  # before material.shear_measure
    for f in _listeners:
        f()
    return cls


def unregister(name: str) -> None:
    """Remove the law ``name`` and the scene keys that only it declared (built-in laws cannot
    be removed)."""
    if name in _BUILTIN:
        raise ValueError(f"{name!r} is a built-in law and cannot be removed")
    cls = MODELS.pop(name)
    used = {p for c in MODELS.values() for p in c.params + c.options} | set(_BUILTIN_KEYS)
    for p in cls.params + cls.options:
        if p not in used and p in MATERIAL_KEYS:
            MATERIAL_KEYS.remove(p)
    for f in _listeners:
        f()


def law_of(params) -> type[Law]:
    """The registered law class whose parameter NamedTuple is ``type(params)``."""
    for cls in MODELS.values():
        if type(params) is cls.params_type:
            return cls
    raise ValueError(
        f"{type(params).__name__} is not the parameter type of a registered law; "
        f"registered: {', '.join(c.params_type.__name__ for c in MODELS.values())}"
    )


def parameters() -> dict[str, Param]:
    """Every material parameter of the registered laws, by name (one declaration each)."""
    out = {}
    for cls in MODELS.values():
        for p in cls.params:
            out.setdefault(p.name, p)
    return out


def internal_labels() -> dict[str, str]:
    """Internal-variable name in the state -> its name in the result files (``lam`` -> ``lambda``)."""
    return {i.name: i.label for cls in MODELS.values() for i in cls.internals}


for _cls in (Newtonian, Bingham, HerschelBulkley, Coussot):
    register(_cls)
_BUILTIN = frozenset(MODELS)
_BUILTIN_KEYS = tuple(MATERIAL_KEYS)

# The thesis's BASE lab material as plain floats (pass to rheometer.make_params(**BASE_VALUES)).
BASE_VALUES = {
    **{p.name: p.default for p in Coussot.params if p.default is not None},
    "rho": BASE_DENSITY_KG_M3,
    "kappa": BASE_BULK_MODULUS_PA,
}
