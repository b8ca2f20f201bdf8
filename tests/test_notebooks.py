"""Notebooks run top to bottom at a small size (MPMJAX_NOTEBOOK_SMALL=1).

Code cells are executed in one namespace, in order, without a Jupyter kernel; each notebook
prints or computes physical numbers that are checked here."""

import json
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
ROOT = Path(__file__).resolve().parents[1]


def _run(path, monkeypatch):
    monkeypatch.setenv("MPMJAX_NOTEBOOK_SMALL", "1")
    nb = json.loads(path.read_text())
    ns = {}
    for cell in nb["cells"]:
        if cell["cell_type"] == "code":
            exec(compile("".join(cell["source"]), f"{path.name}", "exec"), ns)
    return ns


def test_dambreak_notebook(monkeypatch):
    ns = _run(ROOT / "notebooks" / "dambreak.ipynb", monkeypatch)
    front = ns["front"]
    # after 1 s the 0.2 m block has collapsed: the front is past its initial 0.2 m edge but
    # cannot exceed the free-fall bound 0.2 + 1 s * sqrt(2 g 0.2) = 2.2 m (and the 2 m box)
    assert 0.3 < front[-1] < 2.0
    assert int(ns["final"].n_lost) == 0
    # a lower minimum viscosity cannot shorten the runout: d front / d mu0 <= 0 and finite
    g = float(ns["grad"])
    assert math.isfinite(g) and g < 0
