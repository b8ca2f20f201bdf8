"""The XDMF sidecar (result.xdmf): a temporal collection of Polyvertex grids whose
HyperSlabs select, frame by frame, datasets that exist in result.h5 with matching shapes."""

import copy
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

import mpmjax
from mpmjax import builtin_scenes
from mpmjax._io import FrameWriter
from mpmjax._xdmf import write_xdmf

ATTRIBUTE_TYPES = {"Scalar", "Vector", "Tensor", "Tensor6", "Matrix"}
CENTERS = {"Node", "Cell", "Grid", "Face", "Edge"}


def _parse_hyperslab(item):
    """-> (h5 file, dataset path, full shape, start, stride, count, selected dims)."""
    assert item.tag == "DataItem" and item.get("ItemType") == "HyperSlab"
    sel_dims = tuple(int(a) for a in item.get("Dimensions").split())
    sel, src = list(item)
    rows, cols = (int(a) for a in sel.get("Dimensions").split())
    assert rows == 3 and sel.get("Format") == "XML"
    vals = np.array(sel.text.split(), int).reshape(rows, cols)
    assert src.get("Format") == "HDF"
    shape = tuple(int(a) for a in src.get("Dimensions").split())
    assert len(shape) == cols
    fname, dpath = src.text.strip().split(":", 1)
    return fname, dpath, shape, vals[0], vals[1], vals[2], sel_dims


def check_xdmf(xdmf_path: Path, h5_path: Path):
    root = ET.parse(xdmf_path).getroot()
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    colls = root.findall("./Domain/Grid")
    assert len(colls) == 1
    coll = colls[0]
    assert coll.get("GridType") == "Collection" and coll.get("CollectionType") == "Temporal"
    grids = coll.findall("Grid")
    with h5py.File(h5_path, "r") as f:
        t = f["frames/t_s"][()]
        F, n, dim = f["frames/x_m"].shape
        assert len(grids) == F == len(t)
        per_particle = {k for k in f["frames"] if k not in ("t_s", "x_m")}
        for k, g in enumerate(grids):
            assert float(g.find("Time").get("Value")) == t[k]
            topo = g.find("Topology")
            assert topo.get("TopologyType") == "Polyvertex" and int(topo.get("NumberOfElements")) == n
            geom = g.find("Geometry")
            assert geom.get("GeometryType") == ("XY" if dim == 2 else "XYZ")
            items = [("x_m", "Geometry", geom.find("DataItem"))]
            names = set()
            for att in g.findall("Attribute"):
                assert att.get("Center") in CENTERS and att.get("Center") == "Node"
                assert att.get("AttributeType") in ATTRIBUTE_TYPES
                names.add(att.get("Name"))
                items.append((att.get("Name"), att.get("AttributeType"), att.find("DataItem")))
            assert names == per_particle, (names, per_particle)
            for name, kind, item in items:
                fname, dpath, shape, start, stride, count, sel_dims = _parse_hyperslab(item)
                assert fname == h5_path.name  # relative to the xdmf file
                assert (xdmf_path.parent / fname).resolve() == h5_path.resolve()
                assert dpath in f and dpath == f"/frames/{name}"
                ds = f[dpath]
                assert shape == ds.shape
                assert start[0] == k < ds.shape[0] and np.all(start[1:] == 0)
                assert np.all(stride == 1)
                assert tuple(count) == sel_dims == (1,) + ds.shape[1:]
                assert np.all(start + (count - 1) * stride < np.asarray(ds.shape))
                assert ds.shape[1] == n
                if kind in ("Vector", "Geometry"):
                    assert ds.shape[2:] == (dim,)
                else:
                    assert kind == "Scalar" and ds.ndim == 2
                assert item[1].get("NumberType") in ("Float", "UChar")
                assert int(item[1].get("Precision")) == ds.dtype.itemsize
    return grids


def test_xdmf_from_cli_run(tmp_path):
    out = tmp_path / "run"
    mpmjax.run_scene("dambreak-lab", out, ["time.t_end_s=0.05", "time.n_frames=2", "domain.cell_size_m=0.02"], quiet=True)
    xdmf, h5 = out / "result.xdmf", out / "result.h5"
    assert xdmf.is_file() and not (out / "result.xdmf.tmp").exists()
    grids = check_xdmf(xdmf, h5)
    assert len(grids) == 3  # frame 0 (initial) + 2 frames
    names = {a.get("Name") for a in grids[0].findall("Attribute")}
    assert names == {"v_m_s", "J", "mu_pa_s", "active", "lambda"}  # Coussot: lambda present
    kinds = {a.get("Name"): a.get("AttributeType") for a in grids[0].findall("Attribute")}
    assert kinds["v_m_s"] == "Vector" and kinds["J"] == kinds["lambda"] == "Scalar"


def _tiny_scene(dim, model):
    raw = tomllib.loads(builtin_scenes()["dambreak-lab"].read_text())
    raw = copy.deepcopy(raw)
    if model != raw["material"]["model"]:  # another law: only the keys every law reads
        raw["material"] = {k: raw["material"][k] for k in ("density_kg_m3", "bulk_modulus_pa")} | {"model": model}
    raw["time"] = {"t_end_s": 0.01, "n_frames": 2}
    if dim == 2:
        raw["domain"] = {"dim": 2, "lo_m": [0.0, 0.0], "hi_m": [0.2, 0.1], "cell_size_m": 0.05}
        raw["bodies"] = [{"type": "box", "lo_m": [0.0, 0.0], "hi_m": [0.1, 0.05]}]
    else:
        raw["domain"] = {"dim": 3, "lo_m": [0.0, 0.0, 0.0], "hi_m": [0.2, 0.1, 0.1], "cell_size_m": 0.05}
        raw["bodies"] = [{"type": "box", "lo_m": [0.0, 0.0, 0.0], "hi_m": [0.1, 0.05, 0.05]}]
        raw["boundary"].update(z_lo="noslip", z_hi="slip")
    return mpmjax.build(mpmjax.validate(raw))


@pytest.mark.parametrize("dim, model", [(3, "coussot"), (2, "newtonian")])
def test_xdmf_written_from_frame_writer(tmp_path, dim, model):
    setup = _tiny_scene(dim, model)
    h5 = tmp_path / "result.h5"
    with FrameWriter(h5, setup, "test") as w:
        st = setup.state
        for k in range(3):
            w.append(st._replace(t=st.t + 0.005 * k, x=st.x + 0.001 * k))
    path = write_xdmf(h5)
    assert path == tmp_path / "result.xdmf"
    grids = check_xdmf(path, h5)
    assert len(grids) == 3
    names = {a.get("Name") for a in grids[0].findall("Attribute")}
    assert ("lambda" in names) == (model == "coussot")
    # an xdmf elsewhere refers to the h5 file by a relative path
    other = tmp_path / "views" / "r.xdmf"
    other.parent.mkdir()
    write_xdmf(h5, other)
    src = ET.parse(other).getroot().find(".//Geometry/DataItem/DataItem[@Format='HDF']").text
    assert src == "../result.h5:/frames/x_m"
