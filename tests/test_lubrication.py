"""The time-dependent lubrication slump (``mpmjax.studies.lubrication``), the reference of ``mpmjax
validate``'s inertia-free slumps at their frame times: checked against the two closed forms it must
reach (REFERENCE.md's static front x_inf, Huppert's Newtonian similarity front) and for its volume."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mpmjax.studies import lubrication as lub
from mpmjax.studies import validate

RHO, G, H0 = 1000.0, 9.81, 0.1
MU = math.sqrt(RHO**2 * G * H0**3)  # Galileo number 1, as validate's slumps


@pytest.mark.parametrize("bingham, aspect", [(0.05, 1), (0.5, 3)])
def test_the_slump_keeps_its_volume_and_stops_at_x_inf(bingham, aspect):
    """B = 0.05 (spreads everywhere) and B = 0.5 (only its edge yields): at 1000 s both are at rest,
    their wetted front within one cell (0.75 % of x_inf at 200 cells) of the closed-form x_inf,
    measured -0.25 % for both; the volume to round-off (measured 1e-15) at every time."""
    length = aspect * H0
    tau = bingham * RHO * G * H0**2 / length
    xinf = lub.static_front(length, H0, tau)
    assert xinf == pytest.approx(validate.lubrication_xinf(bingham, aspect), rel=1e-12)
    x, hs, steps = lub.slump_profiles(length, H0, tau, MU, [60.0, 1000.0])
    dx = x[1] - x[0]
    assert steps > 0 and np.all(hs >= -1e-9 * H0)
    np.testing.assert_allclose(hs.sum(axis=1) * dx, length * H0, rtol=1e-12)
    assert abs(lub.wetted_front(x, hs[-1], 1e-6 * H0) - xinf) <= dx
    # the headline front (10 % of the thickest) stands behind the tip of the static profile
    # h = sqrt(2 tau_y (x_inf - x)/(rho g)), by (0.1 h_max)^2 rho g / (2 tau_y): about 1 % of x_inf
    assert lub.headline_front(x, hs[-1]) < lub.wetted_front(x, hs[-1], 1e-6 * H0)


def test_a_newtonian_layer_tends_to_huppert_s_similarity_front():
    """tau_y = 0: the block's layer tends to Huppert's (1982) current, x_N = 1.411 (g q^3 t/(3 nu))^(1/5);
    at 400 s (x_N = 6.5 L) measured +0.50 % at 200 and 400 cells (+1.0 % at 20 s, the block's own length
    still showing); bound 1 %."""
    length = H0
    t = 400.0
    x, hs, _ = lub.slump_profiles(length, H0, 0.0, MU, [t])
    x_n = lub.HUPPERT_ETA * (G * (length * H0) ** 3 * t / (3.0 * MU / RHO)) ** 0.2
    assert lub.wetted_front(x, hs[-1], 1e-6 * H0) == pytest.approx(x_n, rel=0.01)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"length_m": 0.0}, "length_m"),
        ({"yield_stress_pa": -1.0}, "yield_stress_pa"),
        ({"viscosity_pa_s": float("nan")}, "viscosity_pa_s"),
        ({"times_s": [10.0, 5.0]}, "times_s"),
        ({"extent_m": 0.15}, "extent_m"),  # the B = 0.05 layer passes 0.15 m within 10 s
    ],
)
def test_bad_input_names_the_field(kwargs, field):
    args = {"length_m": H0, "height_m": H0, "yield_stress_pa": 49.05, "viscosity_pa_s": MU, "times_s": [10.0]}
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        lub.slump_profiles(**args)


def test_validate_records_the_lubrication_front_at_every_frame(tmp_path):
    """A ci-size slump (4 cells over H0, 0.5 s) through validate's case: the lubrication fronts at its
    frame times next to the run's, and the check at t_end (a ci run claims no pass); the page's third
    panel draws them."""
    rec = {"tolerance": 0.05, "status": "ok"}
    validate.CASES["slump-lubrication-B0.5-a3"].run("ci", {}, rec)
    validate.plot({"size": "ci", "cases": {"slump-lubrication-B0.5-a3": rec}}, tmp_path / "v.png")
    assert (tmp_path / "v.png").stat().st_size > 0
    assert len(rec["lubrication_fronts_m"]) == len(rec["fronts_m"]) == len(rec["frame_times_s"])
    names = [c["name"] for c in rec["checks"]]
    assert names == ["front vs x_inf", "front vs lubrication at t_end"]
    # after 0.5 s the layer has spread past the block's 0.3 m but not past x_inf = 0.4 m
    assert 0.3 < rec["lubrication_fronts_m"][-1] < rec["reference"]
