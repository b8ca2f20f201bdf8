"""The package's layering, checked on the source (issue 16).

* Every module of ``mpmjax`` and ``calibration`` imports on its own, whatever is imported
  first (an import cycle shows up as an ImportError of a partly initialised module).
* The import graph (module-level and function-level imports, parsed with ``ast``) has no
  cycle among our modules.
* No library module imports the studies (``mpmjax.studies``: benchmarks and
  reproductions); only the command line (the package ``mpmjax.cli``) and the studies themselves do.
* The simulator does not import its client: no ``mpmjax`` module outside ``mpmjax.cli`` (and the
  studies) imports ``calibration``.
* Nothing imports the command line: no module outside ``mpmjax.cli`` (the library, the studies,
  ``calibration``) imports ``mpmjax.cli``.
* Only the command line parses options: ``argparse`` is imported by ``mpmjax.cli`` and by the
  two study scripts run as ``python -m mpmjax.studies.X`` (``STUDY_SCRIPTS``: measurements of
  their own, not ``mpmjax`` commands), by no other module of ``mpmjax`` or ``calibration``.
* ``calibration`` uses only the public ``mpmjax`` API: ``mpmjax`` itself and its public
  submodules (no ``mpmjax._private``).
* Imports inside functions are only the optional heavy ones (matplotlib, trimesh), each with a
  comment on its line or the line before saying why.
* No upward import between the library's layers (issue 34): the core (scenes, the step, I/O,
  metrics) imports neither the plots, the rheometer nor the run driver; the plots and the
  rheometer do not import the driver; the driver does not import the command line, the studies
  or the ``mpmjax`` package itself, which only re-export.
* The modules of a package split by concept (``mpmjax._driver``, ``mpmjax._schema``,
  ``mpmjax.plotting``, ``mpmjax.rheometer``, ``mpmjax.cli``) import each other and the layers below, never their
  own package (its ``__init__`` only re-exports them).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mpmjax", "calibration")
# imports allowed inside a function body: optional heavy modules loaded only when used
LAZY_OK = ("matplotlib", "trimesh")


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> list[str]:
    """Absolute module names a ``from ... import ...`` depends on."""
    if node.level:
        base = mod.split(".") if is_pkg else mod.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        target = ".".join(base + ([node.module] if node.module else []))
    else:
        target = node.module or ""
    subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
    # ``from . import _x`` depends on the submodule only (the parent package is always set up
    # first); a name defined in the package itself (``from . import __version__``) depends on it
    return subs + ([target] if len(subs) < len(node.names) else [])


def _imports(mod: str, path: Path):
    """(imported module, line, inside a function?) for every import of ``mod``."""
    tree = ast.parse(path.read_text(), str(path))
    is_pkg = path.name == "__init__.py"
    out = []

    def visit(node, in_fn):
        for child in ast.iter_child_nodes(node):
            fn = in_fn or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, in_fn) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                out.extend((name, child.lineno, in_fn) for name in _resolve(mod, is_pkg, child))
            visit(child, fn)

    visit(tree, False)
    return out


def _ours(name: str) -> str | None:
    """The module of ours that an imported name belongs to (longest match), else None."""
    parts = name.split(".")
    for k in range(len(parts), 0, -1):
        cand = ".".join(parts[:k])
        if cand in MODULES:
            return cand
    return None


GRAPH = {m: sorted({o for n, _, _ in _imports(m, p) if (o := _ours(n)) and o != m}) for m, p in MODULES.items()}


def _is_study(m: str) -> bool:
    return m == "mpmjax.studies" or m.startswith("mpmjax.studies.")


def _is_cli(m: str) -> bool:
    return m == "mpmjax.cli" or m.startswith("mpmjax.cli.")


# study modules that are scripts of their own (``python -m mpmjax.studies.X`` with its options)
STUDY_SCRIPTS = ("mpmjax.studies.fit_speed", "mpmjax.studies.hazard_cost")


def test_every_module_imports_on_its_own():
    # One interpreter (jax is imported once); our modules are dropped from sys.modules before each
    # import.  Importing ``a.b.c`` first imports its package ``a.b`` (and that ``a``), so where that
    # package's own import already loads ``a.b.c``, importing ``a.b.c`` alone runs exactly the
    # package's import: each package is imported alone once, and only the modules it does not load
    # are imported alone after it: 26 imports instead of 106, and the test's CPU 14-16 s instead of
    # 36-37 s (pytest's start included, alternating, 2026-12-07).
    code = (
        "import importlib, sys, traceback\n"
        f"mods = {sorted(MODULES)!r}\n"
        "done = {}\n"
        "def alone(name):\n"
        "    if name not in done:\n"
        "        for k in [k for k in sys.modules if k.split('.')[0] in ('mpmjax', 'calibration')]:\n"
        "            del sys.modules[k]\n"
        "        try:\n"
        "            importlib.import_module(name)\n"
        "            done[name] = None, set(sys.modules)\n"
        "        except Exception:\n"
        "            done[name] = traceback.format_exc(limit=3), set()\n"
        "    return done[name]\n"
        "bad = []\n"
        "for m in mods:\n"
        "    parent = m.rpartition('.')[0]\n"
        "    err, loaded = alone(parent) if parent else (None, set())\n"
        "    if m not in loaded and not err:\n"
        "        err = alone(m)[0]\n"
        "    if err:\n"
        "        bad.append(m + ': ' + err)\n"
        "print('\\n'.join(bad))\n"
        "print('imported alone:', len(done), 'of', len(mods), 'modules and packages', file=sys.stderr)\n"
        "sys.exit(1 if bad else 0)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr


def test_import_graph_has_no_cycle():
    state: dict[str, int] = {}
    stack: list[str] = []

    def dfs(m):
        state[m] = 1
        stack.append(m)
        for o in GRAPH[m]:
            if state.get(o) == 1:
                cyc = stack[stack.index(o) :] + [o]
                raise AssertionError("import cycle: " + " -> ".join(cyc))
            if o not in state:
                dfs(o)
        stack.pop()
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            dfs(m)


def test_library_does_not_import_studies_or_calibration():
    bad = []
    for m, deps in GRAPH.items():
        if not m.startswith("mpmjax") or _is_cli(m) or _is_study(m):
            continue
        bad += [f"{m} imports {o}" for o in deps if _is_study(o) or o.startswith("calibration")]
    assert not bad, bad


def test_nothing_imports_the_command_line():
    bad = [f"{m} imports {o}" for m, deps in GRAPH.items() if not _is_cli(m) for o in deps if _is_cli(o)]
    assert not bad, bad
    assert {"mpmjax.cli", "mpmjax.cli._commands", "mpmjax.cli._status"} <= set(MODULES)


def test_only_the_command_line_imports_argparse():
    bad = [
        f"{path.relative_to(ROOT)}:{line} imports {name}"
        for m, path in MODULES.items()
        if not _is_cli(m) and m not in STUDY_SCRIPTS
        for name, line, _ in _imports(m, path)
        if name.split(".")[0] == "argparse"
    ]
    assert not bad, bad


def test_calibration_uses_only_the_public_mpmjax_api():
    bad = []
    for m, path in MODULES.items():
        if not m.startswith("calibration"):
            continue
        for name, line, _ in _imports(m, path):
            if name.startswith("mpmjax") and any(p.startswith("_") for p in name.split(".")[1:]):
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    assert not bad, bad


def _has_reason(lines: list[str], i: int) -> bool:
    """A comment on line ``i`` or on the block of imports (and ``matplotlib.use``) it belongs to,
    or on the line just above that block."""
    while i >= 0:
        text = lines[i].strip()
        if "#" in text:
            return True
        if text and not text.startswith(("import ", "from ", "matplotlib.use(")):
            return False
        i -= 1
    return False


def test_imports_inside_functions_are_optional_heavy_ones_with_a_reason():
    bad = []
    for m, path in MODULES.items():
        lines = path.read_text().splitlines()
        for name, line, in_fn in _imports(m, path):
            if not in_fn:
                continue
            here = f"{path.relative_to(ROOT)}:{line} imports {name} inside a function"
            if name.split(".")[0] not in LAZY_OK:
                bad.append(here)
            elif not _has_reason(lines, line - 1):
                bad.append(here + " without a comment saying why")
    assert not bad, bad


# the library's layers, lowest first: a module may import its own layer and the ones below
SPLIT_PACKAGES = ("mpmjax._driver", "mpmjax._schema", "mpmjax.plotting", "mpmjax.rheometer", "mpmjax.cli")


def _in(m: str, pkg: str) -> bool:
    return m == pkg or m.startswith(pkg + ".")


def _layer(m: str) -> int | None:
    """0 the core, 1 the plots and the rheometer, 2 the run driver, 3 the package's re-exports,
    the command line and the studies; None for ``calibration`` (a client, checked above)."""
    if m == "mpmjax" or _is_cli(m) or _is_study(m):
        return 3
    if _in(m, "mpmjax._driver"):
        return 2
    if _in(m, "mpmjax.plotting") or _in(m, "mpmjax.rheometer"):
        return 1
    return 0 if _in(m, "mpmjax") else None


def test_the_layers_are_what_the_packages_are():
    assert {m for m in MODULES if _layer(m) == 2} >= {"mpmjax._driver", "mpmjax._driver.run", "mpmjax._driver.loop"}
    assert {m for m in MODULES if _layer(m) == 1} >= {"mpmjax.plotting", "mpmjax.plotting._report", "mpmjax.rheometer"}
    assert _layer("mpmjax._step") == 0 and _layer("mpmjax.studies.stress") == 3 and _layer("calibration.fit") is None
    assert _layer("mpmjax.cli") == _layer("mpmjax.cli._status") == 3


def test_no_upward_import_between_layers():
    bad = [
        f"{m} (layer {_layer(m)}) imports {o} (layer {_layer(o)})"
        for m, deps in GRAPH.items()
        if _layer(m) is not None
        for o in deps
        if _layer(o) is not None and _layer(o) > _layer(m)
    ]
    assert not bad, bad


def test_split_packages_import_their_modules_not_themselves():
    bad = [
        f"{m} imports {pkg}"
        for pkg in SPLIT_PACKAGES
        for m, deps in GRAPH.items()
        if m.startswith(pkg + ".") and pkg in deps
    ]
    assert not bad, bad
    for pkg in SPLIT_PACKAGES:  # a package, not a module: the split is still there
        assert any(m.startswith(pkg + ".") for m in MODULES), pkg
