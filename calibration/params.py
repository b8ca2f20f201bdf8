"""Parameter specifications: which material parameters are fitted, their bounds and transforms.

The optimiser works on an unconstrained vector z; each fitted parameter theta is a smooth
function of its z that keeps it inside its bounds (u below; z = (u - u(init)) / k is u
centred at the initial value and scaled so that a unit step in z is, near the start, a
change of ln theta by 1 for ``log`` and of theta by max(|init|, 1e-3 of the range) for the
others: step sizes then mean relative changes for every parameter):

===========  ==========================================  ===============================
transform    theta(u)                                    bounds
===========  ==========================================  ===============================
``log``      exp(a + (b - a) sigmoid(u)), a = ln lo,     0 < lo < hi (both, or neither:
             b = ln hi; without bounds exp(u)            then theta = exp(u) > 0)
``softplus`` lo + softplus(u)                            lower bound lo only (default 0)
``linear``   lo + (hi - lo) sigmoid(u)                   both
``identity`` u                                           none
===========  ==========================================  ===============================

``log`` is the default: rheological parameters span decades and are positive, and equal
steps in z are equal *relative* changes in theta.  A fixed parameter keeps its value and
is not part of z.

Parameter names are the fields of the scene's material NamedTuple (``mpmjax``'s
``CoussotParams``: mu0, alpha, T, n, lambda0, mu_max, rho, kappa; ``BinghamParams``: mu,
tau_y, alpha_b, m; ``HerschelBulkleyParams``: tau_y, K, n_hb, m, mu_max;
``NewtonianParams``: mu; or any registered law's) and, for a depth-averaged scene on a
``coulomb`` or ``voellmy`` terrain, its basal friction (``friction``, ``turbulence``:
``mpmjax.basal_parameters()``).  :data:`DEFAULT_BOUNDS` gives bounds that
contain every value in the thesis and the literature it cites, with margin; a value outside
its bounds is an error, not a silent clip.  Bounds, units and scene keys are read from the
parameters' declarations (``mpmjax.fit_parameters()``), not listed here.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import jax
import jax.numpy as jnp

import mpmjax

__all__ = ["DEFAULT_BOUNDS", "SCENE_KEYS", "UNITS", "ParamSpec", "ParameterSet", "check_names"]

TRANSFORMS = ("log", "softplus", "linear", "identity")

class _Declared(Mapping):
    """name -> one field of each parameter's declaration (``mpmjax.fit_parameters()``: the law's
    ``Param``, or the basal friction's), read live, so a law registered later is included.
    Parameters whose field is None (no calibration bounds) are left out."""

    def __init__(self, field: str):
        self._field = field

    def _table(self) -> dict:
        out = {}
        for name, p in mpmjax.fit_parameters().items():
            v = getattr(p, self._field)
            if v is not None:
                out[name] = v
        return out

    def __getitem__(self, name):
        return self._table()[name]

    def __iter__(self):
        return iter(self._table())

    def __len__(self):
        return len(self._table())

    def __repr__(self):
        return f"{type(self).__name__}({self._field!r}: {self._table()!r})"


# name -> (lo, hi) [SI]: wide, physically plausible ranges (thesis values lie well inside), declared
# with each parameter (``mpmjax.Param.bounds``)
DEFAULT_BOUNDS = _Declared("bounds")
# name -> SI unit (``mpmjax.Param.unit``)
UNITS = _Declared("unit")
# name -> scene key (``mpmjax.Param.key``)
SCENE_KEYS = _Declared("key")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ``name`` (material field), ``init`` (starting value, SI), bounds
    ``lo``/``hi`` (SI; None = unbounded on that side), ``transform`` (see the module
    table) and ``fixed`` (held at ``init``)."""

    name: str
    init: float
    lo: float | None = None
    hi: float | None = None
    transform: str = "log"
    fixed: bool = False

    def __post_init__(self):
        n, t, lo, hi, x = self.name, self.transform, self.lo, self.hi, self.init
        if t not in TRANSFORMS:
            raise ValueError(f"{n}: transform = {t!r} is invalid; allowed: {', '.join(TRANSFORMS)}")
        for k, v in (("init", x), ("lo", lo), ("hi", hi)):
            if v is not None and not math.isfinite(v):
                raise ValueError(f"{n}: {k} = {v!r}; allowed: a finite number")
        if t == "log":
            if (lo is None) != (hi is None):
                raise ValueError(f"{n}: the log transform takes both bounds or neither; got lo = {lo}, hi = {hi}")
            if lo is not None and not (0 < lo < hi):
                raise ValueError(f"{n}: log bounds need 0 < lo < hi; got lo = {lo:g}, hi = {hi:g}")
            if x <= 0:
                raise ValueError(f"{n}: init = {x:g} [{UNITS.get(n, 'SI')}]; the log transform needs a value > 0")
        if t == "softplus" and hi is not None:
            raise ValueError(f"{n}: the softplus transform takes a lower bound only; got hi = {hi:g}")
        if t == "linear" and (lo is None or hi is None or not lo < hi):
            raise ValueError(f"{n}: the linear transform needs lo < hi; got lo = {lo}, hi = {hi}")
        if t == "identity" and (lo is not None or hi is not None):
            raise ValueError(f"{n}: the identity transform is unbounded; got lo = {lo}, hi = {hi}")
        lo_eff = 0.0 if (t == "softplus" and lo is None) else lo
        if lo_eff is not None and x <= lo_eff and not self.fixed:
            top = "inf" if hi is None else f"{hi:g}"
            unit = UNITS.get(n, "SI")
            raise ValueError(f"{n}: init = {x:g} [{unit}] is outside the allowed range ({lo_eff:g}, {top})")
        if hi is not None and x >= hi and not self.fixed:
            raise ValueError(f"{n}: init = {x:g} [{UNITS.get(n, 'SI')}] is outside the allowed range ({lo:g}, {hi:g})")

    # theta <-> z ------------------------------------------------------------------------
    # The optimiser's variable z is centred and scaled at the initial value: z = 0 is
    # ``init`` and dz ~ d(ln theta) there (log: exactly; other transforms: the change of
    # theta in units of max(|init|, 1e-3 of the range)), so that step sizes (Adam's
    # learning rate, L-BFGS's first step) mean relative changes for every parameter.
    def _raw(self, u):
        t, lo, hi = self.transform, self.lo, self.hi
        if t == "log":
            if lo is None:
                return jnp.exp(u)
            a, b = math.log(lo), math.log(hi)
            return jnp.exp(a + (b - a) * jax.nn.sigmoid(u))
        if t == "softplus":
            return (0.0 if lo is None else lo) + jax.nn.softplus(u)
        if t == "linear":
            return lo + (hi - lo) * jax.nn.sigmoid(u)
        return u

    def _raw_inv(self, theta: float) -> float:
        t, lo, hi = self.transform, self.lo, self.hi
        if t == "log":
            if lo is None:
                return math.log(theta)
            a, b = math.log(lo), math.log(hi)
            s = (math.log(theta) - a) / (b - a)
            return math.log(s / (1.0 - s))
        if t == "softplus":
            y = theta - (0.0 if lo is None else lo)
            return y + math.log(-math.expm1(-y))  # inverse softplus, stable
        if t == "linear":
            s = (theta - lo) / (hi - lo)
            return math.log(s / (1.0 - s))
        return float(theta)

    def _centre_scale(self):
        """(u0, k): u = u0 + k z, with dtheta/dz at z = 0 equal to theta0 (log) or the
        scale max(|theta0|, 1e-3 range)."""
        x, t, lo, hi = self.init, self.transform, self.lo, self.hi
        u0 = self._raw_inv(x) if not self.fixed else 0.0
        if t == "log":
            if lo is None:
                return u0, 1.0
            sg = 1.0 / (1.0 + math.exp(-u0))
            return u0, 1.0 / ((math.log(hi) - math.log(lo)) * sg * (1.0 - sg))
        if t == "softplus":
            sg = 1.0 / (1.0 + math.exp(-u0))
            return u0, max(abs(x), 1e-12) / sg
        if t == "linear":
            sg = 1.0 / (1.0 + math.exp(-u0))
            return u0, max(abs(x), 1e-3 * (hi - lo)) / ((hi - lo) * sg * (1.0 - sg))
        return u0, max(abs(x), 1.0)

    def to_theta(self, z):
        u0, k = self._centre_scale()
        return self._raw(u0 + k * z)

    def to_z(self, theta: float) -> float:
        u0, k = self._centre_scale()
        return (self._raw_inv(theta) - u0) / k


