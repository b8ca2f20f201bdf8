"""``mpmjax design``: its options, the candidate tables its flags describe, and its handler
(``calibration.design_run.run_design``).

Candidates come from flags (``--profile-times``, ``--station-spacing-m``, ``--runout-sigma-m``,
``--shear-rates``, ``--rest-times``, ``--dambreak-rest-times``), checked as the ``[[candidate]]``
tables of a ``--candidates`` TOML file are (``calibration.design_run.CANDIDATE_KEYS``;
docs/calibration.md, "Experiment design").
"""

from __future__ import annotations

from calibration.design_run import check_candidate, run_design

from ._calibrate import kv, names
from ._guard import number


def _list(text, flag):
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{flag} {text!r}: expected comma-separated numbers") from None


def _candidates_from_flags(args) -> list:
    """Candidate tables from the command-line flags (checked like the TOML ones)."""
    out = []
    spacing = _list(args.station_spacing_m, "--station-spacing-m") if args.station_spacing_m else None
    if args.profile_times:
        e = {"times_s": _list(args.profile_times, "--profile-times"), "sigma_m": args.profile_sigma_m}
        if spacing:
            e["spacing_m"] = spacing
        out.append(check_candidate("--profile-times", "profile", {k: v for k, v in e.items() if v is not None}))
    elif spacing:
        raise ValueError("--station-spacing-m needs --profile-times (the times of the candidate profiles)")
    if args.runout_sigma_m is not None:
        out.append(check_candidate("--runout-sigma-m", "runout", {"sigma_m": args.runout_sigma_m}))
    rests = _list(args.rest_times, "--rest-times") if args.rest_times else [0.0]
    if args.shear_rates:
        for r in _list(args.shear_rates, "--shear-rates"):
            out.append(check_candidate("--shear-rates", "transient", {
                "rates_1_s": [r], "rest_s": rests, "t_end_s": args.transient_t_end_s,
                "n_times": args.transient_points, "sigma_ln": args.sigma_ln}))
    elif args.rest_times:
        raise ValueError("--rest-times needs --shear-rates (the rate applied after the rest) [1/s]")
    if args.dambreak_rest_times:
        if not args.profile_times:
            raise ValueError("--dambreak-rest-times needs --profile-times (when the profiles are measured) [s]")
        e = {"rest_s": _list(args.dambreak_rest_times, "--dambreak-rest-times"),
             "times_s": _list(args.profile_times, "--profile-times"), "sigma_m": args.profile_sigma_m}
        if spacing:
            e["spacing_m"] = spacing
        out.append(check_candidate("--dambreak-rest-times", "dambreak_after_rest",
                                {k: v for k, v in e.items() if v is not None}))
    return out


def add_design_arguments(p) -> None:
    p.add_argument("data", help="profiles in hand: CSV (x_m, h_m [, t_s, sigma_m]) or HDF5, as for calibrate")
    p.add_argument("--scene", default="dambreak-lab", help="built-in scene name or TOML path (default dambreak-lab)")
    p.add_argument("--fit", help="comma-separated parameters (default: the fitted ones of --estimate)")
    p.add_argument("--estimate", metavar="FIT_JSON", help="the current estimate: a fit.json of mpmjax calibrate")
    p.add_argument("--init", action="append", metavar="NAME=VALUE", help="estimate [SI] (overrides --estimate)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="scene override, e.g. domain.cell_size_m=0.02")
    number(p, "--sigma-m", lo=0, lo_open=True, unit="m", help="noise of the data in hand [m] where they give none")
    number(p, "--bandwidth-m", lo=0, lo_open=True, unit="m",
           help="kernel bandwidth of the model profile [m] (default: cell size)")
    p.add_argument("--flow-curve", help="rheometer flow-curve points in hand: CSV with gamma_dot_1_s, tau_pa")
    p.add_argument(
        "--candidates", metavar="TOML", help="candidate measurements ([[candidate]] tables, docs/calibration.md)"
    )
    p.add_argument("--profile-times", metavar="T1,T2", help="candidate profiles at these times [s]")
    p.add_argument("--station-spacing-m", metavar="S1,S2", help="their station spacing(s) [m] (default 2 cells)")
    number(p, "--profile-sigma-m", lo=0, lo_open=True, unit="m", help="their height noise [m] (default: the data's)")
    number(p, "--runout-sigma-m", lo=0, lo_open=True, unit="m", help="candidate: the final runout, with this noise [m]")
    p.add_argument("--shear-rates", metavar="R1,R2", help="candidate rheometer transients, one per rate [1/s]")
    p.add_argument("--rest-times", metavar="S1,S2", help="shear them after these rests [s] (0: from lambda0)")
    number(p, "--transient-t-end-s", lo=0, lo_open=True, unit="s", default=60.0,
           help="length of each transient [s] (default 60)")
    number(p, "--transient-points", type=int, lo=2, default=30, help="samples per transient (default 30, log-spaced)")
    number(p, "--sigma-ln", lo=0, lo_open=True, unit="-", default=0.05,
           help="relative noise of rheometer data (default 0.05)")
    p.add_argument("--dambreak-rest-times", metavar="S1,S2",
                   help="candidate: the dam break repeated after these rests [s], profiles at --profile-times")
    p.add_argument(
        "--prior-factor", type=float, help="prior: each parameter known to this factor at 1 sigma (default 10)"
    )
    p.add_argument("--out", default="design-out", help="output folder (default design-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def cmd_design(args) -> int:
    entries = _candidates_from_flags(args)
    run_design(
        args.data,
        scene=args.scene,
        fit=names(args.fit) if args.fit else None,
        estimate=args.estimate,
        init=kv(args.init, "--init"),
        overrides=args.set,
        sigma_m=args.sigma_m,
        bandwidth_m=args.bandwidth_m,
        flow_curve=args.flow_curve,
        candidates=args.candidates,
        entries=entries,
        prior_factor=args.prior_factor,
        out=args.out,
        quiet=args.quiet,
    )
    return 0
