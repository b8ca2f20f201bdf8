"""The calibration package without long MPM runs: data loaders, parameter specs, the fit
loop and the Gauss-Newton uncertainty on problems with exact answers, the sweep (batched
equals one-by-one, sharded equals unsharded) and the command-line errors."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path
from typing import Any, NamedTuple

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mpmjax as m
from calibration.data import DataError, Profile, load_profiles, write_profiles_csv
from calibration.experiments import FlowCurveExperiment
from mpmjax import restate
from mpmjax._metrics import RunoutGauge
from calibration.fit import fit
from calibration.params import ParameterSet, ParamSpec
from calibration.sweep import parse_vary, sweep
from calibration.uncertainty import gauss_newton

ROOT = Path(__file__).resolve().parent.parent
TWIN = str(ROOT / "data" / "twin-small-dambreak.toml")


# ---------------------------------------------------------------------------- data
def _write(tmp_path, text, name="p.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_profiles_grouped_by_time_with_sigma(tmp_path):
    p = _write(
        tmp_path, "# origin: test\nt_s,x_m,h_m,sigma_m\n2,0,0.1,0.01\n1,0,0.2,0.02\n1,0.5,0.1,0.02\n2,0.5,0.05,0.01\n"
    )
    profs = load_profiles(p)
    assert [q.t_s for q in profs] == [1.0, 2.0]
    np.testing.assert_array_equal(profs[0].h_m, [0.2, 0.1])
    np.testing.assert_array_equal(profs[1].sigma_m, [0.01, 0.01])
    # round trip
    write_profiles_csv(tmp_path / "rt.csv", profs, "round trip")
    back = load_profiles(tmp_path / "rt.csv")
    for a, b in zip(profs, back, strict=True):
        np.testing.assert_allclose(a.h_m, b.h_m)
        assert a.t_s == b.t_s


@pytest.mark.parametrize(
    "text, needle",
    [
        ("x_m,h\n0,1\n1,1\n", "unknown column(s) 'h'"),
        ("x_m,t_s\n0,1\n1,1\n", "missing required column 'h_m'"),
        ("x_m,h_m\n0,0.1\n1,-0.2\n", "h_m (line 3) = -0.2; allowed range: >= 0"),
        ("x_m,h_m\n0,0.1\n0,0.2\n", "x_m (line 3) = 0.0 repeats"),
        ("x_m,h_m\n1,0.1\n0,0.2\n", "decreases"),
        ("x_m,h_m,sigma_m\n0,0.1,0\n1,0.2,0.1\n", "sigma_m (line 2) = 0.0; allowed range: > 0"),
        ("x_m,h_m\n0,abc\n1,0.2\n", "'abc' is not a number"),
        ("x_m,h_m\n0,nan\n1,0.2\n", "h_m (line 2) = nan"),
        ("x_m,h_m,t_s\n0,0.1,-1\n1,0.2,-1\n", "t_s line 2 = -1.0; allowed range: >= 0"),
        ("x_m,h_m\n0,0.1\n", "at least 2 are needed"),
        ("x_m,h_m\n", "no data rows"),
    ],
)
def test_csv_errors_name_field_value_and_range(tmp_path, text, needle):
    with pytest.raises(DataError) as e:
        load_profiles(_write(tmp_path, text))
    assert needle in str(e.value)


def test_hdf5_profiles_and_unit_check(tmp_path):
    p = tmp_path / "p.h5"
    with h5py.File(p, "w") as f:
        f["x_m"] = [0.0, 0.5, 1.0]
        f["h_m"] = [[0.2, 0.1, 0.0], [0.15, 0.1, 0.05]]
        f["t_s"] = [1.0, 3.0]
        f["sigma_m"] = 0.01
    profs = load_profiles(p)
    assert [q.t_s for q in profs] == [1.0, 3.0]
    np.testing.assert_array_equal(profs[1].h_m, [0.15, 0.1, 0.05])
    np.testing.assert_array_equal(profs[0].sigma_m, [0.01] * 3)
    with h5py.File(p, "a") as f:
        f["h_m"].attrs["units"] = "mm"
    with pytest.raises(DataError, match="h_m has units attribute 'mm'; expected 'm'"):
        load_profiles(p)


# ---------------------------------------------------------------------------- specs
class Mat(NamedTuple):
    a: jnp.ndarray
    b: jnp.ndarray


@pytest.mark.parametrize(
    "spec",
    [
        ParamSpec("a", 3.0, 0.1, 100.0, "log"),
        ParamSpec("a", 3.0, None, None, "log"),
        ParamSpec("a", 3.0, 1.0, None, "softplus"),
        ParamSpec("a", 3.0, -5.0, 5.0, "linear"),
        ParamSpec("a", -3.0, None, None, "identity"),
    ],
)
def test_transforms_round_trip_stay_in_bounds_and_are_scaled(spec):
    z0 = spec.to_z(spec.init)
    assert abs(z0) < 1e-12  # z = 0 is the initial value
    for theta in (spec.init * 0.5 if spec.init > 0 else -1.0, spec.init, 7.0 if spec.hi is None else 0.9 * spec.hi):
        if spec.lo is not None and theta <= spec.lo:
            continue
        assert float(spec.to_theta(spec.to_z(theta))) == pytest.approx(theta, rel=1e-10)
    # far steps stay inside the bounds
    for z in (-60.0, 60.0):
        th = float(spec.to_theta(jnp.float64(z)))
        assert spec.lo is None or th >= spec.lo
        assert spec.hi is None or th <= spec.hi
    # unit step in z = unit change of ln(theta) (log) or of theta/|init| (others) at the start
    d = float(jax.grad(spec.to_theta)(jnp.float64(0.0)))
    expected = spec.init if spec.transform == "log" else max(abs(spec.init), 1.0 if spec.transform == "identity" else 0)
    assert d == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize(
    "kw, needle",
    [
        (dict(name="a", init=-1.0, lo=0.1, hi=10.0), "log transform needs a value > 0"),
        (dict(name="a", init=20.0, lo=0.1, hi=10.0), "outside the allowed range (0.1, 10)"),
        (dict(name="a", init=1.0, lo=0.1, hi=None), "both bounds or neither"),
        (dict(name="a", init=1.0, transform="exp"), "allowed: log, softplus, linear, identity"),
        (dict(name="a", init=1.0, lo=0.0, hi=2.0, transform="softplus"), "lower bound only"),
    ],
)
def test_spec_errors(kw, needle):
    with pytest.raises(ValueError) as e:
        ParamSpec(**kw)
    assert needle in str(e.value)


def test_parameter_set_fixes_unfitted_inits_and_rejects_unknown_names():
    mat = Mat(jnp.float64(1.0), jnp.float64(2.0))
    ps = ParameterSet.from_names(["a"], mat, init={"a": 3.0, "b": 5.0}, bounds={"a": (0.1, 10.0)})
    assert ps.free == ("a",)
    got = ps.material_of({"a": 4.0})
    assert float(got.a) == 4.0 and float(got.b) == 5.0  # b fixed at its --init value
    with pytest.raises(ValueError, match="'c' is not a field of the scene's material Mat; allowed: a, b"):
        ParameterSet.from_names(["c"], mat)


# ------------------------------------------------------------ uncertainty: exact answers
class LinearExperiment:
    """r = (A theta - d) / sigma: Gauss-Newton is exact, cov = sigma^2 (A^T A)^-1."""

    def __init__(self, A, d, sigma, known=True):
        self.A, self.d, self.sigma, self.sigma_known, self.weight = A, d, sigma, known, 1.0
        self.name = "linear"

    def residuals(self, values):
        th = jnp.stack([values["a"], values["b"]])
        return (self.A @ th - self.d) / self.sigma


def test_gauss_newton_equals_the_exact_linear_covariance():
    rng = np.random.default_rng(0)
    A = jnp.asarray(rng.normal(size=(40, 2)) + np.array([3.0, 1.0]))
    d = A @ jnp.array([2.0, 0.5]) + 0.1 * rng.normal(size=40)
    ps = ParameterSet.from_names(
        ["a", "b"], Mat(jnp.float64(1.0), jnp.float64(1.0)), bounds={"a": (0.01, 100), "b": (0.01, 100)}
    )
    exp = LinearExperiment(A, d, 0.1)
    theta = dict(zip(("a", "b"), np.linalg.lstsq(np.asarray(A), np.asarray(d), rcond=None)[0], strict=True))
    u = gauss_newton([exp], ps, theta)
    cov = 0.01 * np.linalg.inv(np.asarray(A.T @ A))
    np.testing.assert_allclose(u.cov, cov, rtol=1e-9)
    np.testing.assert_allclose(u.std, np.sqrt(np.diag(cov)), rtol=1e-9)
    # unknown sigma: the residual variance sets the scale, s^2 = RSS / (N - p)
    u2 = gauss_newton([LinearExperiment(A, d, 1.0, known=False)], ps, theta)
    rss = float(np.sum((np.asarray(A) @ np.array([theta["a"], theta["b"]]) - np.asarray(d)) ** 2))
    np.testing.assert_allclose(u2.cov, rss / 38 * np.linalg.inv(np.asarray(A.T @ A)), rtol=1e-9)


def test_gauss_newton_flags_a_combination_the_data_cannot_separate():
    # the model depends on a*b only (like a flow curve on alpha*T): a and b are perfectly
    # anti-correlated in log space and the weakest direction is a^1 b^-1
    class Product:
        sigma_known, weight, name = True, 1.0, "product"

        def residuals(self, v):
            x = jnp.linspace(0.1, 1.0, 20)
            return (v["a"] * v["b"] * x - 2.0 * x) / 0.01

    ps = ParameterSet.from_names(
        ["a", "b"], Mat(jnp.float64(1.0), jnp.float64(1.0)), bounds={"a": (0.01, 100), "b": (0.01, 100)}
    )
    u = gauss_newton([Product()], ps, {"a": 1.0, "b": 2.0})
    assert any("least determined combination: a^1 * b^-1" in w for w in u.warnings), u.warnings
    assert any("not identifiable" in w or "poorly identified" in w for w in u.warnings)


# ---------------------------------------------------------------- fit loop: flow curve
def _flow_curve_twin():
    """(base, experiment, pset): 12 noisy points (2 % seeded noise) of the BASE flow curve, mu0, n
    and alpha free from a guess about a factor 2 off."""
    from mpmjax.rheometer import steady_flow_curve

    base = m.CoussotParams(*(jnp.float64(v) for v in (1850.0, 15000.0, 4.0, 1.0, 0.5, 2.5, 1.5, 5000.0)))
    g = np.logspace(-1, 2, 12)
    tau = np.asarray(steady_flow_curve(base, g)[0]) * np.exp(0.02 * np.random.default_rng(3).standard_normal(12))
    exp = FlowCurveExperiment(base, g, tau, sigma_ln=0.02)
    return base, exp, ParameterSet.from_names(["mu0", "n", "alpha"], base, init={"mu0": 8.0, "n": 5.0, "alpha": 0.5})


@pytest.fixture(scope="module")
def flow_curve_lbfgs():
    """(base, experiment, pset, a tightly converged L-BFGS fit) of ``_flow_curve_twin``: one fit for the two
    tests below (the recovery, and the reference of Levenberg-Marquardt's)."""
    base, exp, ps = _flow_curve_twin()
    return base, exp, ps, fit([exp], ps, method="lbfgs", max_iter=200, rtol=1e-10, patience=5, progress=False)


def test_fit_recovers_flow_curve_parameters_from_a_factor_two_guess(flow_curve_lbfgs):
    """Flow-curve twin: 12 noisy points (2 % noise) of the BASE flow curve; fit mu0, n and
    alpha (T fixed: the curve depends on alpha*T only).  The loss must fall by > 95 % and
    the parameters come back within 3 standard deviations of the Gauss-Newton estimate
    (the 99.7 % band of a well-posed linearised fit)."""
    base, exp, ps, r = flow_curve_lbfgs
    assert r.loss_final < 0.05 * r.loss_initial
    u = gauss_newton([exp], ps, r.params)
    for i, k in enumerate(u.names):
        assert abs(r.params[k] - float(getattr(base, k))) < 3 * u.std[i], (k, r.params[k], u.std[i])
    # multi-start by vmap finds the same optimum from 3 starts
    r3 = fit([exp], ps, method="lbfgs", max_iter=200, rtol=1e-10, n_starts=3, progress=False)
    assert r3.history.shape[1] == 3
    assert r3.loss_final == pytest.approx(r.loss_final, rel=1e-6)


def test_levenberg_marquardt_reaches_the_lbfgs_optimum_in_fewer_evaluations(flow_curve_lbfgs):
    """method="lm" (optimistix's Levenberg-Marquardt on the residual vector, Jacobian in forward
    mode) on the flow-curve twin above: the same minimum as a tightly converged L-BFGS (loss to
    1e-6 relative, parameters to 1e-3: the optimum is well-posed, and both stop within a
    relative loss change of 1e-10 of it), meeting its own stated criterion ("rtol": MINPACK's
    ftol test), with at most 0.6 times the model evaluations (Gauss-Newton steps converge
    quadratically on a small-residual problem; L-BFGS builds its curvature from gradients)."""
    _, exp, ps, ref = flow_curve_lbfgs
    r = fit([exp], ps, method="lm", max_iter=100, rtol=1e-10, progress=False)
    assert r.converged and r.reason == "rtol", r.reason
    assert r.loss_final == pytest.approx(ref.loss_final, rel=1e-6)
    for k in ps.free:
        assert r.params[k] == pytest.approx(ref.params[k], rel=1e-3), k
    n_lm = r.evaluations["residuals_and_jacobian"]
    n_lbfgs = ref.evaluations["value_and_grad"] + ref.evaluations["value"]
    assert n_lm <= 0.6 * n_lbfgs, (n_lm, n_lbfgs)  # measured: 8 against 17
    # multi-start: every start steps on its own trust region; the best reaches the same optimum
    r3 = fit([exp], ps, method="lm", max_iter=100, rtol=1e-10, n_starts=3, progress=False)
    assert r3.history.shape[1] == 3
    assert r3.loss_final == pytest.approx(ref.loss_final, rel=1e-6)


def test_levenberg_marquardt_stops_by_patience_where_the_linear_model_never_converges():
    """A residual with a kink at its minimum, r(a) = |a - 1| + 0.1: the linear model predicts the
    full decrease at every point (one residual: |P r| = |r|), so LM's Gauss-Newton test never
    fires, and the trust region halves its way to the kink (what a run whose derivative does not
    describe its loss at the step's scale does, docs/calibration.md "The fit loop").  The fit must
    still end, by the patience test ("rtol"), at the floor: loss within 1 % of 0.01 (measured
    0.010005 after 12 iterations, a = 1 + 2.7e-5), not at max_iter."""

    class Mat(NamedTuple):
        a: Any

    class Kink:
        sigma_known, weight, name = True, 1.0, "kink"

        def residuals(self, v):
            return jnp.stack([jnp.abs(v["a"] - 1.0) + 0.1])

    ps = ParameterSet.from_names(["a"], Mat(jnp.float64(3.0)), bounds={"a": (0.01, 100)})
    r = fit([Kink()], ps, method="lm", max_iter=100, rtol=1e-4, patience=3, progress=False)
    assert r.converged and r.reason == "rtol" and r.iterations < 100
    assert 0.01 <= r.loss_final < 0.0101 and abs(r.params["a"] - 1.0) < 1e-3


# ---------------------------------------------------------------------------- sweep
SMALL = ["domain.cell_size_m=0.06", "time.t_end_s=0.3", "time.n_frames=3"]


@pytest.fixture(scope="module")
def small_sweep():
    """Four cases (mu0 x n) of the coarse twin in batches of 3 on this process's one device (two batches, the
    second padded): run once, checked against one-by-one runs and against the same sweep on two devices."""
    return sweep(TWIN, {"mu0": [2.0, 6.0], "n": [2.0, 3.0]}, overrides=SMALL, chunk=3, progress=False)


def test_sweep_batched_equals_one_by_one(small_sweep):
    res = small_sweep
    assert res["chunk"] == 3 and len(res["cases"]) == 4  # two batches, the second padded
    setup = m.build(m.load_scene(TWIN, SMALL))
    for i, c in enumerate(res["cases"]):
        mat = setup.params.material._replace(mu0=jnp.float64(c["mu0"]), n=jnp.float64(c["n"]))
        p = setup.params._replace(material=mat)
        st = restate(setup.state, setup.scene, p)
        final, fr = m.simulate(setup.scene, st, p)
        info = setup.info
        far = float(
            m.runout(final.x, final.active, info["runout_axis"], info["runout_origin_m"], info["particle_spacing_m"])
        )
        assert res["final_runout_farthest_particle_m"][i] == pytest.approx(far, rel=1e-12, abs=1e-12)
        # the headline: the free-surface front, as summary.json defines it (docs/output.md "Runout")
        gauge = RunoutGauge.of(setup.scene, info)
        front = gauge.front(np.asarray(final.x), np.asarray(final.vol0), np.asarray(final.active))
        assert res["final_runout_m"][i] == pytest.approx(front, rel=1e-9, abs=1e-9)
        assert int(res["n_lost"][i]) == int(final.n_lost)
    # physics: a more viscous material runs out less far (same n)
    r = {(c["mu0"], c["n"]): res["final_runout_m"][i] for i, c in enumerate(res["cases"])}
    assert r[(6.0, 2.0)] < r[(2.0, 2.0)] and r[(6.0, 3.0)] < r[(2.0, 3.0)]


def _voellmy_slide(tmp_path) -> str:
    """A depth-averaged scene file: a 0.3 m x 0.15 m Bingham block (tau_y = 1 Pa) on a 30 degree DEM plane
    with Voellmy friction, 0.6 s at h = 2 cm (30 columns)."""
    xs = np.arange(0.0, 3.0 + 1e-9, 0.02)
    heights = ", ".join(f"{(3.0 - x) * math.tan(math.radians(30.0)):.6f}" for x in xs)
    path = tmp_path / "slide.toml"
    path.write_text(
        'name = "voellmy-slide"\n[model]\nformulation = "depth-averaged"\n'
        "[domain]\ndim = 2\nlo_m = [0.0, 0.0]\nhi_m = [3.0, 2.0]\ncell_size_m = 0.02\n"
        '[boundary]\nx_lo = "slip"\nx_hi = "open"\n[numerics]\nshape = "quadratic"\nppc = 2\ndtype = "float64"\n'
        '[material]\nmodel = "bingham"\nviscosity_pa_s = 0.01\nyield_stress_pa = 1.0\ndensity_kg_m3 = 1000.0\n'
        "bulk_modulus_pa = 1e5\n"
        f'[terrain]\ntype = "voellmy"\nheights_m = [{heights}]\norigin_m = [0.0]\nspacing_m = 0.02\nfriction = 0.2\n'
        "turbulence_m_s2 = 200.0\n[time]\nt_end_s = 0.6\nn_frames = 3\n"
        '[[bodies]]\ntype = "box"\nlo_m = [0.0, 1.6]\nhi_m = [0.3, 1.75]\n'
    )
    return str(path)


def test_a_sweep_of_the_basal_friction_equals_one_by_one(tmp_path, capsys):
    """``friction`` and ``turbulence`` (``Params.basal``, issue 33) vary inside a sweep's batch as the
    material parameters do: each lane equals its own run (``mpmjax.replace_parameters``, float64, to
    1e-12), and the physics orders them: more Coulomb friction runs out less far, a larger xi (less
    turbulent drag) further."""
    scene = _voellmy_slide(tmp_path)
    res = sweep(scene, {"friction": [0.1, 0.3], "turbulence": [100.0, 400.0]}, chunk=3, progress=True)
    assert "sweep: batch 2/2 (4/4 cases)" in capsys.readouterr().err  # the progress line of each batch
    setup = m.build(m.load_scene(scene))
    assert res["dt_s"] == setup.scene.dt  # the depth-averaged step's limit depends on no parameter varied
    info = setup.info
    for i, c in enumerate(res["cases"]):
        p = m.replace_parameters(setup.params, c, jnp.float64)
        final, _ = m.simulate(setup.scene, restate(setup.state, setup.scene, p), p)
        far = m.runout(final.x, final.active, info["runout_axis"], info["runout_origin_m"], info["particle_spacing_m"])
        assert res["final_runout_farthest_particle_m"][i] == pytest.approx(float(far), rel=1e-12, abs=1e-12)
    r = {(c["friction"], c["turbulence"]): res["final_runout_m"][i] for i, c in enumerate(res["cases"])}
    assert r[(0.3, 100.0)] < r[(0.1, 100.0)] and r[(0.3, 400.0)] < r[(0.1, 400.0)]
    assert r[(0.1, 100.0)] < r[(0.1, 400.0)] and r[(0.3, 100.0)] < r[(0.3, 400.0)]


def test_sweep_sharded_over_two_host_devices_equals_one_device(small_sweep):
    """The same four cases in one batch of 4 split over two host devices (a subprocess: the device count is
    fixed when jax starts) equal the one-device sweep of this process (``small_sweep``, batches of 3) to
    rounding.  Measured: identical; also to a one-device batch of 4 (2026-12-08)."""
    code = (
        "import json, sys; from calibration.sweep import sweep; import jax; "
        f"r = sweep({TWIN!r}, {{'mu0': [2.0, 6.0], 'n': [2.0, 3.0]}}, overrides={SMALL!r}, chunk=4, progress=False); "
        "print(json.dumps({'n_dev': jax.device_count(), 'chunk': r['chunk'], "
        "'runout': [float(v) for v in r['final_runout_m']]}))"
    )
    flags = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    env = dict(os.environ, XLA_FLAGS=flags, JAX_PLATFORMS="cpu")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert (small_sweep["n_devices"], out["n_dev"], out["chunk"]) == (1, 2, 4)  # 2 lanes per device
    np.testing.assert_allclose(out["runout"], small_sweep["final_runout_m"], rtol=1e-12)


def test_sweep_errors():
    with pytest.raises(ValueError, match="--vary tau_y: not a parameter of scene"):
        sweep(TWIN, {"tau_y": [1.0]}, overrides=SMALL, progress=False)
    with pytest.raises(m.SceneError, match="material.n"):
        sweep(TWIN, {"n": [2.0, -1.0]}, overrides=SMALL, progress=False)
    with pytest.raises(ValueError, match="expected NAME=V1,V2"):
        parse_vary(["n"])
    with pytest.raises(ValueError, match="values must be numbers"):
        parse_vary(["n=a,b"])


# ------------------------------------------------------------------------------ CLI
def _cli(*args):
    from mpmjax.cli import main

    return main(list(args))


def test_calibrate_cli_bad_input_exits_2(tmp_path, capsys):
    good = ROOT / "data" / "synthetic_twin_small_profiles.csv"
    bad = _write(tmp_path, "x_m,h_m\n0,0.1\n1,-1\n")
    assert _cli("calibrate", str(bad), "--scene", TWIN, "--fit", "mu0", "--out", str(tmp_path / "o")) == 2
    assert "h_m (line 3) = -1.0; allowed range: >= 0" in capsys.readouterr().err
    assert _cli("calibrate", str(good), "--scene", TWIN, "--fit", "tau_y", "--out", str(tmp_path / "o")) == 2
    assert "'tau_y' is not a field of the scene's material CoussotParams" in capsys.readouterr().err
    assert (
        _cli("calibrate", str(good), "--scene", TWIN, "--fit", "mu0", "--init", "mu0=-2", "--out", str(tmp_path / "o"))
        == 2
    )
    assert "material.mu0_pa_s" in capsys.readouterr().err
    lm_reverse = ("--fit", "mu0", "--gradient", "reverse", "--out", str(tmp_path))
    assert _cli("calibrate", str(good), "--scene", TWIN, *lm_reverse) == 2
    assert "--gradient reverse is invalid with --method lm; allowed: forward or auto" in capsys.readouterr().err
    assert _cli("calibrate", str(tmp_path / "none.csv"), "--scene", TWIN, "--fit", "mu0", "--out", str(tmp_path)) == 2
    assert "no such file" in capsys.readouterr().err
    assert _cli("sweep", TWIN, "--vary", "n=1,x", "--out", str(tmp_path / "s")) == 2


def test_sweep_cli_writes_table_json_and_plots(tmp_path, small_sweep):
    """``mpmjax sweep`` of the four cases of ``small_sweep``, in the same batches of 3 (the same compiled
    programs): the table, the JSON and the plot, with the Python sweep's runouts."""
    out = tmp_path / "sw"
    args = ["sweep", TWIN, "--vary", "mu0=2,6", "--vary", "n=2,3", "--chunk", "3", "--quiet", "--out", str(out)]
    for s in SMALL:
        args += ["--set", s]
    assert _cli(*args) == 0
    rows = (out / "sweep.csv").read_text().splitlines()
    assert rows[0] == "mu0,n,final_runout_m,time_to_rest_s,n_lost" and len(rows) == 5
    doc = json.loads((out / "sweep.json").read_text())
    assert doc["units"]["final_runout_m"] == "m" and len(doc["runout_m"][0]) == 4  # frames 0..3
    runout = [float(r.split(",")[2]) for r in rows[1:]]
    assert all(0.2 < v < 0.9 for v in runout)  # between the block and the far wall
    # the same cases, batches and programs as the Python sweep: equal (the table keeps 6 significant digits)
    np.testing.assert_allclose(doc["final_runout_m"], small_sweep["final_runout_m"], rtol=1e-12)
    np.testing.assert_allclose(runout, small_sweep["final_runout_m"], rtol=0, atol=5e-7)
    assert (out / "sweep_runout.png").stat().st_size > 1000


def test_time_offsets_match_frames():
    """Data times that are frame times map to them exactly; a time after the run is an error."""
    from calibration.experiments import ProfileExperiment

    s = m.build(m.load_scene(TWIN, SMALL))
    x = np.linspace(0, 0.9, 10)
    e = ProfileExperiment(s, [Profile(x, np.ones(10) * 0.01, 0.2), Profile(x, np.ones(10) * 0.01, None)])
    assert e.frame_index == (2, 3)
    assert max(abs(o) for o in e.time_offsets_s) < 1e-12
    with pytest.raises(ValueError, match=r"t_s = 0.5 s is after the end of the scene's run \(t_end = 0.3 s\)"):
        ProfileExperiment(s, [Profile(x, np.ones(10) * 0.01, 0.5)])
    assert math.isfinite(e.bandwidth_m) and e.bandwidth_m == pytest.approx(0.06)


# ------------------------------------------------------- identifiability, joint experiments
def _self_profile_experiment(setup, n_st=31, sigma=0.001):
    """A final profile made by the model itself (no noise): the Fisher matrix at the truth."""
    from calibration.experiments import ProfileExperiment

    x = np.linspace(0.0, 0.9, n_st)
    e0 = ProfileExperiment(setup, [Profile(x, np.ones(n_st) * 0.01, None)], bandwidth_m=0.04)
    h = np.asarray(e0.model_profiles({})[0])
    return ProfileExperiment(setup, [Profile(x, h, None, np.full(n_st, sigma))], bandwidth_m=0.04)


def test_alpha_and_T_from_a_final_profile_are_flagged():
    """The issue's example: alpha and T separately from one final profile.  The dam break at
    h = 0.03 m to 1.5 s constrains mostly their product (structure builds at 1/T and breaks at
    alpha * shear rate): measured correlation -0.96, weakest combination alpha^-0.73 T^1.  The
    analysis must warn about the correlation and name that combination."""
    s = m.build(m.load_scene(TWIN, ["domain.cell_size_m=0.03", "time.t_end_s=1.5", "time.n_frames=3"]))
    e = _self_profile_experiment(s)
    u = gauss_newton([e], ParameterSet.from_names(["alpha", "T"], s.params.material), {"alpha": 1.0, "T": 0.5})
    assert u.corr[0, 1] < -0.9
    assert any("alpha and T are strongly correlated" in w for w in u.warnings), u.warnings
    assert any("least determined combination: alpha^" in w for w in u.warnings), u.warnings
    # the weak direction changes alpha and T in opposite senses (their product is what is known)
    assert u.weakest["alpha"] * u.weakest["T"] < 0


@pytest.mark.slow  # CI time: tests/test_calibration_joint.py checks the same additivity per experiment step
def test_joint_experiments_add_information():
    """Profiles plus a rheometer flow curve (both with known sigma): the Fisher matrices add
    exactly, so no standard deviation of the joint fit exceeds either experiment's alone, and
    the joint loss is the weighted sum of the parts."""
    from calibration.experiments import joint_loss
    from mpmjax.rheometer import steady_flow_curve

    s = m.build(m.load_scene(TWIN, SMALL))
    e = _self_profile_experiment(s)
    mat = s.params.material
    g = np.logspace(-1, 2, 12)
    fc = FlowCurveExperiment(mat, g, np.asarray(steady_flow_curve(mat, jnp.asarray(g))[0]), sigma_ln=0.05, weight=2.0)
    ps = ParameterSet.from_names(["mu0", "n", "alpha"], mat)
    th = {"mu0": 4.0, "n": 2.5, "alpha": 1.0}
    up, uf, uj = (gauss_newton(x, ps, th) for x in ([e], [fc], [e, fc]))
    np.testing.assert_allclose(uj.fisher, up.fisher + uf.fisher, rtol=1e-10, atol=1e-12 * np.abs(uj.fisher).max())
    assert np.all(uj.std <= np.minimum(up.std, uf.std) * (1 + 1e-9)), (uj.std, up.std, uf.std)
    v = {"mu0": 5.0, "n": 2.0}
    r_fc = np.asarray(fc.residuals(v))
    parts = float(joint_loss([e], v)) + 2.0 * float(np.mean(r_fc**2))  # weight 2 on the flow curve
    assert float(joint_loss([e, fc], v)) == pytest.approx(parts, rel=1e-12)


def test_forward_mode_gradient_equals_reverse_mode():
    """fit's default gradient for few parameters is forward mode (vmapped jvp behind a
    custom_vjp, 2.6x cheaper than a reverse pass for 2 parameters on the twin scene); it must
    give the reverse-mode value and gradient to rounding, also under vmap (multi-start)."""
    from calibration.experiments import ProfileExperiment
    from calibration.fit import loss_function

    s = m.build(m.load_scene(TWIN, SMALL))
    x = np.linspace(0.0, 0.9, 12)
    e = ProfileExperiment(s, [Profile(x, np.full(12, 0.02), 0.3, np.full(12, 0.002))], bandwidth_m=0.06)
    ps = ParameterSet.from_names(["mu0", "n", "lambda0"], s.params.material, init={"mu0": 6.0})
    z = jnp.stack([ps.z0(jnp.float64), ps.z0(jnp.float64) + 0.3])
    # jitted, as fit compiles them (calibration.fit.Objective): one program each, not hundreds of eager ones
    rev = jax.jit(jax.vmap(jax.value_and_grad(loss_function([e], ps, "reverse"))))(z)
    fwd = jax.jit(jax.vmap(jax.value_and_grad(loss_function([e], ps, "forward"))))(z)
    np.testing.assert_allclose(fwd[0], rev[0], rtol=1e-12)
    np.testing.assert_allclose(fwd[1], rev[1], rtol=1e-9, atol=1e-12 * float(jnp.abs(rev[1]).max()))
    assert float(jnp.abs(rev[1]).min()) > 0
    with pytest.raises(ValueError, match="gradient = 'sideways' is invalid"):
        loss_function([e], ps, "sideways")


# ---------------------------------------------------------------------------- sweep plots
def _fake_sweep(final, profile_scale):
    """A sweep result as ``sweep`` returns it (3 values of n x 2 of mu0), no simulation."""
    from calibration.sweep import _cases

    vary = {"n": [1.5, 2.0, 3.0], "mu0": [1.0, 4.0]}
    cases = _cases(vary)
    x = np.linspace(0.0, 2.0, 101)
    prof = np.array([0.05 * np.exp(-x / (0.5 + profile_scale * i)) for i in range(len(cases))])
    return {
        "scene": "fake", "vary": vary, "cases": cases, "times_s": np.array([0.0, 5.0]),
        "final_runout_m": np.asarray(final, float), "profile_x_m": x, "profile_h_m": prof, "dim": 2,
    }


def _texts(ax):
    return [t.get_text() for t in ax.texts]


def test_sweep_plots_flat_sweep_says_no_sensitivity_on_an_absolute_axis():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.sweep import sweep_figures

    # final runouts within 0.3 mm of 1.19 m: the old plot drew this as steep lines labelled
    # in offset notation (+1.19); now an absolute axis of at least 1 cm and the words
    flat = _fake_sweep(1.19 + np.array([0.0, 1e-4, 3e-4, 2e-4, 1e-4, 0.0]), 0.0)
    figs = sweep_figures(flat)
    assert set(figs) == {"sweep_runout.png", "sweep_profiles.png"}
    fig = figs["sweep_runout.png"]
    fig.canvas.draw()
    for ax in fig.axes:
        assert any(t.startswith("no sensitivity") for t in _texts(ax)), ax.get_xlabel()
        assert ax.yaxis.get_major_formatter().get_useOffset() is False
        assert ax.yaxis.get_offset_text().get_text() == ""  # no "+1.19" / "1e-3" above the axis
        lo, hi = ax.get_ylim()
        assert hi - lo >= 0.01 - 1e-12 and lo < 1.19 < hi
        # tick labels are absolute metres
        ticks = [t.get_text().replace("−", "-") for t in ax.get_yticklabels() if t.get_text()]
        assert ticks and all(abs(float(t) - 1.19) < 0.01 for t in ticks)
    # the parameter ranges are in the titles
    assert "n = 1.5–3 (3 values), mu0 = 1–4 (2 values)" in fig._suptitle.get_text()
    assert fig.axes[0].get_title().startswith("n = 1.5–3")
    prof = figs["sweep_profiles.png"]
    (axp,) = prof.axes
    assert any(t.startswith("no sensitivity") for t in _texts(axp))  # identical profiles
    assert "n = 1.5–3 (3 values), mu0 = 1–4 (2 values)" in axp.get_title()
    assert axp.xaxis.get_major_formatter().get_useOffset() is False
    plt.close("all")


def test_sweep_plots_real_sensitivity_is_drawn():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.sweep import sweep_figures

    # runout falls with n by 5-10 cm (cases: n-major, mu0 minor); mu0 changes it by 0.5 mm only
    final = np.array([1.20, 1.2005, 1.15, 1.1505, 1.10, 1.1005])
    figs = sweep_figures(_fake_sweep(final, 0.2))
    ax_n, ax_mu = figs["sweep_runout.png"].axes
    assert not any(t.startswith("no sensitivity") for t in _texts(ax_n))
    assert "spread 100 mm" in ax_n.get_title()
    assert any(t.startswith("no sensitivity") for t in _texts(ax_mu))  # mu0 alone: 0.5 mm
    # one line per combination of the other parameter, through the stored values
    ys = sorted(tuple(np.round(ln.get_ydata(), 6)) for ln in ax_n.lines)
    assert ys == [(1.2, 1.15, 1.1), (1.2005, 1.1505, 1.1005)]
    (axp,) = figs["sweep_profiles.png"].axes
    assert not any(t.startswith("no sensitivity") for t in _texts(axp))
    plt.close("all")


def test_calibrate_cli_and_python_api_give_the_same_fit(tmp_path):
    """Issue 15: "everything runs from the CLI and from Python with the same results".  One small
    fit both ways: mu0 of a coarse dam break (h = 0.06 m, 0.3 s) against one made-up profile (a
    SYNTHETIC wedge, 20 mm at the wall to 0 at 0.6 m), 2 iterations of the default method
    (Levenberg-Marquardt) from mu0 = 6, at one level (``--levels 1``: since issue 32 the default
    fits two levels; this compares the fit itself with ``calibration.fit.fit``).  The CLI
    builds the same scene, experiment and parameter set from its options as the Python calls
    below, and both run the same deterministic float64 programs, so the fitted value, the loss
    history and the evaluation count agree to rounding (rtol 1e-9; measured: identical)."""
    from calibration.experiments import ProfileExperiment

    x = np.linspace(0.0, 0.9, 16)
    data = tmp_path / "p.csv"
    wedge = Profile(x, np.maximum(0.02 * (1 - x / 0.6), 0.0), 0.3, np.full(16, 0.002))
    write_profiles_csv(data, [wedge], "SYNTHETIC: a made-up wedge, not a model run")
    opts = ["--fit", "mu0", "--init", "mu0=6", "--bandwidth-m", "0.06", "--max-iter", "2", "--levels", "1", "--quiet"]
    args = ["calibrate", str(data), "--scene", TWIN, *opts, "--out", str(tmp_path / "o")]
    for o in SMALL:
        args += ["--set", o]
    assert _cli(*args) == 0
    doc = json.loads((tmp_path / "o" / "fit.json").read_text())

    # the same fit from Python
    setup = m.build(m.load_scene(TWIN, SMALL))
    exp = ProfileExperiment(setup, load_profiles(data), bandwidth_m=0.06)
    ps = ParameterSet.from_names(["mu0"], setup.params.material, init={"mu0": 6.0})
    r = fit([exp], ps, max_iter=2, progress=False)
    assert doc["iterations"] == r.iterations == 2 and doc["gradient"] == r.gradient == "forward"
    assert doc["params"]["mu0"] == pytest.approx(r.params["mu0"], rel=1e-9)
    np.testing.assert_allclose(doc["loss_history"], r.history[:, 0], rtol=1e-9)
    assert doc["evaluations"] == r.evaluations and r.evaluations["residuals_and_jacobian"] == 3
    assert r.history[-1, 0] < r.history[0, 0] and r.params["mu0"] != 6.0


def test_default_bounds_lie_inside_each_parameters_valid_range():
    """A fit may go anywhere inside its bounds, so the default bounds must be values the scene accepts:
    each parameter's calibration bounds sit inside the range its declaration validates (one fact,
    declared once in ``mpmjax.Param``)."""
    for name, p in m.material_parameters().items():
        if p.bounds is None:
            continue
        lo, hi = p.bounds
        assert lo < hi, name
        if p.lo is not None:
            assert lo > p.lo if p.lo_open else lo >= p.lo, (name, p.bounds, p.lo)
        if p.hi is not None:
            assert hi <= p.hi, (name, p.bounds, p.hi)
