"""USDZ object meshes for Apple's AR Quick Look, written with Pixar's ``usd-core``.

Format ``usdz`` writes ``instance_<k>.usdz`` per object and, for a whole run, ``scene.usdz``
(every object): the meshes of :mod:`dcseg.export.meshes` (fused from the run's depth), turned to
Y-up (``frame.json``'s matrix), metres (``metersPerUnit = 1``). Each object is an ``Xform``
named ``<class>_<k>`` under the default prim ``/Root`` whose ``customData`` holds the object's
record (as a GLB node's ``extras``); its ``Mesh`` carries the vertex colours as ``displayColor``
and is bound to a ``UsdPreviewSurface`` that reads them (``UsdPrimvarReader_float3``), the
material set AR Quick Look renders. Packages are made by ``UsdUtils.CreateNewARKitUsdzPackage``
from a binary ``.usdc`` root layer, and pass ``UsdUtils.ComplianceChecker(arkit=True)``
(``usdchecker --arkit``).
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdUtils, Vt

from dcseg.export.axes import gltf_turn
from dcseg.export.meshes import object_meshes
from dcseg.export.plan import ExportPlan, Written, node_extras
from dcseg.export.surface import ObjectMesh


def prim_name(name: str) -> str:
    """``name`` as a valid USD prim name (letters, digits, ``_``; not starting with a digit)."""
    clean = re.sub(r"\W", "_", name, flags=re.ASCII)
    return clean if clean and not clean[0].isdigit() else f"_{clean}"


def _material(stage: Usd.Stage) -> UsdShade.Material:
    """One ``UsdPreviewSurface`` whose diffuse colour is the mesh's ``displayColor``."""
    material = UsdShade.Material.Define(stage, "/Root/Materials/VertexColour")
    reader = UsdShade.Shader.Define(stage, "/Root/Materials/VertexColour/Colour")
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("displayColor")
    colour = reader.CreateOutput("result", Sdf.ValueTypeNames.Float3)
    surface = UsdShade.Shader.Define(stage, "/Root/Materials/VertexColour/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(colour)
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    return material


def _add_object(
    stage: Usd.Stage,
    mesh: ObjectMesh,
    extras: dict[str, Any],
    turn: Any,
    material: UsdShade.Material,
) -> str:
    path = f"/Root/{prim_name(extras['name'])}"
    xform = UsdGeom.Xform.Define(stage, path)
    xform.GetPrim().SetCustomData({k: v for k, v in extras.items() if v is not None})
    geom = UsdGeom.Mesh.Define(stage, f"{path}/Mesh")
    points = mesh.vertices @ turn.T
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points.astype(np.float32)))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.faces.reshape(-1).astype(np.int32)))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = points.min(axis=0), points.max(axis=0)
    geom.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, lo)), Gf.Vec3f(*map(float, hi))]))
    colours = (mesh.colours.astype(np.float32) / 255.0) ** 2.2  # sRGB -> linear
    primvar = geom.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
    primvar.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(colours)))
    UsdShade.MaterialBindingAPI.Apply(geom.GetPrim()).Bind(material)
    return path


def write_usdz(path: Path, objects: list[tuple[ObjectMesh, dict[str, Any]]], turn: Any) -> None:
    """One USDZ package holding ``objects`` (each ``(mesh, extras)``) under ``/Root``."""
    with tempfile.TemporaryDirectory(dir=path.parent) as tmp:
        layer = Path(tmp) / f"{path.stem}.usdc"
        stage = Usd.Stage.CreateNew(str(layer))
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        root = UsdGeom.Xform.Define(stage, "/Root")
        stage.SetDefaultPrim(root.GetPrim())
        UsdGeom.Scope.Define(stage, "/Root/Materials")
        material = _material(stage)
        for mesh, extras in objects:
            _add_object(stage, mesh, extras, turn, material)
        stage.GetRootLayer().Save()
        if not UsdUtils.CreateNewARKitUsdzPackage(Sdf.AssetPath(str(layer)), str(path)):
            raise RuntimeError(f"usd-core could not package {path.name}")


def write_usdz_meshes(plan: ExportPlan, folder: Path, fmt: str) -> Written:
    """``instance_<k>.usdz`` per object with a surface and, for a whole run, ``scene.usdz``."""
    turn = gltf_turn(plan.run.path, plan.options.capture)
    records = {int(r["id"]): r for r in plan.records}
    objects = [(mesh, node_extras(records[mesh.instance])) for mesh in object_meshes(plan)]
    written = Written()
    for mesh, extras in objects:
        name = f"instance_{mesh.instance}.usdz"
        write_usdz(folder / name, [(mesh, extras)], turn)
        written.files.append(name)
        written.per_instance[mesh.instance] = name
        written.nodes[mesh.instance] = prim_name(extras["name"])
    if plan.whole:
        written.scene = "scene.usdz"
        write_usdz(folder / written.scene, objects, turn)
        written.files.append(written.scene)
    return written
