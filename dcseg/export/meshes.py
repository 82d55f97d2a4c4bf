"""Mesh exports: ``scene_mesh.glb`` (format ``glb-mesh``, one node per object) or
``instance_<k>.obj`` per object and ``scene_mesh.ply``, fused from the run's depth
(:mod:`dcseg.export.tsdf`) and labelled by its Gaussians (:mod:`dcseg.export.surface`).

GLB nodes are named ``<class>_<k>`` (``object_<k>`` without a class) and carry
``{instance_id, name, class, class_id, score, n_gaussians}`` in their ``extras``; each node's
matrix is the turn from the run's world to glTF's Y-up (``frame.json``), so engines and WebXR
show the scene upright in metres. OBJ and PLY meshes stay in world coordinates. Surfaces no
object claims (vertices far from every labelled Gaussian) are left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray
from plyfile import PlyData, PlyElement

from dcseg.export.appearance import gaussian_rgb, styled
from dcseg.export.depth import depth_views, poses
from dcseg.export.frame import describe_frame
from dcseg.export.plan import ExportPlan, Written, node_extras
from dcseg.export.surface import (
    REACH_VOXELS,
    ObjectMesh,
    extract,
    label_surface,
    object_mesh,
    vertex_colours,
)
from dcseg.export.tsdf import fuse


def object_meshes(plan: ExportPlan) -> list[ObjectMesh]:
    """The selected objects' meshes (objects without any surface are left out)."""
    run, options = plan.run, plan.options
    views = depth_views(run.path, options.capture)
    volume = fuse(views, options.voxel_size, options.voxels_per_side)
    vertices, faces = extract(volume)
    reach = REACH_VOXELS * volume.voxel
    surface = label_surface(vertices, faces, run.splats.means, run.instance_ids, reach)
    meshes = []
    for k in plan.ids:
        got = object_mesh(surface, k, options.max_faces)
        if got is None:
            continue
        rows = plan.rows_of(k)
        rgb = gaussian_rgb(styled(run, rows, options))
        colours = vertex_colours(got[0], run.splats.means[rows], rgb)
        meshes.append(ObjectMesh(k, got[0], got[1], colours))
    return meshes


def _trimesh(mesh: ObjectMesh) -> trimesh.Trimesh:
    rgba = np.concatenate([mesh.colours, np.full((len(mesh.colours), 1), 255, np.uint8)], axis=1)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=rgba, process=False)


def write_glb(path: Path, plan: ExportPlan, meshes: list[ObjectMesh]) -> dict[int, str]:
    """One node per object, turned to Y-up; the frame description in the scene's extras.
    Returns each object's node name."""
    frame = describe_frame(poses(plan.run.path, plan.options.capture), [path.name])
    turn = np.asarray(frame["to_gltf"]["matrix"], np.float64)
    records = {int(r["id"]): r for r in plan.records}
    scene = trimesh.Scene()
    for mesh in meshes:
        extras = node_extras(records[mesh.instance])
        scene.add_geometry(
            _trimesh(mesh),
            node_name=extras["name"],
            geom_name=extras["name"],
            transform=turn,
            metadata=extras,
        )
    scene.metadata = {"dcseg_frame": frame}
    path.write_bytes(scene.export(file_type="glb"))  # type: ignore[no-untyped-call]
    return {m.instance: node_extras(records[m.instance])["name"] for m in meshes}


def write_mesh_ply(path: Path, meshes: list[ObjectMesh]) -> None:
    """All objects in one PLY mesh: vertex ``red green blue`` and ``instance_id``."""
    offsets = np.cumsum([0, *(len(m.vertices) for m in meshes)])
    vertex = np.empty(
        int(offsets[-1]),
        [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
         ("blue", "u1"), ("instance_id", "<i4")],
    )  # fmt: skip
    faces: list[NDArray[np.int64]] = []
    for mesh, start in zip(meshes, offsets[:-1], strict=False):
        rows = slice(int(start), int(start) + len(mesh.vertices))
        for axis, name in enumerate("xyz"):
            vertex[name][rows] = mesh.vertices[:, axis]
        for channel, name in enumerate(("red", "green", "blue")):
            vertex[name][rows] = mesh.colours[:, channel]
        vertex["instance_id"][rows] = mesh.instance
        faces.append(mesh.faces + start)
    face = np.empty(int(sum(len(f) for f in faces)), [("vertex_indices", "<i4", (3,))])
    face["vertex_indices"] = np.concatenate(faces) if faces else np.zeros((0, 3))
    elements = [PlyElement.describe(vertex, "vertex"), PlyElement.describe(face, "face")]
    PlyData(elements, text=False, byte_order="<").write(str(path))


def write_meshes(plan: ExportPlan, folder: Path, fmt: str) -> Written:
    """Write ``scene_mesh.glb`` (``fmt == "glb-mesh"``) or per-object OBJs and
    ``scene_mesh.ply``."""
    meshes = object_meshes(plan)
    written = Written()
    if fmt == "glb-mesh":
        written.scene = "scene_mesh.glb"
        written.nodes = write_glb(folder / written.scene, plan, meshes)
        written.files.append(written.scene)
        return written
    for mesh in meshes:
        name = f"instance_{mesh.instance}.obj"
        obj = trimesh.exchange.obj.export_obj(_trimesh(mesh))  # type: ignore[no-untyped-call]
        (folder / name).write_text(obj)
        written.files.append(name)
        written.per_instance[mesh.instance] = name
    written.scene = "scene_mesh.ply"
    write_mesh_ply(folder / written.scene, meshes)
    written.files.append(written.scene)
    return written
