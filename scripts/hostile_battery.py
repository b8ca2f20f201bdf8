"""The hostile battery of issue 35: bad input, hostile files, busy folders and signals against every
command family, each in a process of its own as a user would try it, and a count of what happened.

    python scripts/hostile_battery.py [--only FAMILY ...] [--list] [--json FILE]

Each case has an expected exit status and the words its one-line message must hold (the option,
key or file it blames).  A case is counted as

* clean: the expected status, no traceback, a status-2 message of one line that names the culprit;
* traceback: a Python traceback on stderr (or status 1, a bug);
* silent acceptance: exit 0 where the input should have been refused, or still running after the
  case's timeout (60 s: a refusal takes seconds);
* wrong status: another status (a crash code such as 139, a hang stopped by the battery's
  timeout, an interrupt that did not stop the process within the case's limit);
* unclear message: the right status, but the message does not name the culprit or is not one line.

The project's own small version of these cases runs in the test suite (tests/test_hostile_*.py);
this script is the larger battery, whose counts are recorded in docs/output.md ("Hostile input").
Runs on the CPU (``JAX_PLATFORMS=cpu``), one case at a time; about 10 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
SMALL = ["domain.cell_size_m=0.06", "time.t_end_s=0.3", "time.n_frames=3"]
SETS = [a for s in SMALL for a in ("--set", s)]
RUN_SETS = ["--set", "domain.cell_size_m=0.04", "--set", "time.t_end_s=0.3", "--set", "time.n_frames=3"]
PROFILE = "x_m,h_m,t_s\n0.0,0.1,0.3\n0.1,0.08,0.3\n0.2,0.05,0.3\n0.3,0.02,0.3\n0.4,0.0,0.3\n"


@dataclasses.dataclass
class Case:
    name: str
    family: str
    argv: list  # after `mpmjax`; "{tmp}" is the case's own folder
    expect: int = 2
    names: tuple = ()  # words the message must hold
    setup: Callable | None = None  # setup(tmp) before the command
    signal_at: tuple | None = None  # (stderr text to wait for, delay [s] after it, signal)
    stop_within_s: float = 20.0  # after the signal
    timeout_s: float = 60.0  # a refusal takes seconds (20 s on a loaded 2-core VM): still running, it accepted
    env: dict = dataclasses.field(default_factory=dict)


def _write(rel, text, mode="w"):
    def setup(tmp):
        p = Path(tmp) / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if mode == "wb":
            p.write_bytes(text)
        else:
            p.write_text(text)

    return setup


def _all(*setups):
    def setup(tmp):
        for s in setups:
            s(tmp)

    return setup


def _fifo(rel):
    return lambda tmp: os.mkfifo(Path(tmp) / rel)


def _mkdir(rel):
    return lambda tmp: (Path(tmp) / rel).mkdir(parents=True)


def _checkpoint(damage):
    """A run interrupted after one frame (its checkpoint.h5), then ``damage`` applied to the checkpoint."""

    def setup(tmp):
        code = (
            "import sys, mpmjax\n"
            "def stop(i, st):\n    raise KeyboardInterrupt\n"
            f"try:\n    mpmjax.run_scene('dambreak-lab', {str(Path(tmp) / 'r')!r}, {RUN_SETS[1::2]!r}, quiet=True, "
            "on_frame=stop)\nexcept KeyboardInterrupt:\n    pass\n"
        )
        subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_env(), check=True, capture_output=True)
        if damage:
            import h5py
            import numpy as np

            with h5py.File(Path(tmp) / "r" / "checkpoint.h5", "r+") as f:
                if damage == "meta":
                    f.attrs["meta_json"] = "{not json"
                elif damage == "frame":
                    f.attrs["frame"] = -3
                elif damage == "shape":
                    x = f["x"][()]
                    del f["x"]
                    f["x"] = np.concatenate([x, x])
                elif damage == "nokey":
                    f.attrs["meta_json"] = json.dumps({"cfg": {}})

    return setup


def _kept_cases(rel):
    """OUT/sweep-partial.npz holding one finished case of another sweep (n = 1.5)."""

    def setup(tmp):
        code = (
            "import numpy as np; from pathlib import Path; import mpmjax; from calibration.sweep import _identity, "
            f"_write_kept; cfg = mpmjax.load_scene({TWIN!r}, {SMALL!r}); "
            f"_write_kept(Path({str(Path(tmp) / rel)!r}) / 'sweep-partial.npz', _identity(cfg, {{'n': [1.5]}}, None, "
            "None), {0: (np.zeros(4), np.zeros(4), np.zeros(4), 0, np.zeros(101))})"
        )
        subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=_env(), check=True, capture_output=True)

    return setup


def _hold_lock(rel):
    """A process holding the lock of folder ``rel`` (as a running command does); killed after the case."""

    def setup(tmp):
        out = Path(tmp) / rel
        out.mkdir(parents=True, exist_ok=True)
        code = (
            "import time; from mpmjax._driver import OutputLock; "
            f"OutputLock({str(out)!r}).acquire(); print('held', flush=True); time.sleep(300)"
        )
        p = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, env=_env(), stdout=subprocess.PIPE, text=True)
        p.stdout.readline()
        HOLDERS.append(p)

    return setup


HOLDERS: list = []


def _env(extra=None):
    return dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT), **(extra or {}))


def calibrate_cases():
    data = _write("p.csv", PROFILE)
    base = ["calibrate", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0", "--levels", "1", "--max-iter", "1",
            "--quiet", *SETS]
    out = ["--out", "{tmp}/o"]
    cases = []

    def c(name, extra, names, setup=None, argv=None, **kw):
        cases.append(Case(name, "calibrate", (argv or base) + extra, names=names,
                          setup=_all(data, setup) if setup else data, **kw))

    for opt, val in [("--rtol", "-1"), ("--rtol", "nan"), ("--bandwidth-m", "inf"), ("--bandwidth-m", "0"),
                     ("--sigma-m", "0"), ("--sigma-m", "nan"), ("--runout-m", "-1"), ("--runout-m", "100"),
                     ("--runout-sigma-m", "0"), ("--max-iter", "0"), ("--max-iter", "-5"), ("--learning-rate", "nan"),
                     ("--learning-rate", "0"), ("--patience", "0"), ("--starts", "0"), ("--profile-width", "inf"),
                     ("--profile-points", "0"), ("--profile-max-iter", "0"), ("--refine-max-iter", "0"),
                     ("--level-budget-s", "0"), ("--lambda-rest", "nan"), ("--lambda-rest", "-1"),
                     ("--seed", "-1")]:
        c(f"{opt} {val}", [opt, val] + out, (opt,))
    c("--sigma runout=0", ["--sigma", "runout=0"] + out, ("--sigma",))
    c("--sigma profiles=0", ["--sigma", "profiles=0"] + out, ("--sigma",))
    c("--sigma profiles=nan", ["--sigma", "profiles=nan"] + out, ("--sigma",))
    c("--weight profiles=-1", ["--weight", "profiles=-1"] + out, ("--weight",))
    c("--init mu0=1e9", ["--init", "mu0=1e9"] + out, ("--init", "mu0"))
    c("--init mu0=nan", ["--init", "mu0=nan"] + out, ("--init",))
    c("--bounds mu0=5:1", ["--bounds", "mu0=5:1"] + out, ("--bounds",))
    c("--bounds mu0=nan:1", ["--bounds", "mu0=nan:1"] + out, ("--bounds",))
    c("--out existing file", ["--out", "{tmp}/afile"], ("--out",), _write("afile", "x"))
    c("--out under a file", ["--out", "{tmp}/afile/sub"], ("--out",), _write("afile", "x"))
    c("--out uncreatable", ["--out", "/proc/mpmjax-no/o"], ("--out",))
    c('--out ""', ["--out", ""], ("--out",))
    c("--out held by another process", out, ("--out", "process"), _hold_lock("o"))
    c("data is a directory", out, ("d.csv",), _mkdir("d.csv"), argv=[*base[:1], "{tmp}/d.csv", *base[2:]])
    c("data is a FIFO", out, ("f.csv",), _fifo("f.csv"), argv=[*base[:1], "{tmp}/f.csv", *base[2:]])
    c("binary CSV", out, ("b.csv",), _write("b.csv", b"\x00\xff\xfe\x89PNG\r\n" * 20, "wb"),
      argv=[*base[:1], "{tmp}/b.csv", *base[2:]])
    c("Latin-1 CSV", out, ("l.csv",), _write("l.csv", "x_m,h_m\n0,0.1\n1,0.2\n# h\xf6he\n".encode("latin-1"), "wb"),
      argv=[*base[:1], "{tmp}/l.csv", *base[2:]])
    c("NaN in a profile", out, ("n.csv",), _write("n.csv", PROFILE.replace("0.08", "nan")),
      argv=[*base[:1], "{tmp}/n.csv", *base[2:]])
    c("profile times all 0", out, ("z.csv", "t_s"), _write("z.csv", PROFILE.replace(",0.3\n", ",0\n")),
      argv=[*base[:1], "{tmp}/z.csv", *base[2:]])
    c("profile at t = 1e6 s", out, ("t.csv", "t_s"), _write("t.csv", PROFILE.replace(",0.3\n", ",1e6\n")),
      argv=["calibrate", "{tmp}/t.csv", "--scene", TWIN, "--fit", "mu0", "--levels", "1", "--max-iter", "1",
            "--quiet", "--set", "domain.cell_size_m=0.06"], timeout_s=60)
    c("NaN in a rest-time file", ["--rest-times", "{tmp}/r.csv"] + out, ("r.csv",),
      _write("r.csv", "t_rest_s,t_s,x_front_m\n0,0.1,0.3\n0,0.2,nan\n"))
    c("empty flow-curve file", ["--flow-curve", "{tmp}/fc.csv"] + out, ("fc.csv",), _write("fc.csv", ""))
    c("flow-curve header only", ["--flow-curve", "{tmp}/fc.csv"] + out, ("fc.csv",),
      _write("fc.csv", "gamma_dot_1_s,tau_pa\n"))
    c("flow-curve is a directory", ["--flow-curve", "{tmp}/fcd"] + out, ("fcd",), _mkdir("fcd"))
    c("flow-curve negative stress", ["--flow-curve", "{tmp}/fc.csv"] + out, ("fc.csv", "tau_pa"),
      _write("fc.csv", "gamma_dot_1_s,tau_pa\n1,-5\n10,20\n"))
    c("runout series is a FIFO", ["--runout-series", "{tmp}/rs.csv"] + out, ("rs.csv",), _fifo("rs.csv"),
      )
    c("memory refused", ["--set", "domain.cell_size_m=0.0004"] + out, ("memory",),
      env={"MPMJAX_MEMORY_LIMIT_GB": "0.2"})
    c("--set n_frames with 10000 digits", ["--set", "time.n_frames=" + "9" * 10000] + out, ("time.n_frames",))
    # valid input that must be accepted
    cases.append(Case("runout series past the last profile time (valid)", "calibrate",
                      ["calibrate", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0", "--levels", "1", "--max-iter", "1",
                       "--quiet", "--set", "domain.cell_size_m=0.06", "--runout-series", "{tmp}/rs.csv"] + out,
                      expect=0,
                      setup=_all(data, _write("rs.csv", "t_s,x_front_m\n0.1,0.25\n0.2,0.3\n0.3,0.32\n0.45,0.33\n")),
                      names=(), timeout_s=240))
    return cases


def sweep_cases():
    base = ["sweep", TWIN, "--vary", "n=2,3", "--quiet", *SETS]
    cases = []

    def c(name, extra, names, setup=None, **kw):
        cases.append(Case(name, "sweep", base + extra, names=names, setup=setup, **kw))

    c("--out existing file", ["--out", "{tmp}/afile"], ("--out",), _write("afile", "x"))
    c("--out under a file", ["--out", "{tmp}/afile/sub"], ("--out",), _write("afile", "x"))
    c("--out uncreatable", ["--out", "/proc/mpmjax-no/o"], ("--out",))
    c('--out ""', ["--out", ""], ("--out",))
    c("--out held by another process", ["--out", "{tmp}/o"], ("--out", "process"), _hold_lock("o"))
    c("--chunk 0", ["--chunk", "0", "--out", "{tmp}/o"], ("--chunk",))
    c("--chunk -1", ["--chunk", "-1", "--out", "{tmp}/o"], ("--chunk",))
    c("--devices 0", ["--devices", "0", "--out", "{tmp}/o"], ("--devices",))
    c("--vary n=nan", ["--vary", "alpha=nan", "--out", "{tmp}/o"], ("--vary",))
    c("--vary n=1e999", ["--vary", "alpha=1e999", "--out", "{tmp}/o"], ("--vary",))
    c("--vary unknown name", ["--vary", "zeta=1", "--out", "{tmp}/o"], ("--vary", "zeta"))
    c("--shard 3/2", ["--shard", "3/2", "--out", "{tmp}/o"], ("--shard",))
    c("memory refused", ["--set", "domain.cell_size_m=0.0004", "--out", "{tmp}/o"], ("memory",),
      env={"MPMJAX_MEMORY_LIMIT_GB": "0.2"})
    c("--set n_frames with 10000 digits", ["--set", "time.n_frames=" + "9" * 10000, "--out", "{tmp}/o"],
      ("time.n_frames",))
    c("--resume with no unfinished sweep", ["--resume", "--out", "{tmp}/o"], ("--resume",), _mkdir("o"))
    c("--out holds another sweep's finished cases", ["--out", "{tmp}/o"], ("--out", "sweep-partial.npz", "--vary"),
      _kept_cases("o"))
    cases.append(Case("sweep-merge: a damaged part", "sweep", ["sweep-merge", "{tmp}/parts", "--quiet"],
                      names=("part-0-of-1.npz",), setup=_write("parts/part-0-of-1.npz", b"PK\x03\x04garbage", "wb")))
    cases.append(Case("sweep-merge: parts folder is a file", "sweep", ["sweep-merge", "{tmp}/afile", "--quiet"],
                      names=("afile",), setup=_write("afile", "x")))
    cases.append(Case("sweep-merge: --out existing file", "sweep",
                      ["sweep-merge", "{tmp}/parts", "--out", "{tmp}/afile", "--quiet"],
                      names=("--out",), setup=_all(_mkdir("parts"), _write("afile", "x"))))
    return cases


def run_cases():
    base = ["run", "dambreak-lab", "--quiet", "--no-animation", *RUN_SETS]
    cases = []

    def c(name, extra, names, setup=None, argv=None, **kw):
        cases.append(Case(name, "run", (argv or base) + extra, names=names, setup=setup, **kw))

    c('--out ""', ["--out", ""], ("--out",))
    c("--set n_frames with 10000 digits", ["--set", "time.n_frames=" + "9" * 10000, "--out", "{tmp}/o"],
      ("time.n_frames",))
    c("--set cell size 1e-400", ["--set", "domain.cell_size_m=1e-400", "--out", "{tmp}/o"], ("domain.cell_size_m",))
    c("--checkpoint-every -1", ["--checkpoint-every", "-1", "--out", "{tmp}/o"], ("--checkpoint-every",))
    c("--devices 0", ["--devices", "0", "--out", "{tmp}/o"], ("devices",))
    c("--resume: damaged metadata", [], ("checkpoint",), _checkpoint("meta"), argv=["run", "--resume", "{tmp}/r",
                                                                                   "--quiet", "--no-animation"])
    c("--resume: negative frame", [], ("checkpoint", "frame"), _checkpoint("frame"),
      argv=["run", "--resume", "{tmp}/r", "--quiet", "--no-animation"])
    c("--resume: arrays of another shape", [], ("checkpoint", "x"), _checkpoint("shape"),
      argv=["run", "--resume", "{tmp}/r", "--quiet", "--no-animation"])
    c("--resume: metadata without its keys", [], ("checkpoint",), _checkpoint("nokey"),
      argv=["run", "--resume", "{tmp}/r", "--quiet", "--no-animation"])
    c("a body wholly below the DEM surface", [], ("bodies[0]", "below the terrain surface"),
      _write("buried.toml", BURIED), argv=["run", "{tmp}/buried.toml", "--quiet", "--no-animation", "--out", "{tmp}/o"])
    return cases


BURIED = """name = "buried"
[domain]
lo_m = [0.0, 0.0]
hi_m = [1.6, 0.4]
cell_size_m = 0.04
[time]
t_end_s = 0.05
n_frames = 1
[material]
model = "newtonian"
density_kg_m3 = 1000.0
bulk_modulus_pa = 1e5
viscosity_pa_s = 1.0
[terrain]
type = "slip"
heights_m = [0.1, 0.2, 0.3]
spacing_m = 0.8
[[bodies]]
lo_m = [0.2, 0.0]
hi_m = [0.4, 0.1]
"""


def other_cases():
    cases = [
        Case("rheometer --t-end nan", "other", ["rheometer", "--t-end", "nan", "--out", "{tmp}/o"], names=("--t-end",)),
        Case("rheometer --rates 0", "other", ["rheometer", "--rates", "0", "--out", "{tmp}/o"], names=("--rates",)),
        Case("rheometer --out existing file", "other", ["rheometer", "--out", "{tmp}/afile"], names=("--out",),
             setup=_write("afile", "x")),
        Case('rheometer --out ""', "other", ["rheometer", "--out", ""], names=("--out",)),
        Case("design --sigma-ln 0", "other",
             ["design", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0", "--sigma-ln", "0", "--out", "{tmp}/o", *SETS],
             names=("--sigma-ln",), setup=_write("p.csv", PROFILE)),
        Case("design --transient-points 0", "other",
             ["design", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0", "--transient-points", "0", "--out", "{tmp}/o",
              *SETS], names=("--transient-points",), setup=_write("p.csv", PROFILE)),
        Case("design --out existing file", "other",
             ["design", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0", "--out", "{tmp}/afile", *SETS],
             names=("--out",), setup=_all(_write("p.csv", PROFILE), _write("afile", "x"))),
        Case("bench --steps 0", "other", ["bench", "--steps", "0", "--out", "{tmp}/b.json"], names=("--steps",)),
        Case("bench --reps -1", "other", ["bench", "--reps", "-1", "--out", "{tmp}/b.json"], names=("--reps",)),
        Case("converge --ppc 0", "other", ["converge", "--size", "ci", "--ppc", "0", "--out", "{tmp}/o"],
             names=("--ppc",)),
        Case("validate --out existing file", "other", ["validate", "--size", "ci", "--out", "{tmp}/afile"],
             names=("--out",), setup=_write("afile", "x")),
        Case('study --out ""', "other", ["study", "stiff", "--out", ""], names=("--out",)),
        Case("records --out existing file", "other", ["records", "--out", "{tmp}/afile"], names=("--out",),
             setup=_write("afile", "x")),
        Case("pareto --out under a file", "other", ["pareto", "--out", "{tmp}/afile/x"], names=("--out",),
             setup=_write("afile", "x")),
    ]
    return cases


def signal_cases():
    run = ["run", "dambreak-lab", "--no-animation", "--out", "{tmp}/o"]
    long_frame = run + ["--set", "time.t_end_s=30", "--set", "time.n_frames=1", "--set", "domain.cell_size_m=0.01"]
    cases = []
    for i in range(3):
        cases.append(Case(f"run: SIGINT while compiling ({i + 1})", "signals", run, expect=130,
                          names=("interrupted",), signal_at=("scene ", 1.0 + 0.7 * i, signal.SIGINT)))
    cases.append(Case("run: SIGTERM while compiling", "signals", run, expect=143, names=("interrupted",),
                      signal_at=("scene ", 1.5, signal.SIGTERM)))
    # a frame is stepped in chunks of about a second: its own handler stops it, before the watchdog's 5 s
    cases.append(Case("run: SIGINT inside a long frame", "signals", long_frame, expect=130,
                      names=("interrupted at frame 0/1",), signal_at=("compiled", 3.0, signal.SIGINT),
                      stop_within_s=4.5, timeout_s=300))
    small = run + [*RUN_SETS]
    for delay in (0.3, 0.6, 0.9, 1.2):  # while the program imports: jax's gc callback used to drop it (exit 0)
        cases.append(Case(f"run: SIGINT {delay:g} s after the start", "signals", small, expect=130,
                          names=("interrupted",), signal_at=("", delay, signal.SIGINT)))
    pics = ["run", "dambreak-lab", "--out", "{tmp}/o", "--set", "domain.cell_size_m=0.04", "--set", "time.t_end_s=0.2",
            "--set", "time.n_frames=10"]
    cases.append(Case("run: SIGTERM while animation.gif is written", "signals", pics, expect=143,
                      names=("animation.gif is missing",), signal_at=("animation [", 0.0, signal.SIGTERM)))
    cal = ["calibrate", "{tmp}/p.csv", "--scene", TWIN, "--fit", "mu0,T", "--levels", "1", "--max-iter", "50",
           "--rtol", "1e-12", "--out", "{tmp}/o", "--set", "domain.cell_size_m=0.03", "--set", "time.t_end_s=0.3",
           "--set", "time.n_frames=3"]
    for i in range(2):
        cases.append(Case(f"calibrate: SIGINT after iterations ({i + 1})", "signals", cal, expect=130,
                          names=("interrupted",), setup=_write("p.csv", PROFILE),
                          signal_at=("iteration", 0.5 + i, signal.SIGINT), timeout_s=300))
    cases.append(Case("calibrate: SIGTERM", "signals", cal, expect=143, names=("interrupted",),
                      setup=_write("p.csv", PROFILE), signal_at=("iteration", 0.5, signal.SIGTERM), timeout_s=300))
    sw = ["sweep", "dambreak-lab", "--vary", "n=2,2.5,3,3.5", "--chunk", "1", "--out", "{tmp}/o",
          "--set", "time.t_end_s=20", "--set", "domain.cell_size_m=0.01"]
    cases.append(Case("sweep: SIGINT inside a batch", "signals", sw, expect=130, names=("interrupted",),
                      signal_at=("", 15.0, signal.SIGINT), stop_within_s=15, timeout_s=300))
    # steps in chunks of about a second: stopped within seconds, the finished case kept
    sw2 = ["sweep", TWIN, "--vary", "n=2,3", "--chunk", "1", "--out", "{tmp}/o", "--set", "domain.cell_size_m=0.03",
           "--set", "time.t_end_s=120", "--set", "time.n_frames=2"]
    cases.append(Case("sweep: SIGTERM in the second batch keeps the first", "signals", sw2, expect=143,
                      names=("1 of 2 cases finished and are kept in",), signal_at=("batch 1/2", 0.5, signal.SIGTERM),
                      stop_within_s=4.5, timeout_s=300))
    return cases


FAMILIES = {"calibrate": calibrate_cases, "sweep": sweep_cases, "run": run_cases, "other": other_cases,
            "signals": signal_cases}


def run_case(case: Case, tmp: Path) -> dict:
    argv = [a.replace("{tmp}", str(tmp)) for a in case.argv]
    if case.setup:
        case.setup(tmp)
    cmd = [sys.executable, "-m", "mpmjax.cli", *argv]
    t0 = time.perf_counter()
    stopped_late = False
    try:
        if case.signal_at is None:
            r = subprocess.run(cmd, cwd=tmp, env=_env(case.env), capture_output=True, text=True,
                               timeout=case.timeout_s, stdin=subprocess.DEVNULL)
            rc, err = r.returncode, r.stderr
        else:
            rc, err, stopped_late = _signalled(cmd, tmp, case)
    except subprocess.TimeoutExpired as e:
        rc, err = "timeout", (e.stderr or b"").decode(errors="replace") if isinstance(e.stderr, bytes) else (
            e.stderr or "")
        if "Traceback" not in err and case.expect == 2:
            rc = "running"  # still working on input it should have refused
    finally:
        while HOLDERS:
            p = HOLDERS.pop()
            p.kill()
            p.wait()
    wall = time.perf_counter() - t0
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    if "Traceback" in err or rc == 1:
        verdict = "traceback"
    elif (rc == 0 or rc == "running") and case.expect != 0:
        verdict = "silent acceptance"
    elif rc != case.expect or stopped_late:
        verdict = "wrong status"
    elif case.expect == 2 and (len(lines) != 1 or not all(n.lower() in last.lower() for n in case.names)):
        verdict = "unclear message"
    elif case.expect in (130, 143) and not all(n in last for n in case.names):
        verdict = "unclear message"
    else:
        verdict = "clean"
    return dict(name=case.name, family=case.family, status=rc, expect=case.expect, verdict=verdict,
                wall_s=round(wall, 1), message=last[:300])


def _signalled(cmd, tmp, case):
    text, delay, signum = case.signal_at
    p = subprocess.Popen(cmd, cwd=tmp, env=_env(case.env), stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                         stdin=subprocess.DEVNULL)
    os.set_blocking(p.stderr.fileno(), False)
    buf = b""
    t0 = time.perf_counter()
    while text.encode() not in buf and p.poll() is None and time.perf_counter() - t0 < case.timeout_s:
        time.sleep(0.05)
        buf += p.stderr.read() or b""
    time.sleep(delay)
    sent = time.perf_counter()
    if p.poll() is None:
        p.send_signal(signum)
    late = False
    try:
        p.wait(timeout=case.stop_within_s)
    except subprocess.TimeoutExpired:
        late = True
        p.kill()
        p.wait()
    del sent
    os.set_blocking(p.stderr.fileno(), True)
    buf += p.stderr.read() or b""
    rc = p.returncode if p.returncode >= 0 else 128 - p.returncode
    return rc, buf.decode(errors="replace"), late


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", action="append", choices=sorted(FAMILIES), help="run only this family (repeatable)")
    ap.add_argument("--match", help="run only cases whose name holds this text")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--json", help="write every case's result to this JSON file")
    ap.add_argument("--root", help="the checkout to test (default: this script's), e.g. to count another branch")
    a = ap.parse_args(argv)
    if a.root:
        global ROOT, TWIN
        ROOT = Path(a.root).resolve()
        TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
    cases = [c for f in (a.only or FAMILIES) for c in FAMILIES[f]()]
    if a.match:
        cases = [c for c in cases if a.match in c.name]
    if a.list:
        for c in cases:
            print(f"{c.family:10s} {c.name}")
        return 0
    results = []
    for c in cases:
        with tempfile.TemporaryDirectory(prefix="mpmjax-hostile-") as tmp:
            r = run_case(c, Path(tmp))
        results.append(r)
        flag = "" if r["verdict"] == "clean" else f"  <-- {r['verdict']}"
        print(f"{r['family']:9s} {r['name'][:52]:52s} {str(r['status']):>7s} {r['wall_s']:6.1f} s{flag}", flush=True)
        if r["verdict"] != "clean":
            print(f"          {r['message']}", flush=True)
    counts = Counter(r["verdict"] for r in results)
    order = ("clean", "traceback", "silent acceptance", "wrong status", "unclear message")
    print(f"\n{len(results)} cases: " + ", ".join(f"{counts.get(k, 0)} {k}" for k in order))
    if a.json:
        Path(a.json).write_text(json.dumps({"counts": {k: counts.get(k, 0) for k in order}, "cases": results},
                                           indent=1))
    return 0 if counts.get("clean", 0) == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
