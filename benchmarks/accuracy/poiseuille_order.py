"""The no-slip wall's order: plane Poiseuille and the Bingham plug (`mpmjax validate`'s cases,
mpmjax/studies/validate.py) at 10 / 20 / 40 cells across the gap and cfl 0.4 / 0.1, one JSON line
each: max |u - u_exact| / u_max in per cent, steps, loop CPU (docs/incompressible.md, "The bed").

    .venv/bin/python benchmarks/accuracy/poiseuille_order.py incompressible lag
    .venv/bin/python benchmarks/accuracy/poiseuille_order.py explicit jaumann
"""

import json
import sys

import mpmjax.studies.validate as V

pressure, rotation = sys.argv[1], sys.argv[2]
for bingham in (False, True):
    for cells in (10, 20, 40):
        for cfl in (0.4, 0.1):
            V.POIS_SIZE["full"]["cells"] = cells
            base = {"numerics.pressure": pressure, "numerics.maxwell_rotation": rotation, "numerics.cfl": cfl}
            _, run = V._poiseuille(bingham)
            rec = {"tolerance": 0.01}
            run("full", base, rec)
            line = {"bingham": bingham, "cells": cells, "cfl": cfl, "pressure": pressure, "rotation": rotation}
            line.update(err_pct=round(100 * rec["max_velocity_error_rel"], 3), steps=rec["n_steps"])
            print(json.dumps(line | {"cpu_s": round(rec["cpu_s"], 1)}), flush=True)
