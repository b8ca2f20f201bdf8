"""``incompressible_slump.py`` with the grid pressure's CG relative tolerance set for both precisions
(``mpmjax._pressure.CG_RTOL``; float32 1e-4 and float64 1e-11 by default), so that precision and the
solve's tolerance can be varied one at a time: is it float32 that keeps the 32-cell B = 0.05 deposit
creeping? (docs/incompressible-default.md, "The void closures against the lubrication solution in time").

    RTOL=1e-4 .venv/bin/python benchmarks/accuracy/slump_rtol.py 0.05 1 32 120 numerics.pressure=incompressible numerics.void_closure=velocity numerics.dtype=float64

Arguments as ``incompressible_slump.py``; prints its JSON line.
"""
import os
import runpy
import sys
from pathlib import Path

import mpmjax._pressure as pressure

rtol = float(os.environ["RTOL"])
pressure.CG_RTOL = {"float32": rtol, "float64": rtol}
script = Path(__file__).with_name("incompressible_slump.py")
sys.argv = [str(script)] + sys.argv[1:]
runpy.run_path(str(script), run_name="__main__")
