"""Shapes of the capture generator: analytic sphere and cylinder, the pyramid, any mesh.

``hemisphere``
    Mitsuba's analytic ``sphere`` (only its upper half is visible to the camera and no
    reflected ray can reach the lower half of a convex body, so the images equal those of a
    hemisphere); shading normals are exact sphere normals.
``cylinder``
    Mitsuba's analytic ``cylinder``, axis along image y, of ``length``.
``pyramid``
    A square pyramid (apex towards the camera) as a flat-shaded mesh: four planar faces.
``mesh``
    Any file trimesh loads, scaled, rotated (x, y, z Euler angles, degrees), centred in x, y
    and lowered so that its lowest point is at z = 0; smooth shading normals (trimesh's
    vertex normals) unless ``smooth = false``. Closed meshes get outward normals, open ones
    are turned to face the camera. Surfaces seen from behind (shading normal n_z <= 0) render
    black and are left out of the mask.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["geometry"]


def _rotation(deg):
    ax, ay, az = np.radians(deg)
    rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    rz = np.array([[np.cos(az), -np.sin(az), 0], [np.sin(az), np.cos(az), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _pyramid_mesh(base: float, height: float):
    b = 0.5 * base
    # Apex first, then the base corners counter-clockwise seen from +z; unshared vertices so
    # each face is flat.
    apex = [0.0, 0.0, height]
    corners = [[-b, -b, 0.0], [b, -b, 0.0], [b, b, 0.0], [-b, b, 0.0]]
    verts, faces = [], []
    for i in range(4):
        verts += [corners[i], corners[(i + 1) % 4], apex]
        faces.append([3 * i, 3 * i + 1, 3 * i + 2])
    return np.array(verts, dtype=np.float64), np.array(faces, dtype=np.int64), None


def _load_mesh(shape: dict):
    import trimesh

    path = shape.params["path"]
    try:
        loaded = trimesh.load(path, force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise UserError(f"{path}: cannot load mesh ({e})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise UserError(f"{path}: no triangles found in the mesh file")
    mesh = loaded.copy()
    mesh.apply_transform(np.block([[_rotation(shape.params["rotate_deg"]) * shape.params["scale"], np.zeros((3, 1))],
                                   [np.zeros((1, 3)), np.ones((1, 1))]]))
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserError(f"{path}: mesh has non-finite vertex positions")
    size = float(np.max(mesh.extents)) if len(mesh.vertices) else 0.0
    if not 1e-6 <= size <= 1e6:
        raise UserError(f"{path}: the mesh is {size:g} scene units across after 'shape.scale' = "
                        f"{shape.params['scale']:g}; expected 1e-06 to 1e+06 (Mitsuba's geometry is "
                        f"single precision)")
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    if mesh.is_watertight:
        mesh.fix_normals()  # consistent winding, normals pointing out of the solid
    elif np.sum(mesh.area_faces * mesh.face_normals[:, 2]) < -1e-9 * mesh.area:
        # An open surface (a sheet, a relief): orient it so that most of its projected
        # area faces the camera.
        mesh.invert()
    if shape.params["smooth"]:
        return (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64),
                np.asarray(mesh.vertex_normals, dtype=np.float64))
    tri = mesh.vertices[mesh.faces].reshape(-1, 3)
    return tri, np.arange(len(tri)).reshape(-1, 3), None


def geometry(shape):
    """(kind of Mitsuba shape, its parameters, projected extent, zmin, zmax, rim radius)."""
    kind = shape.kind
    if kind == "hemisphere":
        r = shape.params["radius"]
        return ("sphere", {"radius": r}, (-r, r, -r, r), 0.0, r, r)
    if kind == "cylinder":
        r, half = shape.params["radius"], 0.5 * shape.params["length"]
        return ("cylinder", {"radius": r, "half_length": half}, (-r, r, -half, half), 0.0, r,
                float(np.hypot(r, half)))
    if kind == "pyramid":
        verts, faces, normals = _pyramid_mesh(shape.params["base"], shape.params["height"])
    elif kind == "mesh":
        verts, faces, normals = _load_mesh(shape)
    else:  # pragma: no cover - load_spec validated it
        raise UserError(f"unknown shape kind {kind!r}")
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = 0.5 * (lo[:2] + hi[:2])
    rim = float(np.max(np.hypot(verts[:, 0] - centre[0], verts[:, 1] - centre[1])))
    if not (hi[0] > lo[0] and hi[1] > lo[1]):
        raise UserError(f"{shape.params.get('path', kind)}: the shape has no extent in the image plane")
    return ("mesh", {"vertices": verts, "faces": faces, "normals": normals},
            (lo[0], hi[0], lo[1], hi[1]), float(lo[2]), float(hi[2]), rim)
