"""The live ``SCHEMA`` table: the fixed keys (``keys``) with the material keys of every
registered rheology law between them.

``SCHEMA`` and ``SECTIONS`` are module-level objects that the rest of the package (and its users)
import once, so they are refilled in place, never rebound: ``_rebuild_schema`` runs once at import and
again from the rheology registry's listener list (``_rheology._listeners``) whenever a law is
registered or removed, which is how ``register_law`` adds a law's keys.  This is the one place
that changes them.
"""

from __future__ import annotations

from .. import _rheology
from .keys import _HEAD, _REQ, _TAIL, Key


def _material_key(decl) -> Key:
    """The schema entry of a law's ``Param`` or ``Option``."""
    if isinstance(decl, _rheology.Option):
        return Key(str, decl.default, "-", decl.doc, choices=decl.choices)
    default = (None if decl.optional else _REQ) if decl.default is None else decl.default
    return Key(float, default, decl.unit, decl.doc, lo=decl.lo, lo_open=decl.lo_open, hi=decl.hi)


SCHEMA: dict[str, Key] = {}
SECTIONS: set[str] = set()


def _rebuild_schema() -> None:
    """Refill ``SCHEMA`` (in place) from the fixed keys and the registered laws' declarations."""
    SCHEMA.clear()
    SCHEMA.update(_HEAD)
    SCHEMA["material.model"] = Key(str, "newtonian", "-", "Rheology.", choices=tuple(_rheology.MODELS))
    SCHEMA.update({d.key: _material_key(d) for d in _rheology.MATERIAL_KEYS})
    SCHEMA.update(_TAIL)
    SECTIONS.clear()
    SECTIONS.update(k.split(".")[0] for k in SCHEMA if "." in k)


_rebuild_schema()
# the rheology registry calls its listeners after every register / unregister
_rheology._listeners.append(_rebuild_schema)


def register_law(cls):
    """Register a rheology law (a ``_rheology.Law`` subclass): ``material.model = cls.name``
    becomes valid and its parameters and options become scene keys.  Returns ``cls``."""
    return _rheology.register(cls)


def unregister_law(name: str) -> None:
    """Remove a law added by ``register_law`` and the scene keys only it declared."""
    _rheology.unregister(name)
