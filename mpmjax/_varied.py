"""The traced parameters that a fit or a sweep can vary, by name: the law's material parameters
(``Params.material``) and, for a depth-averaged scene on a ``coulomb`` or ``voellmy`` terrain, the
basal friction (``Params.basal``: ``friction``, ``turbulence``).

The basal parameters are declared here once, as the laws declare theirs (``_rheology.Param``): the
scene key, with its unit and description read from the schema, and calibration's default search
range.  ``calibrate``, ``sweep`` and a fit in Python name either kind the same way, e.g.
``--fit tau_y,friction`` or ``--vary turbulence=100,200,400``.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from . import _rheology
from ._schema import SCHEMA

__all__ = ["basal_parameters", "fit_parameters", "parameter_value", "replace_parameters", "unused_parameters"]


def _basal(name: str, key: str, bounds: tuple[float, float]) -> _rheology.Param:
    k = SCHEMA[key]
    return _rheology.Param(
        name, key, k.unit, k.doc, default=k.default, lo=k.lo, lo_open=k.lo_open, hi=k.hi, bounds=bounds
    )


def basal_parameters() -> dict[str, _rheology.Param]:
    """``Basal``'s fields (``_scene.Basal``) as parameter declarations: the Coulomb coefficient μ
    (default search range 0.01 .. 1.5, friction angles 0.6° to 56°) and Voellmy's ξ [m/s²] (10 ..
    1e5: RAMMS and DAN3D back-analyses of debris flows and tailings breaches report 100 to a few
    thousand)."""
    return {
        "friction": _basal("friction", "terrain.friction", (0.01, 1.5)),
        "turbulence": _basal("turbulence", "terrain.turbulence_m_s2", (10.0, 1e5)),
    }


def fit_parameters(params=None, cfg=None) -> dict[str, _rheology.Param]:
    """Name -> declaration of the parameters that can be fitted or varied: with ``params`` (a
    ``Params``), those it carries (its law's material fields, and the basal ones where it has a
    ``Basal``); without, those of every registered law and the basal ones.  With ``cfg`` (the
    scene's loaded configuration), less those its step does not read (``unused_parameters``)."""
    if params is None:
        out = {**_rheology.parameters(), **basal_parameters()}
    else:
        declared = _rheology.parameters()
        out = {f: declared.get(f) for f in type(params.material)._fields}
        if params.basal is not None:
            basal = basal_parameters()
            out.update({f: basal[f] for f in type(params.basal)._fields if not _absent(getattr(params.basal, f))})
    if cfg is not None:
        for name in unused_parameters(cfg):
            out.pop(name, None)
        phi = cfg.get("model.internal_friction_deg")
        if phi is not None and out.get("friction") is not None:
            # the bed cannot be rougher than the material (the scene refuses it), and Savage & Hutter's k has an
            # infinite derivative in the friction there: a fit or sweep stays at or below tan(phi)
            top = math.tan(math.radians(phi))
            f = out["friction"]
            bounds = (min(f.bounds[0], 0.5 * top), min(f.bounds[1], top))
            out["friction"] = dataclasses.replace(f, hi=top, bounds=bounds)
    return out


def unused_parameters(cfg) -> dict[str, str]:
    """Name -> why, for the parameters a scene carries but its step does not read, so that fitting or
    varying one would change nothing (a flat loss, identical cases): the bulk modulus ``kappa`` where
    the pressure is solved on the grid (``numerics.pressure = "incompressible"``) or the flow is
    depth-averaged (``model.formulation``)."""
    return _rheology.unused_parameters(cfg)


def _absent(value) -> bool:
    """A basal coefficient the terrain does not have: Voellmy's xi on a coulomb terrain is inf."""
    try:
        return bool(np.isinf(np.asarray(value)).all())
    except jax.errors.TracerArrayConversionError:  # traced: present
        return False


def _unknown(params, names) -> ValueError:
    allowed = ", ".join(fit_parameters(params))
    where = type(params.material).__name__ + (" and the basal friction" if params.basal is not None else "")
    return ValueError(
        f"{', '.join(map(repr, names))}: not a parameter of this scene's {where}; allowed: {allowed}"
        + ("" if params.basal is not None else " (friction and turbulence exist on a depth-averaged scene whose "
           "terrain.type is coulomb or voellmy)")
    )


def replace_parameters(params, values: dict, dtype=None):
    """``params`` with the named parameters set to ``values`` (material and basal fields alike);
    each value is cast to ``dtype`` where one is given (traced values stay traced).  A name that
    ``params`` does not carry is a ValueError naming the allowed ones."""
    mat_f = type(params.material)._fields
    bas_f = () if params.basal is None else type(params.basal)._fields
    bad = [k for k in values if k not in mat_f and k not in bas_f]
    if bad:
        raise _unknown(params, bad)

    def cast(v):
        return v if dtype is None else jnp.asarray(v, dtype)

    mat = {k: cast(v) for k, v in values.items() if k in mat_f}
    bas = {k: cast(v) for k, v in values.items() if k in bas_f}
    out = params._replace(material=params.material._replace(**mat)) if mat else params
    return out._replace(basal=out.basal._replace(**bas)) if bas else out


def parameter_value(params, name: str):
    """The value of the named parameter in ``params`` (material or basal)."""
    if name in type(params.material)._fields:
        return getattr(params.material, name)
    if params.basal is not None and name in type(params.basal)._fields:
        return getattr(params.basal, name)
    raise _unknown(params, [name])
