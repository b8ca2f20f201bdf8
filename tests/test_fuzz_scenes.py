"""Fuzzing the scene loader: ``validate`` + ``build`` either succeed or raise a
``SceneError`` that names the offending key -- never another exception.

Two generators: (1) garbage -- random subsets of known keys (and unknown ones) set to
values of the wrong type or out of range (None-like, bools, strings, lists, tables,
NaN, inf, huge and negative numbers, wrong vector lengths, malformed bodies/planes
tables); (2) valid-ish mutations of the built-in ``dambreak-lab`` scene on a small grid
(so that ``build`` stays cheap), with values near and beyond the edges of the allowed
ranges.  ``build`` is only called when validation passed and the grid is small.
"""

import copy
import math
import re
import tomllib

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import mpmjax
from mpmjax import cli
from mpmjax import SCHEMA, builtin_scenes

BASE = tomllib.loads(builtin_scenes()["dambreak-lab"].read_text())
# a small grid so that build() is cheap: 10 x 3 cells in 2D
SMALL_2D = {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.4, 0.12], "cell_size_m": 0.04}
SMALL_BODY_2D = {"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.12, 0.08]}
SMALL_3D = {"dim": 3, "lo_m": [0.0, 0.0, 0.0], "hi_m": [0.2, 0.08, 0.08], "cell_size_m": 0.04}
SMALL_BODY_3D = {"type": "box", "lo_m": [0.0, 0.0, 0.0], "hi_m": [0.08, 0.08, 0.08]}
MAX_BUILD_CELLS = 5000
MAX_BUILD_PARTICLES = 40000

NUMPY_REPR = re.compile(r"np\.\w+\(|array\(")  # a numpy repr in a message
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck))


def small_base(dim=2):
    raw = copy.deepcopy(BASE)
    raw["domain"] = copy.deepcopy(SMALL_2D if dim == 2 else SMALL_3D)
    raw["bodies"] = [copy.deepcopy(SMALL_BODY_2D if dim == 2 else SMALL_BODY_3D)]
    raw["time"] = {"t_end_s": 0.05, "n_frames": 2}
    if dim == 3:
        raw["boundary"].update(z_lo="noslip", z_hi="slip")
    return raw


def set_path(raw, key, val):
    """raw[a][b] = val for key 'a.b' (creating / overwriting tables on the way)."""
    parts = key.split(".")
    node = raw
    for p in parts[:-1]:
        if not isinstance(node.get(p), dict):
            node[p] = {}
        node = node[p]
    node[parts[-1]] = val


def del_path(raw, key):
    parts = key.split(".")
    node = raw
    for p in parts[:-1]:
        node = node.get(p)
        if not isinstance(node, dict):
            return
    node.pop(parts[-1], None)


def key_names(key):
    """Names an error about mutating ``key`` may use: the key, its table (bodies[0].lo_m ->
    bodies) and, for the dimension, the vector keys whose length it governs."""
    names = {key, key.split("[")[0]}
    parts = key.split(".")
    names |= {".".join(parts[:i]) for i in range(2, len(parts))}  # numerics.ppc.x replaced numerics.ppc
    if key.split(".")[0] in ("bodies", "boundary") and "[" in key:
        names.add(key.split("[")[0])
    if key == "domain.dim":
        names |= {k for k, s in SCHEMA.items() if s.type == "vec"} | {"bodies", "boundary.planes", "boundary.z"}
    return names


