"""Loading a scene: a built-in scene or a TOML file, ``--set key=value`` overrides, then
``validate``."""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from .. import _rheology
from .keys import SceneError
from .table import SCHEMA
from .validate import _law_keys, validate


def builtin_scenes() -> dict[str, Path]:
    """Built-in scene names -> paths of the TOML files shipped inside the package."""
    root = resources.files("mpmjax") / "scenes"
    return {Path(str(p)).stem: Path(str(p)) for p in root.iterdir() if str(p).endswith(".toml")}


def parse_override(text: str) -> tuple[str, Any]:
    """``key=value`` with a TOML value (numbers, strings, lists); bare words become strings."""
    if "=" not in text:
        raise SceneError(f"--set {text!r}: expected key=value, e.g. material.mu0_pa_s=2.0")
    key, raw = text.split("=", 1)
    key = key.strip()
    try:
        val = tomllib.loads(f"v = {raw.strip()}")["v"]
    except (ValueError, RecursionError, KeyError):  # TOMLDecodeError, integer too long, deep nesting
        val = raw.strip()
    return key, val


def load_scene(name_or_path: str | Path, overrides: list[str] | dict | None = None) -> dict:
    """Read a built-in scene by name, or a TOML file by path, apply ``key=value``
    overrides and validate.  Returns the flat validated dict."""
    scenes = builtin_scenes()
    name = str(name_or_path)
    if name in scenes:
        path = scenes[name]
    else:
        path = Path(name)
        if not path.is_file():
            raise SceneError(
                f"scene {name!r} is neither a built-in scene ({', '.join(sorted(scenes))}) nor a TOML file"
            )
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise SceneError(f"{path}: not a UTF-8 text file (TOML must be UTF-8): {e}") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot be read: {e}") from None
    try:
        raw = tomllib.loads(text)
    except (ValueError, RecursionError) as e:  # TOMLDecodeError; ValueError: integer too long; deep nesting
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    items = overrides.items() if isinstance(overrides, dict) else [parse_override(o) for o in (overrides or [])]
    items = list(items)
    file_mat = raw.get("material") if isinstance(raw.get("material"), dict) else {}
    file_model = file_mat.get("model", SCHEMA["material.model"].default)
    for key, val in items:
        if key not in SCHEMA:
            raise SceneError(f"--set {key}: unknown key. Known keys: see `mpmjax scenes --keys` or docs/scenes.md")
        node = raw
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise SceneError(f"--set {key}: {p} is not a table in {path}")
        node[parts[-1]] = val
    _drop_switched_law_keys(raw, file_model, file_mat, {k for k, _ in items})
    ter = raw.get("terrain")
    for k in ("csv", "dem"):
        if isinstance(ter, dict) and isinstance(ter.get(k), str) and ter[k]:
            if "\x00" in ter[k]:
                raise SceneError(f"terrain.{k} = {ter[k]!r}: a file path cannot contain a NUL character")
            ter[k] = str((path.parent / ter[k]).resolve()) if not Path(ter[k]).is_absolute() else ter[k]
    bodies = raw.get("bodies")
    for b in bodies if isinstance(bodies, list) else []:  # mesh files, like the terrain's
        if isinstance(b, dict) and isinstance(b.get("file"), str) and b["file"] and "\x00" not in b["file"]:
            b["file"] = str((path.parent / b["file"]).resolve()) if not Path(b["file"]).is_absolute() else b["file"]
    return validate(raw)


def _drop_switched_law_keys(raw: dict, file_model, file_keys: dict, set_keys: set) -> None:
    """``--set material.model=OTHER`` switches a scene file's law: the file's keys of its own
    law that the new law does not read are dropped (they described the old law; the validated
    scene then holds the defaults there).  Keys the file's own law never read are still
    refused, as are ``--set`` keys the new law does not read."""
    mat = raw.get("material")
    if "material.model" not in set_keys or not isinstance(mat, dict):
        return
    new_model = mat.get("model")
    if not (isinstance(new_model, str) and isinstance(file_model, str)) or new_model == file_model:
        return
    if new_model not in _rheology.MODELS or file_model not in _rheology.MODELS:
        return
    old_keys = _law_keys(_rheology.MODELS[file_model])
    new_keys = _law_keys(_rheology.MODELS[new_model])
    for k in list(file_keys):
        key = f"material.{k}"
        if key in old_keys and key not in new_keys and key not in set_keys:
            mat.pop(k, None)
