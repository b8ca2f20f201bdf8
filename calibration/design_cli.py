"""``mpmjax design``: rank candidate measurements by the information they add (``calibration.design``).

Candidates come from flags (``--profile-times``, ``--station-spacing-m``, ``--runout-sigma-m``,
``--shear-rates``, ``--rest-times``, ``--dambreak-rest-times``) and/or a TOML file
(``--candidates``) whose ``[[candidate]]`` tables have the keys of :data:`CANDIDATE_KEYS`
(docs/calibration.md, "Experiment design").  Exit status as ``mpmjax calibrate``: 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np

import mpmjax

from .cli import _guard, _kv
from .data import DataError, load_profiles
from .design import ProfileRequest, design, flow_curve_candidate, plot_design, profile_candidates, rheometer_candidate
from .design import table_lines
from .experiments import FlowCurveExperiment, ProfileExperiment
from .params import UNITS, ParameterSet
from .run import _load_flow_curve, _scene_overrides

REQUIRED = object()
# kind -> key -> (type, unit, default, meaning); default REQUIRED: must be given; None: see meaning
CANDIDATE_KEYS = {
    "profile": {
        "times_s": ("list", "s", REQUIRED, "profile times; one candidate per time and spacing"),
        "spacing_m": ("list", "m", None, "station spacing(s) (default: 2 cells)"),
        "sigma_m": ("float", "m", None, "height noise (default: the data's, as for calibrate)"),
        "x_range_m": ("pair", "m", None, "stations from lo to hi (default: the domain)"),
    },
    "runout": {"sigma_m": ("float", "m", REQUIRED, "noise of the final runout (at the scene's last time)")},
    "transient": {
        "rates_1_s": ("list", "1/s", REQUIRED, "shear rates, one constant-shear test each (one candidate)"),
        "rest_s": ("list", "s", [0.0], "rest before shearing; one candidate per rest time (0: from lambda0)"),
        "t_end_s": ("float", "s", 60.0, "length of each test"),
        "n_times": ("int", "-", 30, "samples, log-spaced from t_end_s/1000 to t_end_s"),
        "sigma_ln": ("float", "-", 0.05, "relative noise of the viscosity (std of ln mu)"),
    },
    "flow_curve": {
        "rates_1_s": ("list", "1/s", REQUIRED, "steady flow-curve rates"),
        "sigma_ln": ("float", "-", 0.05, "relative noise of the stress (std of ln tau)"),
    },
    "dambreak_after_rest": {
        "rest_s": ("list", "s", REQUIRED, "rest before the release; one simulation per rest time"),
        "times_s": ("list", "s", REQUIRED, "profile times"),
        "spacing_m": ("list", "m", None, "station spacing(s) (default: 2 cells)"),
        "sigma_m": ("float", "m", None, "height noise (default: the data's)"),
        "x_range_m": ("pair", "m", None, "stations from lo to hi (default: the domain)"),
    },
}


def _number(where, key, v, unit):
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ValueError(f"{where}: {key} = {v!r}; allowed: a finite number [{unit}]")
    return float(v)


def _check_entry(where, kind, entry):
    """Validate one candidate table (``where`` names it in messages); returns it with defaults."""
    if kind not in CANDIDATE_KEYS:
        raise ValueError(f"{where}: kind = {kind!r}; allowed: {', '.join(CANDIDATE_KEYS)}")
    keys = CANDIDATE_KEYS[kind]
    extra = sorted(set(entry) - set(keys) - {"kind"})
    if extra:
        raise ValueError(f"{where}: unknown key(s) {extra} for kind {kind!r}; allowed: {', '.join(keys)}")
    out = {"kind": kind}
    for k, (typ, unit, default, _) in keys.items():
        if k not in entry:
            if default is REQUIRED:
                raise ValueError(f"{where}: kind {kind!r} needs {k} [{unit}]")
            out[k] = default
            continue
        v = entry[k]
        if typ == "list":
            vs = v if isinstance(v, list) else [v]
            if not vs:
                raise ValueError(f"{where}: {k} is empty; give at least one value [{unit}]")
            vs = [_number(where, k, x, unit) for x in vs]
            lo_ok = (lambda x: x >= 0) if k in ("rest_s",) else (lambda x: x > 0)
            bad = [x for x in vs if not lo_ok(x)]
            if bad:
                rng = ">= 0" if k == "rest_s" else "> 0"
                raise ValueError(f"{where}: {k} = {bad[0]!r}; allowed range: {rng} [{unit}]")
            out[k] = vs
        elif typ == "pair":
            if not (isinstance(v, list) and len(v) == 2):
                raise ValueError(f"{where}: {k} = {v!r}; allowed: [lo, hi] [{unit}]")
            out[k] = tuple(_number(where, k, x, unit) for x in v)
        elif typ == "int":
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{where}: {k} = {v!r}; allowed range: integer >= 1")
            out[k] = v
        else:
            x = _number(where, k, v, unit)
            if not x > 0:
                raise ValueError(f"{where}: {k} = {x!r}; allowed range: > 0 [{unit}]")
            out[k] = x
    return out


def load_candidates(path) -> tuple[list, dict]:
    """([checked candidate tables], top-level settings) from a TOML file (``[[candidate]]`` tables,
    optional ``prior_factor``)."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    try:
        doc = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"{path}: not valid TOML: {e}") from None
    extra = sorted(set(doc) - {"candidate", "prior_factor"})
    if extra:
        raise ValueError(f"{path}: unknown key(s) {extra}; allowed: [[candidate]] tables and prior_factor")
    tables = doc.get("candidate", [])
    if not isinstance(tables, list) or not tables:
        raise ValueError(f"{path}: no [[candidate]] table")
    out = []
    for i, t in enumerate(tables, 1):
        where = f"{path}: candidate {i}"
        if "kind" not in t:
            raise ValueError(f"{where}: no kind; allowed: {', '.join(CANDIDATE_KEYS)}")
        out.append(_check_entry(where, t["kind"], t))
    settings = {}
    if "prior_factor" in doc:
        settings["prior_factor"] = _number(str(path), "prior_factor", doc["prior_factor"], "-")
    return out, settings