def check(raw, mutated):
    """The property: validate + build succeed, or raise SceneError naming a mutated key."""
    names = set().union(*(key_names(k) for k in mutated)) if mutated else set()
    try:
        cfg = mpmjax.validate(raw)
    except mpmjax.SceneError as e:
        msg = str(e)
        assert any(n in msg for n in names), (msg, sorted(mutated))
        assert not NUMPY_REPR.search(msg), msg  # plain numbers, never np.float64(5.0) (issue 17 item 6)
        return "invalid"
    ncell = np.prod(
        np.round((np.asarray(cfg["domain.hi_m"]) - np.asarray(cfg["domain.lo_m"])) / cfg["domain.cell_size_m"])
    )
    nppc = cfg["numerics.ppc"] ** cfg["domain.dim"]
    if ncell > MAX_BUILD_CELLS or ncell * nppc > MAX_BUILD_PARTICLES:
        return "valid, not built"
    try:
        setup = mpmjax.build(cfg)
    except mpmjax.SceneError as e:
        msg = str(e)
        assert any(n in msg for n in names), (msg, sorted(mutated))
        assert not NUMPY_REPR.search(msg), msg
        return "build error"
    sc = setup.scene
    assert math.isfinite(sc.dt) and sc.dt > 0 and sc.steps_per_frame >= 1
    assert sc.n_particles >= 1 and np.all(np.isfinite(np.asarray(setup.state.x)))
    return "built"


# ---------------------------------------------------------------- value strategies

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-5, 5),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.sampled_from([0, -1, 2**63, -(2**63), 10**400, -(10**400)]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(
        [
            0.0,
            -0.0,
            math.nan,
            math.inf,
            -math.inf,
            1e-320,
            5e-324,
            1e-45,
            1e-38,
            3.5e38,
            1e308,
            -1e308,
            1.7976931348623157e308,
        ]
    ),
    st.text(max_size=6),
    st.sampled_from(["", "nan", "inf", "1.0", "gimp", "coussot", "box", "periodic", "float64", "\x00", "[1, 2]"]),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=4), inner, max_size=3)),
    max_leaves=8,
)
vectors = st.one_of(
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
    st.lists(st.integers(min_value=-(10**400), max_value=10**400), max_size=4),
    st.lists(scalars, max_size=4),
)
bodyish = st.one_of(
    values,
    st.lists(
        st.one_of(
            values,
            st.fixed_dictionaries(
                {},
                optional={
                    "type": st.one_of(st.just("box"), values),
                    "lo_m": st.one_of(vectors, values),
                    "hi_m": st.one_of(vectors, values),
                    "velocity_m_s": st.one_of(vectors, values),
                    "extra": values,
                },
            ),
        ),
        max_size=3,
    ),
)
planeish = st.one_of(
    values,
    st.lists(
        st.one_of(
            values,
            st.fixed_dictionaries(
                {},
                optional={
                    "point_m": st.one_of(vectors, values),
                    "normal": st.one_of(vectors, values),
                    "type": st.one_of(st.sampled_from(["noslip", "slip", "symmetry", "periodic"]), values),
                    "bogus": values,
                },
            ),
        ),
        max_size=3,
    ),
)
KNOWN = sorted(SCHEMA)
UNKNOWN = [
    "domain.bogus",
    "materials",
    "material.mu_pa_s",
    "time.t_end",
    "bodies_extra",
    "gravity.g",
    "numerics.ppc.x",
    "zzz",
]


@st.composite
def garbage_scene(draw):
    dim = draw(st.sampled_from([2, 3]))
    raw = small_base(dim)
    mutated = set()
    for key in draw(st.lists(st.sampled_from(KNOWN), min_size=1, max_size=4, unique=True)):
        action = draw(st.sampled_from(["value", "value", "vector", "delete"]))
        if action == "delete":
            del_path(raw, key)
        elif key == "bodies":
            raw["bodies"] = draw(bodyish)
        elif key == "boundary.planes":
            raw["boundary"]["planes"] = draw(planeish)
        else:
            set_path(raw, key, draw(vectors if action == "vector" else values))
        mutated.add(key)
    if draw(st.booleans()):
        key = draw(st.sampled_from(UNKNOWN))
        set_path(raw, key, draw(values))
        mutated.add(key)
    if draw(st.integers(0, 9)) == 0:  # a whole section of the wrong type
        sec = draw(st.sampled_from(sorted({k.split(".")[0] for k in KNOWN})))
        raw[sec] = draw(scalars)
        mutated.add(sec)
    return raw, mutated


