"""Every numeric option of every command against its declared range (issue 35, ``mpmjax.cli._guard``):
a value outside it, a NaN or an infinity is exit status 2 with one line naming the option, the value
and the allowed range, before anything is built or written; a value inside it passes the check.
Hypothesis draws the option and the value."""

from __future__ import annotations

import argparse
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mpmjax import cli
from mpmjax.cli import _guard

# the positional arguments and required options a command needs to parse
REQUIRED = {
    "calibrate": ["d.csv", "--fit", "mu0"],
    "design": ["d.csv"],
    "sweep": ["--vary", "n=1"],
    "study": ["stiff"],
    "sweep-merge": ["parts"],
}


def _declared():
    """(command, flag, Range, is_int) of every option declared with ``_guard.number``."""
    sub = next(a for a in cli.make_parser()._actions if a.dest == "cmd")
    out = []
    for name, sp in sub.choices.items():
        types = {a.dest: a.type for a in sp._actions}
        for dest, (flag, rng) in (sp.get_default(_guard.RANGES) or {}).items():
            out.append((name, flag, rng, types[dest] is int))
    return out


DECLARED = _declared()


def test_the_numeric_options_of_the_issue_have_ranges():
    have = {(c, f) for c, f, _, _ in DECLARED}
    for c, f in [("calibrate", "--rtol"), ("calibrate", "--bandwidth-m"), ("calibrate", "--sigma-m"),
                 ("calibrate", "--runout-m"), ("calibrate", "--max-iter"), ("sweep", "--chunk"),
                 ("sweep", "--devices"), ("run", "--checkpoint-every"), ("design", "--sigma-ln"),
                 ("bench", "--steps"), ("converge", "--ppc")]:
        assert (c, f) in have, (c, f)


def _outside(rng, is_int):
    """Values outside ``rng``: non-finite floats, and numbers beyond each bound."""
    bad = [] if is_int else [st.sampled_from([math.nan, math.inf, -math.inf])]
    num = st.integers if is_int else st.floats
    if rng.lo is not None:
        top = rng.lo if (rng.lo_open or not is_int) else rng.lo - 1
        bad.append(num(max_value=top) if is_int else num(max_value=top, allow_nan=False, allow_infinity=False)
                   .filter(lambda x: not rng.holds(x)))
    if rng.hi is not None:
        bottom = rng.hi if (rng.hi_open or not is_int) else rng.hi + 1
        bad.append(num(min_value=bottom) if is_int else num(min_value=bottom, allow_nan=False,
                                                            allow_infinity=False).filter(lambda x: not rng.holds(x)))
    return st.one_of(bad) if bad else st.nothing()


CASES = [(c, f, r, i) for c, f, r, i in DECLARED if r.lo is not None or r.hi is not None or not i]


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_value_outside_the_range_exits_2_naming_the_option(data, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    command, flag, rng, is_int = data.draw(st.sampled_from(CASES))
    value = data.draw(_outside(rng, is_int))
    argv = [command, *REQUIRED.get(command, []), f"{flag}={value!r}" if not is_int else f"{flag}={value}"]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"mpmjax: error: {flag} = ") and "allowed range: " in err and len(err.splitlines()) == 1
    assert rng.text() in err
    assert list(tmp_path.iterdir()) == []  # nothing written


@settings(max_examples=200, deadline=None)
@given(data=st.data())
def test_a_value_inside_the_range_passes(data):
    command, flag, rng, is_int = data.draw(st.sampled_from(DECLARED))
    lo = rng.lo if rng.lo is not None else -1e6
    hi = rng.hi if rng.hi is not None else lo + 1e6
    if is_int:
        value = data.draw(st.integers(math.ceil(lo) + rng.lo_open, math.floor(hi) - rng.hi_open))
    else:
        value = data.draw(st.floats(lo, hi, exclude_min=rng.lo_open, exclude_max=rng.hi_open))
    dest = flag.lstrip("-").replace("-", "_")
    _guard.check_options(argparse.Namespace(**{dest: value, _guard.RANGES: {dest: (flag, rng)}}))


def test_an_unparsable_number_is_argparse_s_usage_error(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["sweep", "--vary", "n=1", "--chunk", "9" * 10000])
    assert e.value.code == 2
    assert "--chunk" in capsys.readouterr().err
