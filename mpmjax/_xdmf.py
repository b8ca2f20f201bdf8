"""XDMF 3 sidecar for ``result.h5``: open the particle frames in ParaView or VisIt.

``write_xdmf(h5_path)`` writes ``result.xdmf`` beside ``result.h5``: a temporal
collection (``GridType="Collection" CollectionType="Temporal"``) with one ``Polyvertex``
grid per frame.  Every array is a HyperSlab of the HDF5 datasets (no data is copied):
frame ``k`` selects start ``(k, 0[, 0])``, stride 1, count ``(1, n[, dim])`` of
``/frames/x_m`` (geometry, XY in 2D / XYZ in 3D) and of each per-particle field
(``v_m_s`` vector, ``J``, ``mu_pa_s``, ``active``, ``lambda`` and any other rheology
field: scalars; a field's layers across a depth-averaged column, ``lambda_layers``, are not exported), all
node-centred.  The HDF5 path is written relative to the XDMF file
(just the file name when both lie in one folder), so the pair can be moved together.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np

from ._io import LAYERS_SUFFIX, atomic_write_text

FIELD_ORDER = ("v_m_s", "J", "mu_pa_s", "active", "lambda")


def _number_type(dtype: np.dtype) -> tuple[str, int]:
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return "Float", dtype.itemsize
    if dtype.kind == "u":
        return ("UChar" if dtype.itemsize == 1 else "UInt"), dtype.itemsize
    if dtype.kind == "b":
        return "UChar", 1
    if dtype.kind == "i":
        return ("Char" if dtype.itemsize == 1 else "Int"), dtype.itemsize
    raise ValueError(f"no XDMF number type for {dtype}")


def _dims(shape) -> str:
    return " ".join(str(int(s)) for s in shape)


def _hyperslab(parent, h5_ref: str, ds_path: str, shape: tuple, dtype, k: int):
    """HyperSlab DataItem selecting frame ``k`` of a dataset of shape (F, n[, dim])."""
    count = (1,) + tuple(shape[1:])
    slab = ET.SubElement(parent, "DataItem", ItemType="HyperSlab", Type="HyperSlab", Dimensions=_dims(count))
    sel = ET.SubElement(slab, "DataItem", Dimensions=f"3 {len(shape)}", Format="XML", NumberType="Int")
    start = (k,) + (0,) * (len(shape) - 1)
    sel.text = f"{_dims(start)} {_dims((1,) * len(shape))} {_dims(count)}"
    ntype, prec = _number_type(dtype)
    src = ET.SubElement(slab, "DataItem", Dimensions=_dims(shape), Format="HDF", NumberType=ntype, Precision=str(prec))
    src.text = f"{h5_ref}:{ds_path}"
    return slab


def write_xdmf(h5_path, xdmf_path=None) -> Path:
    """Write the XDMF 3 sidecar of ``h5_path`` (default: the same name with ``.xdmf``).

    Returns the path written.  Frames are those present in every dataset (an
    interrupted run may have one more time than positions); the file is written
    atomically (temporary file and rename).
    """
    h5_path = Path(h5_path)
    xdmf_path = h5_path.with_suffix(".xdmf") if xdmf_path is None else Path(xdmf_path)
    h5_ref = Path(os.path.relpath(h5_path.resolve(), xdmf_path.resolve().parent)).as_posix()
    with h5py.File(h5_path, "r") as f:
        g = f["frames"]
        t = np.asarray(g["t_s"][()], float)
        xs = g["x_m"]
        _, n, dim = xs.shape
        fields = []  # (name, shape, dtype, attribute type)
        names = [k for k in FIELD_ORDER if k in g] + sorted(k for k in g if k not in FIELD_ORDER + ("t_s", "x_m"))
        for name in names:
            ds = g[name]
            if not isinstance(ds, h5py.Dataset):
                continue
            if ds.shape[1:] == (n,):
                fields.append((name, ds.shape, ds.dtype, "Scalar"))
            elif ds.shape[1:] == (n, dim) and not name.endswith(LAYERS_SUFFIX):  # layers across a depth: no vector
                fields.append((name, ds.shape, ds.dtype, "Vector"))
        n_frames = min([len(t), xs.shape[0]] + [s[0] for _, s, _, _ in fields])
        x_shape, x_dtype = xs.shape, xs.dtype
        scene = f.attrs.get("scene", "mpmjax")
        scene = scene.decode() if isinstance(scene, bytes) else str(scene)

    root = ET.Element("Xdmf", Version="3.0")
    domain = ET.SubElement(root, "Domain")
    coll = ET.SubElement(domain, "Grid", Name=scene, GridType="Collection", CollectionType="Temporal")
    width = max(5, len(str(max(n_frames - 1, 0))))
    for k in range(n_frames):
        grid = ET.SubElement(coll, "Grid", Name=f"frame_{k:0{width}d}", GridType="Uniform")
        ET.SubElement(grid, "Time", Value=repr(float(t[k])))
        ET.SubElement(grid, "Topology", TopologyType="Polyvertex", NumberOfElements=str(n), NodesPerElement="1")
        geom = ET.SubElement(grid, "Geometry", GeometryType="XY" if dim == 2 else "XYZ")
        _hyperslab(geom, h5_ref, "/frames/x_m", x_shape, x_dtype, k)
        for name, shape, dtype, kind in fields:
            att = ET.SubElement(grid, "Attribute", Name=name, AttributeType=kind, Center="Node")
            _hyperslab(att, h5_ref, f"/frames/{name}", shape, dtype, k)
    ET.indent(root, space=" ")
    text = (
        '<?xml version="1.0" encoding="utf-8"?>\n<!DOCTYPE Xdmf SYSTEM "Xdmf.dtd" []>\n'
        + ET.tostring(root, encoding="unicode")
        + "\n"
    )
    atomic_write_text(xdmf_path, text)
    return xdmf_path