# valid-ish values: right types, values around the edges of (and beyond) the ranges
def number_near(spec):
    edges = [0.0, 1e-300, 1e-30, 1e-9, 0.5, 1.0, 3.0, 10.0, 1e6, 1e30, 1e300, -1.0]
    for b in (spec.lo, spec.hi):
        if b is not None:
            edges += [b, b - 1e-12, b + 1e-12, np.nextafter(b, np.inf), np.nextafter(b, -np.inf)]
    return st.one_of(
        st.sampled_from([float(e) for e in edges]), st.floats(min_value=-1e3, max_value=1e3, allow_nan=False)
    )


@st.composite
def validish_scene(draw):
    dim = draw(st.sampled_from([2, 2, 3]))
    raw = small_base(dim)
    raw["numerics"]["dtype"] = draw(st.sampled_from(["float32", "float64"]))
    mutated = {"numerics.dtype"}
    keys = [k for k in KNOWN if not k.startswith("domain.") and k not in ("bodies", "name", "description")]
    for key in draw(st.lists(st.sampled_from(keys), min_size=1, max_size=5, unique=True)):
        spec = SCHEMA[key]
        if spec.choices:
            val = draw(st.sampled_from(list(spec.choices) + ["bogus"]))
        elif spec.type is int:
            lo = -2 if spec.lo is None else int(spec.lo) - 1
            hi = 5 if spec.hi is None else min(int(spec.hi) + 1, 100)
            val = draw(st.integers(lo, hi))
        elif spec.type is float:
            val = draw(number_near(spec))
        elif spec.type == "vec":
            val = draw(
                st.lists(st.sampled_from([0.0, 1.0, -1.0, 0.05, 1e-320, 1e300]), min_size=dim - 1, max_size=dim + 1)
            )
        else:  # boundary.planes
            val = draw(
                st.lists(
                    st.fixed_dictionaries(
                        {
                            "point_m": st.lists(
                                st.sampled_from([0.0, 0.04, 0.1, -1.0, 1e300]), min_size=dim, max_size=dim
                            ),
                            "normal": st.lists(
                                st.sampled_from([0.0, 1.0, -1.0, 0.5, 1e-200, 1e200]), min_size=dim, max_size=dim
                            ),
                            "type": st.sampled_from(["noslip", "slip", "symmetry"]),
                        }
                    ),
                    max_size=2,
                )
            )
        set_path(raw, key, val)
        mutated.add(key)
    # bodies: 1-3 boxes on the grid's lattice, sometimes poking out or inverted
    if draw(st.booleans()):
        bodies = []
        size = raw["domain"]["hi_m"]
        for _ in range(draw(st.integers(1, 3))):
            lo = [draw(st.sampled_from([0.0, 0.04, 0.08, -0.04])) for _ in range(dim)]
            hi = [a + draw(st.sampled_from([0.04, 0.08, 0.0, -0.04, 1e-12])) for a in lo]
            body = {"type": "box", "lo_m": lo, "hi_m": hi}
            if draw(st.booleans()):
                body["velocity_m_s"] = [draw(st.sampled_from([0.0, 1.0, -3.0, 1e300, 1e39])) for _ in range(dim)]
            bodies.append(body)
        raw["bodies"] = bodies
        mutated.add("bodies")
        assert len(size) == dim
    # domain: scale the cell size / box while keeping it small, or break it
    if draw(st.booleans()):
        choice = draw(st.sampled_from(["h_half", "h_bad", "h_tiny", "hi_lo_swap", "shift", "huge"]))
        d = raw["domain"]
        if choice == "h_half":
            d["cell_size_m"] = d["cell_size_m"] / 2
        elif choice == "h_bad":
            d["cell_size_m"] = 0.03
        elif choice == "h_tiny":
            d["cell_size_m"] = draw(st.sampled_from([1e-300, 5e-324, 1e-9]))
        elif choice == "hi_lo_swap":
            d["lo_m"], d["hi_m"] = d["hi_m"], d["lo_m"]
        elif choice == "shift":
            d["lo_m"] = [a - 0.04 for a in d["lo_m"]]
        else:
            d["lo_m"] = [-1e308] * dim
            d["hi_m"] = [1e308] * dim
        mutated |= {"domain.cell_size_m", "domain.lo_m", "domain.hi_m"}
    return raw, mutated


