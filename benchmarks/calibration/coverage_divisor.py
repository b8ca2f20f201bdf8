"""Would a Richardson divisor on the numerical std keep the coverage?  Recomputed from the raw coverage studies.

Issue 32 item 2 allows, with the order the validation benchmarks measure, Richardson's estimate of the fine
level's error: for an error of order p in h, the shift between levels h and h/2 is (2^p - 1) times the fine
level's own error, so ``std_numerical / (2^p - 1)``.  The joint-experiment studies keep every twin's statistical
and numerical std, fit and truth, so the coverage each divisor would give is a recomputation, not a new fit:
the total std is sqrt(std_statistical^2 + (std_numerical / D)^2), as ``calibration.uncertainty`` combines them.

    .venv/bin/python benchmarks/calibration/coverage_divisor.py            # prints the table, writes the JSON

Inputs: ``coverage_joint_seed0.json`` and ``..._seed1.json`` (data on the fine level's own grid, h/2; pooled,
20 twins) and ``coverage_joint_seed0_data4.json`` (the same ten truths of seed 0, data on h/4: the fine level
then has a resolution error of its own, so only these test what the numerical std is for).
Output: ``coverage_divisor.json`` beside this script.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
NAMES = ("mu0", "alpha", "T", "n", "lambda0")
# p = 1, log2(3), 2, and 2.84: the order of the explicit lab scene's runout at h = 2 / 1 / 0.5 cm
# (1.189 / 1.282 / 1.295 m, docs/incompressible-default.md), the suite's measured order nearest to these fits' model
ORDERS = (1.0, math.log2(3.0), 2.0, math.log2(0.093 / 0.013))
STUDIES = {
    "data at h/2 (seeds 0 and 1, 20 twins)": ("coverage_joint_seed0.json", "coverage_joint_seed1.json"),
    "data at h/4 (seed 0, 10 twins)": ("coverage_joint_seed0_data4.json",),
}


def _twins(files):
    rows = []
    for f in files:
        rows += [t for t in json.loads((HERE / f).read_text())["twins"] if t.get("error") is None]
    return rows


def divided(rows, divisor: float) -> dict:
    """Per parameter: 1 and 2 sigma coverage and the median relative total std with the numerical std / divisor."""
    out = {}
    for k in NAMES:
        z, rel = [], []
        for t in rows:
            std = math.hypot(t["std_statistical"][k], t["std_numerical"][k] / divisor)
            z.append(abs(t["fit"][k] - t["truth"][k]) / std)
            rel.append(std / abs(t["fit"][k]))
        out[k] = {
            "cover_1sigma": float(np.mean(np.asarray(z) <= 1.0)),
            "cover_2sigma": float(np.mean(np.asarray(z) <= 2.0)),
            "median_rel_std": float(np.median(rel)),
        }
    return out


def shift_over_error(rows) -> dict:
    """Per parameter: quantiles (0, 25, 50, 75, 100 %) of the fixed-parameter shift over the actual error."""
    out = {}
    for k in NAMES:
        r = [t["std_numerical"][k] / abs(t["fit"][k] - t["truth"][k]) for t in rows if t["fit"][k] != t["truth"][k]]
        out[k] = [float(q) for q in np.quantile(r, [0.0, 0.25, 0.5, 0.75, 1.0])]
    return out


def main() -> None:
    doc = {"orders": {}, "shift_over_error": {}}
    for p in ORDERS:
        d = 2.0**p - 1.0
        doc["orders"][f"{p:.3f}"] = {"divisor": d, **{s: divided(_twins(f), d) for s, f in STUDIES.items()}}
    for s, f in STUDIES.items():
        doc["shift_over_error"][s] = shift_over_error(_twins(f))
    doc["definition"] = __doc__.strip().splitlines()[0]
    (HERE / "coverage_divisor.json").write_text(json.dumps(doc, indent=1) + "\n")
    for p, row in doc["orders"].items():
        print(f"p = {p} (divisor {row['divisor']:.2f})")
        for s in STUDIES:
            cells = [
                f"{k} {100 * v['cover_1sigma']:.0f}/{100 * v['cover_2sigma']:.0f} % ({100 * v['median_rel_std']:.1f} %)"
                for k, v in row[s].items()
            ]
            print(f"  {s}: " + "; ".join(cells))
    print("shift / |error|, quantiles min, 25, 50, 75 %, max (a ratio):")
    for s, q in doc["shift_over_error"].items():
        print(f"  {s}: " + "; ".join(f"{k} " + " ".join(f"{v:.2g}" for v in qs) for k, qs in q.items()))


if __name__ == "__main__":
    main()
