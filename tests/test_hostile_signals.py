"""Signals against the ``mpmjax`` program (issue 35's first row): SIGTERM while a run compiles and
SIGINT during ``calibrate`` end with 143 / 130 and one line, never a crash code (139: XLA's threads
torn down at interpreter exit, which ``_guard.program_exit`` now skips with ``os._exit``), and a
signal that arrives while the main thread is inside one long XLA call ends the process within
seconds (``_guard.Watchdog``), where the interpreter used to wait for the call to finish."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")
ENV = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONPATH=str(ROOT))


def _signal_after(cmd, text, signum, cwd, delay=0.3, within=30.0):
    """Start ``cmd``, send ``signum`` ``delay`` s after ``text`` appears on its stderr; (status,
    stderr, seconds from the signal to the exit)."""
    p = subprocess.Popen(cmd, cwd=cwd, env=ENV, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    err = ""
    while text not in err:
        line = p.stderr.readline()
        assert line or p.poll() is None, f"ended before {text!r}: {err}"
        err += line
    time.sleep(delay)
    p.send_signal(signum)
    t0 = time.perf_counter()
    try:
        rest = p.communicate(timeout=within)[1]
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        raise AssertionError(f"still running {within} s after the signal") from None
    return p.returncode, err + rest, time.perf_counter() - t0


def test_sigterm_while_a_run_compiles_exits_143_with_one_line(tmp_path):
    cmd = [sys.executable, "-m", "mpmjax.cli", "run", "dambreak-lab", "--out", str(tmp_path / "o"),
           "--no-animation", "--set", "domain.cell_size_m=0.04", "--set", "time.t_end_s=0.3"]
    rc, err, _ = _signal_after(cmd, "scene ", signal.SIGTERM, tmp_path)
    assert rc == 143, (rc, err)
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted") and "Traceback" not in err, err


def test_sigint_during_calibrate_exits_130_with_one_line(tmp_path):
    (tmp_path / "p.csv").write_text("x_m,h_m,t_s\n0,0.1,0.3\n0.1,0.08,0.3\n0.2,0.05,0.3\n0.3,0.02,0.3\n0.4,0,0.3\n")
    cmd = [sys.executable, "-m", "mpmjax.cli", "calibrate", "p.csv", "--scene", TWIN, "--fit", "mu0,T",
           "--levels", "1", "--max-iter", "200", "--rtol", "0", "--out", "o", "--set", "domain.cell_size_m=0.06",
           "--set", "time.t_end_s=0.3", "--set", "time.n_frames=3"]
    rc, err, _ = _signal_after(cmd, "iteration", signal.SIGINT, tmp_path)
    assert rc == 130, (rc, err)
    assert err.strip().splitlines()[-1] == "interrupted: files already written in o are kept", err
    assert "Traceback" not in err


def test_the_watchdog_ends_a_main_thread_that_cannot_see_the_signal(tmp_path):
    """The main thread blocks SIGINT and sleeps in C, as one inside a long compilation or a call
    that holds off signal handlers: only the watchdog sees the signal, and ends the process."""
    code = (
        "import signal, sys, time\n"
        "from mpmjax.cli._guard import Watchdog, interrupt_signals\n"
        "Watchdog(lambda: 'interrupted: the note of the command')\n"
        "with interrupt_signals():\n"
        "    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})\n"
        "    print('computing', file=sys.stderr, flush=True)\n"
        "    time.sleep(120)\n"
    )
    rc, err, waited = _signal_after([sys.executable, "-c", code], "computing", signal.SIGINT, tmp_path, delay=1.0)
    assert rc == 130, (rc, err)
    assert "interrupted: the note of the command (stopped inside a computation" in err
    assert waited < 15  # GRACE_S (5 s) and the exit, not the minutes the loop takes