@FUZZ
@given(garbage_scene())
def test_fuzz_garbage_scenes(case):
    raw, mutated = case
    event(check(raw, mutated))


@FUZZ
@given(validish_scene())
def test_fuzz_validish_scenes(case):
    raw, mutated = case
    event(check(raw, mutated))


@FUZZ
@given(
    st.one_of(values, st.dictionaries(st.sampled_from(KNOWN + ["domain", "material", "bodies"]), values, max_size=4))
)
def test_fuzz_arbitrary_documents(raw):
    """Whole documents of random shape: SceneError (any message) or nothing else."""
    try:
        mpmjax.validate(raw)
    except mpmjax.SceneError:
        pass


@FUZZ
@given(st.sampled_from(KNOWN), st.text(max_size=12))
def test_fuzz_overrides(key, text):
    """``--set key=value`` with random value text goes through load_scene's TOML parsing."""
    try:
        mpmjax.load_scene("dambreak-lab", [f"{key}={text}", "domain.cell_size_m=0.04"])
    except mpmjax.SceneError as e:
        assert key in str(e) or "domain.cell_size_m" in str(e) or "bodies" in str(e), str(e)


def test_known_crashers():
    """Regressions: inputs that used to raise OverflowError / ZeroDivisionError / ValueError."""
    cases = [
        ("domain.lo_m", [-1e308, -1e308]),  # domain size overflows -> int(inf)
        ("domain.hi_m", [10**400, 1.0]),  # int too large to convert to float
        ("domain.cell_size_m", 5e-324),  # cell count overflows -> int(inf)
        ("material.density_kg_m3", 10**400),
        ("material.density_kg_m3", 1e-300),  # below the key's range (>= 1 kg/m^3)
        ("material.mu_max_pa_s", 1e-300),  # float32: mu_max -> 0 -> division by zero
        ("material.bulk_modulus_pa", 1e300),  # float32: kappa -> inf -> dt = 0
        ("time.t_end_s", 1e308),  # steps per frame -> inf -> math.ceil(inf)
        ("bodies", [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.08, 0.08], 1: 2, "zz": 3}]),  # sorted([1, "zz"])
        ("boundary.planes", [{"point_m": [0.0, 0.0], "normal": [1e308, 1e308]}]),  # |normal| = inf
        ("bodies", [{"type": ["box"], "lo_m": [0.0, 0.0], "hi_m": [0.08, 0.08]}]),
        ("name", "a\x00b"),  # h5py: VLEN strings do not support embedded NULLs
        ("gate.normal", [0.0, 0.0]),
    ]
    for key, val in cases:
        raw = small_base()
        set_path(raw, key, val)
        if key == "gate.normal":
            set_path(raw, "gate.point_m", [0.1, 0.0])
        assert check(raw, {key}) != "built", key
    # float64: the same extremes (but the density, out of its range) reach build() and the time-step limits
    # a density below 1 kg/m^3 is out of range (with the grid pressure 1e-300 used to build and NaN at step 1)
    raw = small_base()
    raw["numerics"]["dtype"] = "float64"
    set_path(raw, "material.density_kg_m3", 1e-300)
    assert check(raw, {"material.density_kg_m3"}) == "invalid"
    for key, val in [
        ("material.bulk_modulus_pa", 1e300),
        ("gravity.g_m_s2", 1e308),
        ("time.t_end_s", 1e308),
        ("time.t_end_s", 1e300),
    ]:
        raw = small_base()
        raw["numerics"]["dtype"] = "float64"
        raw["numerics"]["pressure"] = "explicit"  # the sound speed's limit, where kappa and rho meet
        set_path(raw, key, val)
        assert check(raw, {key}) == "build error", key
    raw = small_base()
    raw["numerics"].update(dtype="float64", viscous_update="explicit")
    raw["material"] = {"model": "newtonian", "density_kg_m3": 1850.0, "bulk_modulus_pa": 15000.0}
    raw["material"]["viscosity_pa_s"] = 1e300  # dt_visc ~ 1e-300: steps per frame overflow
    msg = _build_error(raw)
    assert "material.viscosity_pa_s" in msg and "time.t_end_s" in msg, msg
    assert check("not a table", {""}) == "invalid"
    assert check([1, 2], {""}) == "invalid"
    # load_scene resolves terrain.csv against the scene's folder: a NUL in it raised ValueError
    # from pathlib (found by test_fuzz_overrides with key='terrain.csv', text='\x00')
    with pytest.raises(mpmjax.SceneError, match="terrain.csv"):
        mpmjax.load_scene("dambreak-lab", {"terrain.csv": "\x00"})


