"""The scene-key reference: docs/scenes.md's table, generated from ``SCHEMA``."""

from __future__ import annotations

import math

from .keys import _REQ, BODY_KEYS, BODY_TYPES
from .table import SCHEMA


def _body_rows():
    """The keys of a [[bodies]] table, as (bodies[].KEY, spec); required means: for the types that take it."""
    for sub, spec in BODY_KEYS.items():
        yield f"bodies[].{sub}", spec


def default_label(spec) -> str | None:
    """How a key's default reads where it is not a value: ``(required)``, ``(derived)`` (NaN: worked out from
    the scene) or ``(none)`` (None: the key is optional, or needed only where its doc says); None for a value
    (shown as its repr).  ``mpmjax scenes --keys`` prints it; the reference table (``schema_markdown``) too, but for
    a required key, which it words itself ("required", or which body types need it)."""
    if spec.default is _REQ:
        return "(required)"
    if isinstance(spec.default, float) and math.isnan(spec.default):
        return "(derived)"
    if spec.default is None:
        return "(none)"
    return None


def schema_markdown() -> str:
    """The scene-key reference as a Markdown table (docs/scenes.md is generated from it); the keys
    of a [[bodies]] table follow the ``bodies`` row as ``bodies[].KEY``."""
    rows = ["| key | unit | default | allowed | meaning |", "|---|---|---|---|---|"]
    items = []
    for key, spec in SCHEMA.items():
        items.append((key, spec))
        if key == "bodies":
            items.extend(_body_rows())
    for key, spec in items:
        label = default_label(spec)
        if spec.default is _REQ:
            default = "required" if not key.startswith("bodies[]") else _body_required(key[len("bodies[].") :])
        else:
            default = f"`{spec.default!r}`" if label is None else label
        if spec.choices:
            allowed = ", ".join(f"`{c}`" for c in spec.choices)
        else:
            parts = []
            if spec.lo is not None:
                parts.append(f"{'>' if spec.lo_open else '≥'} {spec.lo:g}")
            if spec.hi is not None:
                parts.append(f"≤ {spec.hi:g}")
            allowed = ", ".join(parts) or "-"
        rows.append(f"| `{key}` | {spec.unit} | {default} | {allowed} | {spec.doc} |")
    return "\n".join(rows)


def _body_required(sub: str) -> str:
    types = [t for t, (_, keys) in BODY_TYPES.items() if sub in keys]
    return f"required ({', '.join(types)})"
