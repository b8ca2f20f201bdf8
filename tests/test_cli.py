"""The command line package (issue 34): one command table lists every command and its options,
``--help`` works for each, and one map turns what a handler raises into the exit status and
one-line message of the contract (``mpmjax.cli``'s docstring)."""

from __future__ import annotations

import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from calibration.data import DataError
from calibration.distributed import DistributedError
from mpmjax import cli
from mpmjax._driver import Interrupted, MemoryRefused, OutputBusy, OutputError, OutputFailure
from mpmjax._health import RunFailure
from mpmjax._schema import SceneError
from mpmjax.cli._status import run_command

ROOT = Path(__file__).resolve().parents[1]
EXPECTED = (
    "scenes run rheometer bench stress records pareto converge validate study calibrate calibrate-coverage "
    "design sweep sweep-merge"
).split()


def test_the_table_lists_every_command_once_and_the_parser_has_them():
    names = [c.name for c in cli.COMMANDS]
    assert names == EXPECTED
    sub = next(a for a in cli.make_parser()._actions if a.dest == "cmd")
    assert list(sub.choices) == names
    listed = cli.__doc__.split("``")[1].removeprefix("mpmjax ").split()  # the package docstring's list
    assert [w for w in listed if w != "|"] == names


def test_the_entry_point_is_main():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts == {"mpmjax": "mpmjax.cli:main"}


@pytest.mark.parametrize("argv", [["--help"]] + [[name, "--help"] for name in EXPECTED])
def test_help_exits_0(argv, capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 0
    assert "usage: mpmjax" in capsys.readouterr().out


def test_python_m_mpmjax_cli_runs_the_command():
    r = subprocess.run([sys.executable, "-m", "mpmjax.cli", "scenes"], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "dambreak-lab" in r.stdout


def _raising(e, **notes):
    def handler(args):
        raise e

    return cli.Command("test", "", lambda p: None, handler, **notes)


@pytest.mark.parametrize(
    "exc,status,first",
    [
        (cli.UsageError("--x = 3 is invalid"), 2, "mpmjax: error: --x = 3 is invalid"),
        (SceneError("material.alpha = -3"), 2, "mpmjax: error: material.alpha = -3"),
        (MemoryRefused("needs 9 GB"), 2, "mpmjax: error: needs 9 GB"),
        (OutputBusy("locked"), 2, "mpmjax: error: locked"),
        (OutputError("cannot be created"), 2, "mpmjax: error: cannot be created"),
        (DataError("x.csv: no such file"), 2, "mpmjax: error: x.csv: no such file"),
        (DistributedError("--process-id"), 2, "mpmjax: error: --process-id"),
        (RunFailure({"error": "NaN at step 3"}), 3, "mpmjax: NaN at step 3"),
        (OutputFailure("disk full"), 4, "mpmjax: disk full"),
        (KeyboardInterrupt(), 130, "interrupted: see o"),
        (Interrupted(signal.SIGTERM), 143, "interrupted: see o"),
        (Interrupted(signal.SIGINT, "resume with mpmjax run --resume o"), 130, "resume with mpmjax run --resume o"),
    ],
)
def test_the_status_map(exc, status, first, capsys):
    args = type("Args", (), {})()
    args.out = "o"
    cmd = _raising(exc, interrupted="interrupted: see {out}", failed="kept in {out}")
    assert run_command(cmd, args) == status
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == first and "Traceback" not in "\n".join(err)
    assert err[1:] == (["kept in o"] if status == 3 else [])


def test_value_error_is_invalid_input_only_where_the_table_says_so(capsys):
    args = type("Args", (), {})()
    assert run_command(_raising(ValueError("--vary 'n=x'"), invalid=(ValueError,)), args) == 2
    assert capsys.readouterr().err.strip() == "mpmjax: error: --vary 'n=x'"
    with pytest.raises(ValueError):  # elsewhere a ValueError is a bug: status 1 with its traceback
        run_command(_raising(ValueError("bug")), args)


def test_usage_error_is_defined_once():
    hits = [
        str(p.relative_to(ROOT))
        for p in sorted([*(ROOT / "mpmjax").rglob("*.py"), *(ROOT / "calibration").rglob("*.py")])
        if "USAGE_ERROR =" in p.read_text()
    ]
    assert hits == ["mpmjax/cli/_status.py"]