def _list(text, flag):
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"{flag} {text!r}: expected comma-separated numbers") from None


def candidates_from_flags(args) -> list:
    """Candidate tables from the command-line flags (checked like the TOML ones)."""
    out = []
    spacing = _list(args.station_spacing_m, "--station-spacing-m") if args.station_spacing_m else None
    if args.profile_times:
        e = {"times_s": _list(args.profile_times, "--profile-times"), "sigma_m": args.profile_sigma_m}
        if spacing:
            e["spacing_m"] = spacing
        out.append(_check_entry("--profile-times", "profile", {k: v for k, v in e.items() if v is not None}))
    elif spacing:
        raise ValueError("--station-spacing-m needs --profile-times (the times of the candidate profiles)")
    if args.runout_sigma_m is not None:
        out.append(_check_entry("--runout-sigma-m", "runout", {"sigma_m": args.runout_sigma_m}))
    rests = _list(args.rest_times, "--rest-times") if args.rest_times else [0.0]
    if args.shear_rates:
        for r in _list(args.shear_rates, "--shear-rates"):
            out.append(_check_entry("--shear-rates", "transient", {
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
        out.append(_check_entry("--dambreak-rest-times", "dambreak_after_rest",
                                {k: v for k, v in e.items() if v is not None}))
    return out


def add_design_arguments(p: argparse.ArgumentParser):
    p.add_argument("data", help="profiles in hand: CSV (x_m, h_m [, t_s, sigma_m]) or HDF5, as for calibrate")
    p.add_argument("--scene", default="dambreak-lab", help="built-in scene name or TOML path (default dambreak-lab)")
    p.add_argument("--fit", help="comma-separated parameters (default: the fitted ones of --estimate)")
    p.add_argument("--estimate", metavar="FIT_JSON", help="the current estimate: a fit.json of mpmjax calibrate")
    p.add_argument("--init", action="append", metavar="NAME=VALUE", help="estimate [SI] (overrides --estimate)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="scene override, e.g. domain.cell_size_m=0.02")
    p.add_argument("--sigma-m", type=float, help="noise of the data in hand [m] where they give none")
    p.add_argument("--bandwidth-m", type=float, help="kernel bandwidth of the model profile [m] (default: cell size)")
    p.add_argument("--flow-curve", help="rheometer flow-curve points in hand: CSV with gamma_dot_1_s, tau_pa")
    p.add_argument(
        "--candidates", metavar="TOML", help="candidate measurements ([[candidate]] tables, docs/calibration.md)"
    )
    p.add_argument("--profile-times", metavar="T1,T2", help="candidate profiles at these times [s]")
    p.add_argument("--station-spacing-m", metavar="S1,S2", help="their station spacing(s) [m] (default 2 cells)")
    p.add_argument("--profile-sigma-m", type=float, help="their height noise [m] (default: the data's)")
    p.add_argument("--runout-sigma-m", type=float, help="candidate: the final runout, with this noise [m]")
    p.add_argument("--shear-rates", metavar="R1,R2", help="candidate rheometer transients, one per rate [1/s]")
    p.add_argument("--rest-times", metavar="S1,S2", help="shear them after these rests [s] (0: from lambda0)")
    p.add_argument("--transient-t-end-s", type=float, default=60.0, help="length of each transient [s] (default 60)")
    p.add_argument("--transient-points", type=int, default=30, help="samples per transient (default 30, log-spaced)")
    p.add_argument("--sigma-ln", type=float, default=0.05, help="relative noise of rheometer data (default 0.05)")
    p.add_argument("--dambreak-rest-times", metavar="S1,S2",
                   help="candidate: the dam break repeated after these rests [s], profiles at --profile-times")
    p.add_argument(
        "--prior-factor", type=float, help="prior: each parameter known to this factor at 1 sigma (default 10)"
    )
    p.add_argument("--out", default="design-out", help="output folder (default design-out)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def _estimate(args):
    """(names, init) from --estimate / --fit / --init."""
    init = {}
    fitted = []
    if args.estimate:
        path = Path(args.estimate)
        try:
            doc = json.loads(path.read_text())
            fitted = list(doc["params"])
            init.update({k: float(v) for k, v in doc["params"].items()})
            init.update({k: float(v) for k, v in doc.get("fixed", {}).items()})
        except FileNotFoundError:
            raise DataError(f"--estimate {path}: no such file") from None
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise DataError(f"--estimate {path}: not a fit.json of mpmjax calibrate ({e})") from None
    init.update(_kv(args.init, "--init"))
    names = [s.strip() for s in args.fit.split(",") if s.strip()] if args.fit else fitted
    if not names:
        raise ValueError("--fit: name the parameters (e.g. --fit mu0,alpha,T,n,lambda0) or give --estimate FIT_JSON")
    return names, init


def run_design(args) -> dict:
    out = Path(args.out)
    log = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    profiles = load_profiles(args.data)
    names, init = _estimate(args)
    entries, settings = load_candidates(args.candidates) if args.candidates else ([], {})
    entries += candidates_from_flags(args)
    if not entries:
        raise ValueError("no candidate measurement: give --candidates TOML or --profile-times / --shear-rates / ...")
    prior = args.prior_factor if args.prior_factor is not None else settings.get("prior_factor", 10.0)
    times = [p.t_s for p in profiles] + [t for e in entries for t in e.get("times_s") or []]
    cfg0, overrides = _scene_overrides(args.scene, args.set, times, init)
    setup = mpmjax.build(mpmjax.load_scene(args.scene, overrides))
    h = setup.scene.h
    pset = ParameterSet.from_names(names, setup.params.material, init=init)
    theta = {k: pset.specs[k].init for k in pset.free}
    bw = args.bandwidth_m
    current = [ProfileExperiment(setup, profiles, bandwidth_m=bw, sigma_m=args.sigma_m, name=Path(args.data).name)]
    if args.flow_curve:
        current.append(FlowCurveExperiment(setup.params.material, *_load_flow_curve(args.flow_curve),
                                           name=Path(args.flow_curve).name))
    # candidate profile noise: as calibrate's default for the data in hand
    data_sigma = [float(np.median(p.sigma_m)) for p in profiles if p.sigma_m is not None]
    sigma0 = float(np.median(data_sigma)) if data_sigma else (
        args.sigma_m if args.sigma_m is not None else 0.05 * max(float(np.max(p.h_m)) for p in profiles))
    mat = setup.params.material
    plain, runout, cands = [], None, []
    for e in entries:
        k = e["kind"]
        if k in ("profile", "dambreak_after_rest"):
            reqs = [ProfileRequest(t, sp, e["sigma_m"] or sigma0, e["x_range_m"])
                    for t in e["times_s"] for sp in (e["spacing_m"] or [2 * h])]
            if k == "profile":
                plain += reqs
            else:
                for r in e["rest_s"]:
                    cands += profile_candidates(setup, reqs, bandwidth_m=bw, rest_s=r)
        elif k == "runout":
            runout = e["sigma_m"]
        elif k == "transient":
            for r in e["rest_s"]:
                cands.append(rheometer_candidate(mat, e["rates_1_s"], t_end_s=e["t_end_s"], n_times=e["n_times"],
                                                 sigma_ln=e["sigma_ln"], rest_s=r))
        else:
            cands.append(flow_curve_candidate(mat, e["rates_1_s"], sigma_ln=e["sigma_ln"]))
    if plain or runout is not None:
        cands = profile_candidates(setup, plain, bandwidth_m=bw, runout_sigma_m=runout) + cands
    log(f"design: {len(cands)} candidate(s), parameters {', '.join(pset.free)} at "
        + ", ".join(f"{k} = {v:.4g}" for k, v in theta.items()) + f"; scene {cfg0['name']} at h = {h:g} m")
    res = design(current, pset, theta, cands, prior_factor=prior)
    doc = {**res.as_dict(units={k: UNITS.get(k, "SI") for k in pset.free}), "scene": cfg0["name"],
           "scene_overrides": overrides, "data": str(args.data), "code_version": mpmjax.__version__}
    out.mkdir(parents=True, exist_ok=True)
    mpmjax.atomic_write_text(out / "design.json", json.dumps(doc, indent=1))
    plot_design(res, out / "design.png")
    for line in table_lines(res):
        print(line)
    log(f"wrote {out / 'design.json'}, {out / 'design.png'}")
    return doc


def cmd_design(args) -> int:
    return _guard(run_design, args)
