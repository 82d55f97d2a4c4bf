"""``usdz``: object meshes for AR Quick Look, checked by usd-core's ARKit compliance checker
(``usdchecker --arkit``) and read back with ``pxr``: names, records, Y-up metres, colours."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdUtils

from dcseg.export import ExportOptions, export_run
from tests.scenes.runs import BOX

UNAVAILABLE_RULE = "ShaderPropertyTypeConformanceChecker"
"""Needs the ``usdShaders`` plugin's ``shaderDefs.usda``, which usd-core's wheel does not ship
(the rule raises on any Shader); the shader input types it checks are asserted below instead."""


def arkit_check(path: Path) -> UsdUtils.ComplianceChecker:
    checker = UsdUtils.ComplianceChecker(arkit=True)
    rules = [type(r).__name__ for r in checker._rules]
    assert UNAVAILABLE_RULE in rules and "ARKitShaderChecker" in rules
    checker._rules = [r for r in checker._rules if type(r).__name__ != UNAVAILABLE_RULE]
    checker.CheckCompliance(str(path))
    return checker


@pytest.fixture(scope="module")
def usdz(run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("usdz")
    export_run(run, out, "usdz", options=ExportOptions(max_faces=2000))
    return out


def test_every_package_passes_the_arkit_compliance_checker(usdz: Path) -> None:
    files = sorted(usdz.glob("*.usdz"))
    assert [p.name for p in files] == [f"instance_{k}.usdz" for k in (1, 2, 3)] + ["scene.usdz"]
    for path in files:
        checker = arkit_check(path)
        assert checker.GetErrors() == [] and checker.GetFailedChecks() == [], path.name
        assert checker.GetWarnings() == [], path.name


def test_objects_are_named_prims_with_their_records_upright_in_metres(usdz: Path) -> None:
    table = json.loads((usdz / "instances.usdz.json").read_text())
    stage = Usd.Stage.Open(str(usdz / "scene.usdz"))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/Root")
    for record in table["instances"]:
        prim = stage.GetPrimAtPath(f"/Root/{record['node']}")
        data = prim.GetCustomData()
        assert data["instance_id"] == record["id"] and data["label"] == record["label"]
        assert data["score"] == pytest.approx(record["score"])
    box = UsdGeom.Mesh(stage.GetPrimAtPath(f"/Root/box_{BOX}/Mesh"))
    points = np.asarray(box.GetPointsAttr().Get())
    assert points[:, 1].max() == pytest.approx(0.4, abs=0.02)  # the box's top, +Y up
    primvar = box.GetDisplayColorPrimvar()
    assert np.asarray(primvar.Get()).shape == points.shape
    assert primvar.GetInterpolation() == "vertex"
    material, _ = UsdShade.MaterialBindingAPI(box.GetPrim()).ComputeBoundMaterial()
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    diffuse = surface.GetInput("diffuseColor")
    assert diffuse.GetTypeName() == Sdf.ValueTypeNames.Color3f
    reader = UsdShade.Shader(diffuse.GetConnectedSources()[0][0].source.GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float3"
    varname = reader.GetInput("varname")
    assert varname.GetTypeName() == Sdf.ValueTypeNames.String and varname.Get() == "displayColor"
    assert surface.GetInput("roughness").GetTypeName() == Sdf.ValueTypeNames.Float
