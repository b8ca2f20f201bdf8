"""The scene-key reference: docs/scenes.md's table, generated from ``SCHEMA``."""

from __future__ import annotations

import math

from .keys import _REQ
from .table import SCHEMA


def schema_markdown() -> str:
    """The scene-key reference as a Markdown table (docs/scenes.md is generated from it)."""
    rows = ["| key | unit | default | allowed | meaning |", "|---|---|---|---|---|"]
    for key, spec in SCHEMA.items():
        if spec.default is _REQ:
            default = "required"
        elif isinstance(spec.default, float) and math.isnan(spec.default):
            default = "(derived)"
        else:
            default = f"`{spec.default!r}`" if spec.default is not None else "(none)"
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
