"""``mpmjax rheometer``: its options (``add_rheometer_arguments``) and its handler
(``cmd_rheometer``: the Coussot law at constant shear rates, ``mpmjax.rheometer.write_outputs``)."""

from __future__ import annotations

import math

import jax
import numpy as np

from .._rheology import BASE_VALUES, Coussot, Param
from ..rheometer import make_params, write_outputs
from ..rheometer._physics import _in_range, _range_text
from ._status import UsageError

# The Coussot parameters the rheometer uses (rho and kappa are carried, not used), each with
# its option --name (underscores as dashes: --mu-max).
_CLI_PARAMS = tuple(p for p in Coussot.params if p.name not in ("rho", "kappa"))


def _flag(p: Param) -> str:
    return "--" + p.name.replace("_", "-")


def add_rheometer_arguments(parser) -> None:
    """Add the ``mpmjax rheometer`` options (defaults: thesis BASE lab case)."""
    for p in _CLI_PARAMS:
        parser.add_argument(
            _flag(p),
            dest=p.name,
            default=str(BASE_VALUES[p.name]),
            metavar="X",
            help=f"{p.doc.rstrip('.')} [{p.unit}] (default {BASE_VALUES[p.name]:g}, thesis BASE)",
        )
    parser.add_argument(
        "--rates",
        default="0.1,1,10,100",
        metavar="LIST",
        help="comma-separated constant shear rates [1/s], each > 0 (default 0.1,1,10,100)",
    )
    parser.add_argument(
        "--t-end",
        dest="t_end",
        default="1000",
        metavar="S",
        help="end time [s] > 0; save times are log-spaced over 5 decades up to it (default 1000)",
    )
    parser.add_argument("--out", default="rheometer_out", metavar="DIR", help="output folder (default rheometer_out)")


def _parse_number(option, value):
    """A finite number > 0 from the command line."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = None
    if x is None or not (math.isfinite(x) and x > 0):
        raise UsageError(f"{option}: invalid value {value!r}; allowed range: a finite number > 0")
    return x


def _parse_param(p: Param, value):
    """A value of the declared parameter ``p`` from the command line (its declared range)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = None
    if x is None or not (math.isfinite(x) and bool(_in_range(p, np.asarray(x)))):
        raise UsageError(f"{_flag(p)}: invalid value {value!r}; allowed range: a finite number {_range_text(p)}")
    return x


def _parse_rates(value):
    items = list(value) if isinstance(value, (list, tuple)) else str(value).split(",")
    rates = []
    for item in items:
        try:
            rates.append(_parse_number("--rates", item.strip() if isinstance(item, str) else item))
        except UsageError:
            raise UsageError(
                f"--rates: invalid value {str(value)!r} (item {str(item).strip()!r}); allowed range: "
                "a comma-separated list of finite numbers > 0 [1/s], e.g. 0.1,1,10,100"
            ) from None
    if not rates:
        raise UsageError(f"--rates: invalid value {str(value)!r}; allowed range: at least one rate > 0 [1/s]")
    return rates


def cmd_rheometer(args) -> int:
    """Run ``mpmjax rheometer``: invalid input raises ``UsageError`` (option, value, allowed range)
    before anything is written.  Enables float64 in JAX for this process (the CLI is a one-shot run)."""
    vals = {p.name: _parse_param(p, getattr(args, p.name)) for p in _CLI_PARAMS}
    if vals["mu_max"] <= vals["mu0"]:
        raise UsageError(
            f"--mu-max: invalid value {vals['mu_max']:g}; allowed range: > --mu0 = {vals['mu0']:g} [Pa s]"
        )
    rates = _parse_rates(args.rates)
    t_end = _parse_number("--t-end", args.t_end)
    out = str(args.out)  # probed and locked by the shared hardening (_guard)

    jax.config.update("jax_enable_x64", True)
    params = make_params(**vals)
    t_s = np.logspace(math.log10(t_end) - 5.0, math.log10(t_end), 200)
    try:
        meta = write_outputs(out, params, rates, t_s)
    except OSError as e:
        raise UsageError(f"--out {out!r}: {e}") from None
    crit = meta["critical_point"]
    print(f"wrote {', '.join(meta['files'])} to {out}")
    for s in meta["steady_state"]:
        g, m, t = s["gamma_dot_1_s"], s["mu_ss_pa_s"], s["tau_ss_pa"]
        print(f"  gdot = {g:g} 1/s: mu_ss = {m:.6g} Pa s, tau_ss = {t:.6g} Pa")
    if crit:
        print(f"  critical point: gdot_c = {crit['gamma_dot_c_1_s']:.6g} 1/s, tau_c = {crit['tau_c_pa']:.6g} Pa")
    else:
        print(f"  {meta['critical_point_note']}")
    return 0
