"""One sweep on 1 process against 2 local processes joined by jax.distributed (issue 18 item 5).

usage: python benchmarks/devices/distributed_sweep.py [ROUNDS] >> benchmarks/devices/distributed_sweep.jsonl

Runs the same ``mpmjax sweep`` (the twin dam break, 300 particles, 1140 steps, float64, 8 cases:
mu0 x n) as whole command-line processes, the codes alternating in each round and each going
first in turn, and prints one JSON line per run:

* ``1proc``: one process, one CPU device (the 8 cases as one vmap batch);
* ``2proc``: two processes on 127.0.0.1 (``--coordinator``, ``--num-processes 2``,
  ``--process-id``), one CPU device each: 4 cases per process, gathered by process 0;
* ``1proc-2dev``: one process with 2 host devices
  (``XLA_FLAGS=--xla_force_host_platform_device_count=2``), for comparison.

Wall time is the command's, from start to the last process's exit (imports, compilation, the
run, writing the outputs); CPU time is user + system of all its processes (``resource``
RUSAGE_CHILDREN).  The load average at the start of each run is recorded: on a shared machine
wall times mean little.
"""

import json
import os
import resource
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ARGS = [
    str(ROOT / "data" / "twin-small-dambreak.toml"),
    "--vary", "mu0=2,3,4,6", "--vary", "n=2,3", "--quiet",
]


def _port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(code, out):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))
    base = [sys.executable, "-m", "mpmjax.cli", "sweep", *ARGS, "--out", str(out)]
    if code == "2proc":
        port = _port()
        cmds = [base + ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(i)]
                for i in range(2)]
    else:
        cmds = [base]
        if code == "1proc-2dev":
            env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    procs = [subprocess.Popen(c, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE) for c in cmds]
    errs = [p.communicate(timeout=1800)[1] for p in procs]
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if any(p.returncode for p in procs):
        raise SystemExit(f"{code}: exit {[p.returncode for p in procs]}\n{errs[0][-2000:].decode()}")
    doc = json.loads((Path(out) / "sweep.json").read_text())
    return {
        "code": code,
        "wall_s": round(wall, 2),
        "cpu_s": round((r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), 2),
        "sweep_loop_wall_s": round(doc["wall_s"], 2),
        "n_processes": doc["n_processes"],
        "n_devices": doc["n_devices"],
        "load_1min": load,
        "final_runout_m": doc["final_runout_m"],
    }


def main():
    rounds = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    codes = ["1proc", "2proc", "1proc-2dev"]
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            order = codes[r % len(codes):] + codes[: r % len(codes)]
            for c in order:
                rec = run(c, Path(tmp) / f"{c}-{r}")
                rec["round"] = r
                print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