def _names(base) -> tuple:
    """The parameter names ``base`` carries: a ``mpmjax.Params`` (material and basal) or a material NamedTuple."""
    return tuple(mpmjax.fit_parameters(base)) if isinstance(base, mpmjax.Params) else type(base)._fields


def _value(base, name):
    return mpmjax.parameter_value(base, name) if isinstance(base, mpmjax.Params) else getattr(base, name)


def _not_carried(name, base) -> ValueError:
    what = type(base.material if isinstance(base, mpmjax.Params) else base).__name__
    if isinstance(base, mpmjax.Params) and base.basal is not None:
        what += " or its basal friction"
    hint = ""
    if name in mpmjax.basal_parameters() and not (isinstance(base, mpmjax.Params) and base.basal is not None):
        hint = " (friction and turbulence belong to a depth-averaged scene whose terrain.type is coulomb or voellmy)"
    return ValueError(
        f"parameter {name!r} is not a field of the scene's material {what}; allowed: {', '.join(_names(base))}{hint}"
    )


def check_names(names, params, option: str, cfg=None) -> None:
    """ValueError naming ``option`` (e.g. ``--fit``) for the first of ``names`` that ``params`` (the
    scene's ``mpmjax.Params``, e.g. ``mpmjax.make_params(cfg)``: no scene is built) does not carry,
    or, given the scene's ``cfg``, that its step does not read (``mpmjax.unused_parameters``: a fit of
    it would meet a flat loss)."""
    unused = {} if cfg is None else mpmjax.unused_parameters(cfg)
    for n in names:
        if n not in _names(params):
            raise ValueError(f"{option} {n}: {_not_carried(n, params)}")
        if n in unused:
            raise ValueError(f"{option} {n}: not used by scene {cfg['name']!r}: {unused[n]}")


