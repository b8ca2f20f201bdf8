"""Scene keys: the schema, validation, TOML loading and ``--set`` overrides.

A scene file is a TOML document whose keys are listed in ``SCHEMA`` (each with its
unit, default, allowed range and meaning; ``mpmjax scenes --keys`` prints them and
docs/scenes.md is generated from them by ``schema_markdown``).  The ``material.*`` keys
are not listed here: each rheology law declares its own (``_rheology.Param`` /
``_rheology.Option``), and ``SCHEMA`` is rebuilt from those declarations whenever a law
is registered.  ``load_scene(name_or_path, overrides)`` returns a validated flat dict;
``_build.build(cfg)`` turns it into a run.

Errors are ``SceneError`` (a ``ValueError``) naming the key, the value and the
allowed range.

One module a concept: ``keys`` (the ``Key`` spec, ``SceneError`` and the fixed keys), ``table``
(the live ``SCHEMA`` table, rebuilt in place when a law is registered), ``validate`` (the checks
of one value and of the scene as a whole), ``load`` (TOML files, the built-in scenes and
``--set`` overrides) and ``reference`` (the docs/scenes.md table).
"""

from .keys import _REQ, Key, SceneError
from .load import _drop_switched_law_keys, builtin_scenes, load_scene, parse_override
from .reference import schema_markdown
from .table import SCHEMA, SECTIONS, register_law, unregister_law
from .validate import _NAN_DEFAULT, validate

__all__ = [
    "SCHEMA",
    "SECTIONS",
    "_NAN_DEFAULT",
    "_REQ",
    "Key",
    "SceneError",
    "_drop_switched_law_keys",
    "builtin_scenes",
    "load_scene",
    "parse_override",
    "register_law",
    "schema_markdown",
    "unregister_law",
    "validate",
]
