"""Results on disk: HDF5 frames written as they are produced, summary.json, checkpoints
(the pictures of a run: ``mpmjax.plotting``).

HDF5 schema of ``result.h5`` (see docs/output.md):

* root attributes: ``scene`` (name), ``scene_config_json`` (the full validated scene,
  JSON), ``params_json`` (material parameters and gravity, SI), ``code_version``,
  ``dim``, ``dt_s``, ``n_particles``, ``n_frames_planned``, ``units_json``, ``dtype`` (the
  run's ``numerics.dtype``: the float datasets are stored in it), ``complete`` (False until the
  run ends).
* ``/particles/vol0_m3`` (n,) initial particle volume [m^3; 2D: m^2 per m depth],
  ``/particles/mass_kg`` (n,) [kg; 2D: kg per m depth].
* ``/frames/t_s`` (F,), ``/frames/x_m`` (F, n, dim), ``/frames/v_m_s`` (F, n, dim),
  ``/frames/J`` (F, n), ``/frames/mu_pa_s`` (F, n), ``/frames/active`` (F, n) and one
  dataset per rheology internal field (``/frames/lambda`` for Coussot; with layers across a column's
  depth, ``numerics.depth_layers`` = K > 1, its thickness-weighted mean over the depth, and the layers
  themselves in ``/frames/lambda_layers`` (F, n, K), bed first); with column splitting
  (``numerics.split_levels`` > 0) also ``/frames/vol0_m3`` (F, n), the volumes that change as
  columns split (``frame_volumes`` reads either).  Frame 0 is the
  initial state.  Datasets grow by one frame at a time and the file is flushed after
  each frame, so an interrupted run keeps every frame written so far.  ``/frames/t_s`` is
  written last in a frame: its length is the number of complete frames, and
  ``read_result`` reads that many (a frame cut off half-way is ignored).
* root attributes written at the end: ``n_frames``, ``status`` (``complete``,
  ``interrupted`` or ``failed``) and, for a failed run, ``error``.

``checkpoint.h5`` (``write_checkpoint`` / ``read_checkpoint``): the full ``State`` pytree
after frame ``frame`` (one dataset per field, ``internal/<name>`` for the rheology
fields), written to a temporary file and renamed over the old one, so it is always a
complete checkpoint; attributes ``frame``, ``config_hash`` (``config_hash`` of the scene)
and ``meta_json`` (what the run needs to continue).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from pathlib import Path

import h5py
import numpy as np

from . import _basal
from ._scene import State

UNITS = {
    "t_s": "s",
    "x_m": "m",
    "v_m_s": "m/s",
    "J": "-",
    "mu_pa_s": "Pa s",
    "active": "bool",
    "vol0_m3": "m^3 (2D: m^2 per metre of depth)",
    "mass_kg": "kg (2D: kg per metre of depth)",
}


def atomic_write_text(path: Path, text: str):
    """Write ``text`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return None if not math.isfinite(f) else f
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def config_hash(cfg: dict) -> str:
    """SHA-256 of the validated scene (every key after defaults and overrides), as canonical JSON."""
    text = json.dumps(_jsonable(cfg), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def params_dict(params) -> dict:
    mat = params.material
    # a parameter the scene left out because the step does not use it (``_rheology.UNUSED``, inf) is null
    d = {f"material.{k}": _finite_or_none(float(np.asarray(v))) for k, v in mat._asdict().items()}
    d["gravity_m_s2"] = np.asarray(params.gravity).tolist()
    return d


# ``/frames`` dataset of an internal field's layers across the depth: its name plus this
LAYERS_SUFFIX = "_layers"


def internal_datasets(rheology) -> dict[str, tuple[str, str]]:
    """The law's internal variables: state name -> (dataset name in ``/frames``, unit), from
    its ``Internal`` declarations (Coussot: ``lam`` -> ``lambda``, dimensionless)."""
    return {i.name: (i.label, i.unit) for i in rheology.internals}


def units_of(rheology) -> dict[str, str]:
    """Unit of every dataset of a result of this law (``units_json``)."""
    return {**UNITS, **{label: unit for label, unit in internal_datasets(rheology).values()}}


class FrameWriter:
    """Appends frames to ``result.h5``; usable as a context manager."""

    def __init__(self, path, setup, code_version: str, keep_frames: int | None = None):
        """A new ``result.h5`` for ``setup``; or, with ``keep_frames``, reopen an existing one
        (an interrupted run of the same scene), keep its first ``keep_frames`` frames and
        append after them."""
        self.path = Path(path)
        if keep_frames is not None:
            self._reopen(setup, keep_frames)
            return
        self.f = h5py.File(self.path, "w")
        s = setup
        a = self.f.attrs
        a["scene"] = s.cfg["name"]
        a["scene_config_json"] = json.dumps(_jsonable(s.cfg))
        a["params_json"] = json.dumps(params_dict(s.params))
        a["code_version"] = code_version
        a["dim"] = s.scene.dim
        a["dt_s"] = s.scene.dt
        a["n_particles"] = s.scene.n_particles
        a["n_frames_planned"] = s.scene.n_frames + 1
        a["units_json"] = json.dumps(units_of(s.scene.rheology))
        a["dtype"] = s.scene.dtype  # the run's precision: the float datasets are stored in it
        a["complete"] = False
        a["runout_origin_m"] = float(s.info["runout_origin_m"])
        # where the run lies on the map (scene = map - map_origin_m; docs/output.md) and its breach release
        if "map" in s.info:
            m = s.info["map"]
            a["map_json"] = json.dumps(_jsonable(m))
            a["map_origin_m"] = np.asarray(m["map_origin_m"], float)
            a["crs_wkt"] = m["crs_wkt"] or ""
            a["epsg"] = -1 if m["epsg"] is None else int(m["epsg"])
        if "release" in s.info:
            a["release_json"] = json.dumps(_jsonable(s.info["release"]))
        st = s.state
        p = self.f.create_group("particles")
        p["vol0_m3"] = np.asarray(st.vol0)
        p["mass_kg"] = np.asarray(st.vol0) * float(s.params.material.rho)
        self.g = self.f.create_group("frames")
        self._layout(s)
        self.g.create_dataset("t_s", shape=(0,), maxshape=(None,), dtype="f8")
        # float fields in the run's own precision (a float64 run used to be stored as float32, which
        # cut its positions to ~1e-7 relative: 0.1 mm on a 3 km domain)
        fdt = "f8" if s.scene.dtype == "float64" else "f4"
        for name, shp in self.fields.items():
            dt = "u1" if name == "active" else fdt
            self.g.create_dataset(
                name,
                shape=(0,) + shp,
                maxshape=(None,) + shp,
                dtype=dt,
                chunks=(1,) + shp,
                compression="gzip",
                compression_opts=1,
            )
        self.n = 0

    def _layout(self, setup):
        """The per-frame datasets and their shapes (``self.fields``) and the internal fields' dataset names."""
        n, dim = setup.scene.n_particles, setup.scene.dim
        self.fields = {"x_m": (n, dim), "v_m_s": (n, dim), "J": (n,), "mu_pa_s": (n,), "active": (n,)}
        if setup.scene.split_levels > 0:  # columns split: their volumes change (_split)
            self.fields["vol0_m3"] = (n,)
        self.internal = {k: lab for k, (lab, _) in internal_datasets(setup.scene.rheology).items()}
        for k, arr in setup.state.internal.items():
            self.fields[self.internal[k]] = (n,)
            if np.ndim(arr) == 2:  # layers across the depth (``_basal.layered``): their mean, and the layers
                self.fields[self.internal[k] + LAYERS_SUFFIX] = (n, np.shape(arr)[1])

    def _reopen(self, setup, keep_frames: int):
        self.f = h5py.File(self.path, "r+")
        self.g = self.f["frames"]
        self._layout(setup)
        have = min(self.g[name].shape[0] for name in ("t_s", *self.fields))
        if have < keep_frames:
            self.f.close()
            raise ValueError(f"{self.path} holds {have} complete frames; the checkpoint needs {keep_frames}")
        for name in ("t_s", *self.fields):
            ds = self.g[name]
            ds.resize((keep_frames,) + ds.shape[1:])
        self.f.attrs["complete"] = False
        for k in ("status", "error", "n_frames"):
            if k in self.f.attrs:
                del self.f.attrs[k]
        self.n = keep_frames
        self.f.flush()

    def append(self, state):
        vals = {"x_m": state.x, "v_m_s": state.v, "J": state.J, "mu_pa_s": state.mu, "active": state.active,
                "vol0_m3": state.vol0}
        for k, arr in state.internal.items():
            if np.ndim(arr) == 2:
                arr = np.asarray(arr)
                vals[self.internal[k] + LAYERS_SUFFIX] = arr
                arr = arr @ _basal.layer_weights(arr.shape[1])[2]  # the mean over the depth
            vals[self.internal[k]] = arr
        for name in self.fields:
            ds = self.g[name]
            ds.resize((self.n + 1,) + ds.shape[1:])
            ds[self.n] = np.asarray(vals[name])
        # the time last: len(t_s) counts complete frames only
        self.g["t_s"].resize((self.n + 1,))
        self.g["t_s"][self.n] = float(state.t)
        self.n += 1
        self.f.flush()

    def close(self, complete: bool, status: str | None = None, error: str | None = None):
        if not self.f:  # already closed
            return
        self.f.attrs["complete"] = bool(complete)
        self.f.attrs["n_frames"] = self.n
        self.f.attrs["status"] = status or ("complete" if complete else "interrupted")
        if error is not None:
            self.f.attrs["error"] = error
        self.f.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.close(complete=exc_type is None)
        return False


def frame_volumes(res: dict) -> np.ndarray:
    """The particles' rest volumes of every saved frame of a ``read_result`` dict, (F, n) [m^3; 2D:
    m^2 per metre]: ``/frames/vol0_m3`` where columns split, else the constant ``/particles/vol0_m3``."""
    fr = res["frames"]
    if "vol0_m3" in fr:
        return np.asarray(fr["vol0_m3"], float)
    vol = np.asarray(res["particles"]["vol0_m3"], float)
    return np.broadcast_to(vol, (len(fr["t_s"]),) + vol.shape)


def _read_open(f) -> dict:
    attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
    # a frame is complete once its time is written (t_s is written last)
    nf = f["frames"]["t_s"].shape[0]
    frames = {k: f["frames"][k][:nf] for k in f["frames"]}
    particles = {k: f["particles"][k][()] for k in f["particles"]}
    return {"attrs": attrs, "frames": frames, "particles": particles}


def _same_frames(a: dict, b: dict) -> bool:
    n = min(len(a["frames"]["t_s"]), len(b["frames"]["t_s"]))
    return all(np.array_equal(a["frames"][k][:n], b["frames"][k][:n], equal_nan=k != "active") for k in a["frames"])


def read_result(path, live_retries: int = 50) -> dict:
    """Read ``result.h5`` back into numpy arrays: {'attrs': {...}, 'frames': {...}, 'particles': {...}}.

    Works on the file left by an interrupted or killed run, and on the file of a run that is
    still going.  The writer then holds the HDF5 file lock, so the file is opened without it;
    and since the writer's flush is not atomic, one read can catch it half-way (an HDF5 error,
    or the newest frames read as zeros).  A live file is therefore read twice, and the frames
    are returned only when both reads agree (up to ``live_retries`` tries 0.05 s apart)."""
    try:
        with h5py.File(path, "r") as f:
            return _read_open(f)
    except BlockingIOError:
        pass
    prev = None
    for attempt in range(live_retries + 1):
        try:
            with h5py.File(path, "r", locking=False) as f:
                cur = _read_open(f)
        except (OSError, KeyError):
            if attempt == live_retries:
                raise
            cur = None
        if cur is not None and prev is not None and _same_frames(prev, cur):
            return prev
        prev = cur
        time.sleep(0.05)
    raise OSError(f"{path}: a run is writing it and {live_retries + 1} reads did not agree; read it again later")


def write_checkpoint(path, state, frame: int, cfg_hash: str, meta: dict):
    """Write ``state`` (a ``State``) after ``frame`` frames to ``path`` atomically: a temporary
    file in the same folder, fsync'd, then renamed over ``path``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        for name, val in state._asdict().items():
            if val is None:  # a field the run does not use (State.p of an explicit-pressure run)
                continue
            if isinstance(val, dict):
                g = f.create_group(name)
                for k, arr in val.items():
                    g[k] = np.asarray(arr)
            else:
                f[name] = np.asarray(val)
        f.attrs["frame"] = int(frame)
        f.attrs["config_hash"] = cfg_hash
        f.attrs["meta_json"] = json.dumps(_jsonable(meta))
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def read_checkpoint(path):
    """``(state, frame, config_hash, meta)`` from ``write_checkpoint``; the state's arrays are
    numpy arrays with the dtypes they were written with (exact, bit for bit)."""
    with h5py.File(path, "r") as f:
        vals = {}
        for name in State._fields:
            if name not in f and name in State._field_defaults:
                continue
            obj = f[name]
            vals[name] = {k: obj[k][()] for k in obj} if isinstance(obj, h5py.Group) else obj[()]
        frame = int(f.attrs["frame"])
        h = f.attrs["config_hash"]
        meta = json.loads(f.attrs["meta_json"])
    return State(**vals), frame, (h.decode() if isinstance(h, bytes) else h), meta
