"""Gaussians as glTF 2.0 binary files with the Khronos ``KHR_gaussian_splatting`` extension.

Each object is one node named ``<class>_<k>`` (``object_<k>`` without a class) whose mesh has
one ``POINTS`` primitive carrying the ellipse kernel's attributes as the extension specifies:
``POSITION``, ``KHR_gaussian_splatting:ROTATION`` (unit quaternion, glTF's xyzw order),
``:SCALE`` (linear), ``:OPACITY`` (after the sigmoid, in [0, 1]), ``:SH_DEGREE_0_COEF_0`` and
``:SH_DEGREE_l_COEF_n`` for every higher band the run has (VEC3 RGB, ``m`` from lowest to
highest, the 3DGS order), plus ``COLOR_0`` (the DC colour, linear, opacity in alpha) for
viewers that draw the points only. Nodes carry the object in ``extras`` (``instance_id``,
``name``, ``label``, ``class``, ``class_id``, ``score``, ``n_gaussians``), as the mesh GLB does.

The data is in glTF's axes (+Y up): the extension recommends this over node transforms, which
rotate SH only in renderers that implement it; so the turn of ``frame.json`` is baked in
(:mod:`dcseg.export.axes`) and nodes have no transform. ``colorSpace`` is
``srgb_rec709_display`` (3DGS trains display-referred sRGB).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcseg.io.splat_table import SH_C0, SplatTable

EXTENSION = "KHR_gaussian_splatting"
PRIMITIVE_EXTENSION = {
    "kernel": "ellipse",
    "colorSpace": "srgb_rec709_display",
    "projection": "perspective",
    "sortingMethod": "cameraDistance",
}
_FLOAT, _UBYTE = 5126, 5121
_ARRAY_BUFFER = 34962
_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}


def srgb_to_linear(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """The sRGB transfer function undone (``COLOR_0`` holds linear values)."""
    out: NDArray[np.float64] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return out


def splat_attributes(table: SplatTable) -> dict[str, NDArray[Any]]:
    """The primitive's attribute arrays (float32, or uint8 for ``COLOR_0``), by semantic."""
    quats = table.quats.astype(np.float64)
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    unit = np.where(norm > 0, quats / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])
    alpha = 1.0 / (1.0 + np.exp(-table.opacity_logits.astype(np.float64)))
    rgb = np.clip(0.5 + SH_C0 * table.sh[:, 0, :].astype(np.float64), 0.0, 1.0)
    rgba = np.concatenate([srgb_to_linear(rgb), alpha[:, None]], axis=1)
    out: dict[str, NDArray[Any]] = {
        "POSITION": table.means.astype(np.float32),
        "COLOR_0": np.round(rgba * 255.0).astype(np.uint8),
        f"{EXTENSION}:ROTATION": unit[:, [1, 2, 3, 0]].astype(np.float32),  # wxyz -> xyzw
        f"{EXTENSION}:SCALE": np.exp(table.log_scales.astype(np.float64)).astype(np.float32),
        f"{EXTENSION}:OPACITY": alpha.astype(np.float32),
    }
    coeff = 0
    for degree in range(table.sh_degree + 1):
        for n in range(2 * degree + 1):
            sh = table.sh[:, coeff, :].astype(np.float32)
            out[f"{EXTENSION}:SH_DEGREE_{degree}_COEF_{n}"] = sh
            coeff += 1
    return out


class GlbBuilder:
    """Accumulates accessors over one binary buffer and writes the ``.glb`` container."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.size = 0
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def accessor(self, name: str, values: NDArray[Any]) -> int:
        """Add ``values`` ``[N, C]`` (or ``[N]``) as a tightly packed vertex accessor."""
        values = values.reshape(len(values), -1)
        data = np.ascontiguousarray(values).tobytes()
        self.views.append(
            {"buffer": 0, "byteOffset": self.size, "byteLength": len(data),
             "target": _ARRAY_BUFFER}
        )  # fmt: skip
        padded = data + b"\0" * (-len(data) % 4)
        self.chunks.append(padded)
        self.size += len(padded)
        accessor: dict[str, Any] = {
            "bufferView": len(self.views) - 1,
            "componentType": _UBYTE if values.dtype == np.uint8 else _FLOAT,
            "count": int(len(values)),
            "type": _TYPES[values.shape[1]],
        }
        if values.dtype == np.uint8:
            accessor["normalized"] = True
        if name == "POSITION":  # required for POSITION
            accessor["min"] = values.min(axis=0).astype(float).tolist()
            accessor["max"] = values.max(axis=0).astype(float).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def primitive(self, table: SplatTable) -> dict[str, Any]:
        """A ``POINTS`` primitive with the extension's attributes of ``table``."""
        attributes = {k: self.accessor(k, v) for k, v in splat_attributes(table).items()}
        return {"attributes": attributes, "mode": 0, "extensions": {EXTENSION: PRIMITIVE_EXTENSION}}

    def glb(self, gltf: dict[str, Any]) -> bytes:
        """The binary glTF file of ``gltf`` (buffers, views and accessors filled in)."""
        gltf = {
            **gltf,
            "buffers": [{"byteLength": self.size}],
            "bufferViews": self.views,
            "accessors": self.accessors,
        }
        text = json.dumps(gltf, separators=(",", ":")).encode("utf-8")
        text += b" " * (-len(text) % 4)
        body = b"".join(self.chunks)
        total = 12 + 8 + len(text) + 8 + len(body)
        return b"".join(
            [struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"),
             text, struct.pack("<I4s", len(body), b"BIN\0"), body]
        )  # fmt: skip


Node = tuple[dict[str, Any], SplatTable]
"""A node's ``extras`` (its ``name`` names the node) and its Gaussians."""


def splat_glb(nodes: list[Node], scene_extras: dict[str, Any]) -> bytes:
    """A GLB with one node per ``(extras, table)``, named ``extras["name"]``."""
    builder = GlbBuilder()
    gltf_nodes, meshes = [], []
    for extras, table in nodes:
        meshes.append({"name": extras["name"], "primitives": [builder.primitive(table)]})
        gltf_nodes.append({"name": extras["name"], "mesh": len(meshes) - 1, "extras": extras})
    gltf = {
        "asset": {"version": "2.0", "generator": "dcseg export (KHR_gaussian_splatting)"},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": list(range(len(gltf_nodes))), "extras": scene_extras}],
        "nodes": gltf_nodes,
        "meshes": meshes,
    }
    return builder.glb(gltf)


def write_splat_glb(path: Path, nodes: list[Node], scene_extras: dict[str, Any]) -> None:
    """Write :func:`splat_glb` to ``path`` (nodes without Gaussians are left out)."""
    path.write_bytes(splat_glb([(e, t) for e, t in nodes if len(t)], scene_extras))
