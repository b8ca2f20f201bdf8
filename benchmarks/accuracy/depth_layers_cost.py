"""What ``numerics.depth_layers`` costs the depth-averaged field scenes, and what it moves (docs/depth-layers.md).

Each built-in depth-averaged Coussot scene run by ``mpmjax run`` to ``T`` seconds at each layer count,
alternating in rounds (the 2-core VM drifts by about 30 %, so the counts are compared round by round): the run's
time loop (``summary.json``'s wall_s less compile_s), the whole process's CPU seconds (user + system, compilation
and output included), and the free-surface front at the end (``final_runout_m``).  One JSON line per run.

    .venv/bin/python benchmarks/accuracy/depth_layers_cost.py [T_S] [ROUNDS] [LAYERS ...]   # default 60 2 1 16 32
"""

import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SCENES = ("field-breach-da", "field-dambreak-da")
MPMJAX = str(Path(sys.executable).with_name("mpmjax"))


def once(scene, t_end, layers):
    with tempfile.TemporaryDirectory() as out:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run([MPMJAX, "run", scene, "--set", f"time.t_end_s={t_end!r}", "--set",
                        f"numerics.depth_layers={layers}", "--out", out, "--quiet", "--no-animation"], check=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        s = json.loads((Path(out) / "summary.json").read_text())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"scene": scene, "t_end_s": t_end, "layers": layers, "steps": s["n_steps"], "particles": s["n_particles"],
            "loop_wall_s": round(s["wall_s"] - s["compile_s"], 1), "process_cpu_s": round(cpu, 1),
            "front_m": round(s["final_runout_m"], 2), "date": time.strftime("%Y-%m-%d")}


if __name__ == "__main__":
    t_end = float(sys.argv[1]) if len(sys.argv) > 1 else 60.0
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    counts = [int(a) for a in sys.argv[3:]] or [1, 16, 32]
    for _ in range(rounds):
        for scene in SCENES:
            for k in counts:
                print(json.dumps(once(scene, t_end, k)), flush=True)