def _build_error(raw):
    try:
        mpmjax.build(mpmjax.validate(raw))
    except mpmjax.SceneError as e:
        return str(e)
    raise AssertionError("expected a SceneError")


def test_load_scene_rejects_unreadable_toml(tmp_path):
    cases = {
        "binary.toml": b'name = "\xff\xfe"\n',
        "hugeint.toml": b"x = " + b"1" * 5000 + b"\n",
        "deep.toml": b"x = " + b"[" * 3000 + b"]" * 3000 + b"\n",
    }
    for name, data in cases.items():
        path = tmp_path / name
        path.write_bytes(data)
        try:
            mpmjax.load_scene(path)
        except mpmjax.SceneError as e:
            assert str(path) in str(e)
        else:
            raise AssertionError(name)
    for text in ["1" * 5000, "[" * 3000 + "]" * 3000]:
        try:
            mpmjax.load_scene("dambreak-lab", [f"material.mu0_pa_s={text}"])
        except mpmjax.SceneError as e:
            assert "material.mu0_pa_s" in str(e)


BROKEN_TOML = {
    "syntax": ('name = "x"\n[domain\ndim = 2\n', ["not valid TOML"]),
    "unknown_key": (None, ["material.viscosity_pas"]),
    "negative_density": (None, ["material.density_kg_m3", "-1850"]),
    "outside_domain": (None, ["bodies[0]", "outside the domain"]),
    "nul_name": (None, ["name"]),
    "not_utf8": (b'name = "\xff"\n', ["UTF-8"]),
    "huge_int": (b"[time]\nn_frames = " + b"9" * 5000 + b"\n", ["not valid TOML"]),
}


def _broken_file(tmp_path, kind):
    text, words = BROKEN_TOML[kind]
    path = tmp_path / f"{kind}.toml"
    if text is None:
        src = builtin_scenes()["dambreak-lab"].read_text()
        if kind == "unknown_key":
            src = src.replace("mu0_pa_s = 4.0", "mu0_pa_s = 4.0\nviscosity_pas = 2.0")
        elif kind == "negative_density":
            src = src.replace("density_kg_m3 = 1850.0", "density_kg_m3 = -1850.0")
        elif kind == "outside_domain":
            src = src.replace("hi_m = [0.2, 0.2]", "hi_m = [0.2, 0.5]")
        elif kind == "nul_name":
            src = src.replace('name = "dambreak-lab"', 'name = "dam\\u0000break"')
        path.write_text(src)
    elif isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path, words


def test_cli_broken_toml_exit_2(tmp_path, capsys):
    for kind in BROKEN_TOML:
        path, words = _broken_file(tmp_path, kind)
        rc = cli.main(["run", str(path), "--quiet", "--out", str(tmp_path / f"out_{kind}")])
        cap = capsys.readouterr()
        assert rc == 2, kind
        assert "Traceback" not in cap.err and "Traceback" not in cap.out, kind
        for w in words:
            assert w in cap.err, (kind, w, cap.err)
        assert not (tmp_path / f"out_{kind}" / "result.h5").exists()