class ParameterSet:
    """The fitted and fixed parameters of a calibration, mapped onto the scene's parameters.

    ``specs``: ParamSpecs (fixed ones included); ``material``: the scene's ``mpmjax.Params``
    (``setup.params``: material and basal friction can be named) or its material NamedTuple
    (``setup.params.material``), whose other fields stay as they are.
    ``free``: names of the fitted parameters, in order (the order of z and of the
    uncertainty outputs).
    """

    def __init__(self, specs, material):
        self.specs = {s.name: s for s in specs}
        fields = _names(material)
        for s in specs:
            if s.name not in fields:
                raise _not_carried(s.name, material)
        if len(self.specs) != len(specs):
            raise ValueError(f"a parameter is named twice in {[s.name for s in specs]}")
        self.material = material
        self.free = tuple(s.name for s in specs if not s.fixed)
        if not self.free:
            raise ValueError("no parameter to fit: every parameter is fixed")

    @classmethod
    def from_names(cls, fit, material, init=None, bounds=None, transforms=None, fixed=()):
        """Specs for the names in ``fit`` with default bounds (:data:`DEFAULT_BOUNDS`) and
        the log transform, starting at ``init[name]`` or the material's current value."""
        init, bounds, transforms = dict(init or {}), dict(bounds or {}), dict(transforms or {})
        # an initial value for a parameter that is not fitted fixes it at that value
        fixed = tuple(fixed) + tuple(k for k in init if k not in fit and k not in fixed)
        specs = []
        for name in list(fit) + [f for f in fixed if f not in fit]:
            if name not in _names(material):
                raise _not_carried(name, material)
            x0 = float(init.get(name, _value(material, name)))
            tr = transforms.get(name, "log")
            lo, hi = bounds.get(
                name, DEFAULT_BOUNDS.get(name, (None, None)) if tr in ("log", "linear") else (None, None)
            )
            specs.append(ParamSpec(name, x0, lo, hi, tr, fixed=name in fixed))
        return cls(specs, material)

    def z0(self, dtype=jnp.float64):
        return jnp.asarray([self.specs[k].to_z(self.specs[k].init) for k in self.free], dtype)

    def theta(self, z):
        """Dict name -> physical value (traced) of the free parameters."""
        return {k: self.specs[k].to_theta(z[i]) for i, k in enumerate(self.free)}

    def theta_vector(self, z):
        return jnp.stack([self.specs[k].to_theta(z[i]) for i, k in enumerate(self.free)])

    def z_of_theta(self, theta, dtype=jnp.float64):
        return jnp.asarray([self.specs[k].to_z(float(theta[k])) for k in self.free], dtype)

    def values(self, theta: dict) -> dict:
        """Name -> value of every specified parameter: ``theta`` for the free ones (traced)
        and ``init`` for the fixed ones."""
        return {**{k: s.init for k, s in self.specs.items() if s.fixed}, **theta}

    def material_of(self, theta: dict, base=None):
        """``base`` (default: the set's ``material``, a material NamedTuple or a ``mpmjax.Params``)
        with the free parameters set to ``theta`` and the fixed ones to their ``init``; the same kind
        as ``base``."""
        base = self.material if base is None else base
        if isinstance(base, mpmjax.Params):
            return mpmjax.replace_parameters(base, self.values(theta), jnp.result_type(base.material[0]))
        dt = jnp.result_type(base[0])
        return base._replace(**{k: jnp.asarray(v, dt) for k, v in self.values(theta).items()})

    def bounds_table(self):
        return {
            k: {
                "init": s.init,
                "lo": s.lo,
                "hi": s.hi,
                "transform": s.transform,
                "fixed": s.fixed,
                "unit": UNITS.get(k, "SI"),
            }
            for k, s in self.specs.items()
        }
