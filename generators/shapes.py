"""Shapes of the capture generator: analytic sphere and cylinder, meshes built at run time,
any mesh file, and groups of separate objects.

Scene units; the camera looks along -z (``docs/design.md``, *Conventions*). Rotations
``rotate_deg`` are x, y, z Euler angles in degrees applied in that order (about the shape's own
centre, before any ``offset``).

``hemisphere``
    Mitsuba's analytic ``sphere`` (only its upper half is visible to the camera and no
    reflected ray can reach the lower half of a convex body, so the images equal those of a
    hemisphere); shading normals are exact sphere normals.
``cylinder``
    Mitsuba's analytic ``cylinder``, axis along image y, of ``length``.
``pyramid``
    A square pyramid (apex towards the camera) as a flat-shaded mesh: four planar faces.
``mesh``
    Any file trimesh loads, scaled, rotated, centred in x, y and lowered so that its lowest
    point is at z = 0; smooth shading normals (trimesh's vertex normals) unless
    ``smooth = false``. Closed meshes get outward normals, open ones are turned to face the
    camera. Surfaces seen from behind (shading normal n_z <= 0) render black and are left
    out of the mask.

Meshes built here, with exact (analytic) vertex normals, fine enough that the silhouette
is smooth at a few hundred pixels:

``torus``
    ``major_radius`` (centre of the tube to the axis), ``minor_radius`` (the tube); axis
    towards the camera before ``rotate_deg`` (a ring with its hole in view). Tilted, the
    tube hides part of the hole: interior occluding contours.
``capsule``
    A cylinder of ``radius`` and ``length`` closed by two hemispheres; axis along image y
    before ``rotate_deg`` (lying, like ``cylinder``).
``ellipsoid``
    ``semi_axes`` (x, y, z) then ``rotate_deg``.
``cap``
    A spherical cap (an open shell, no base) of sphere ``radius`` and ``height`` (from
    0 to 2 radius; up to one radius it is a dome whose rim is a cut edge, beyond it the
    silhouette is an occluding contour); pole towards the camera before ``rotate_deg``.
``sheet``
    An open, wavy height-field sheet over a square of side ``size``:
    ``z = amplitude · sin(2π u / wavelength + phase)`` along the direction
    ``direction_deg`` in the image plane (u the coordinate along it), times
    ``cos(2π v / wavelength)`` across it when ``cross = true`` (an egg-crate); then
    ``rotate_deg``. Its edges are cut edges, not occluding contours.
``group``
    Several separate objects in one image: ``parts`` is a list of shape tables (any kind
    but ``mesh`` and ``group``, each with its own keys) with an ``offset`` (x, y, z) each.
    Every part becomes a mesh (a ``hemisphere`` a full sphere, a ``cylinder`` an open tube).
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.errors import UserError

__all__ = ["geometry", "part_mesh", "MESH_SECTIONS"]

#: angular sections of the meshes built here (around an axis, along a profile)
MESH_SECTIONS = 256
#: the most triangles a ``mesh`` shape's file may hold (counted before the mesh is processed)
MAX_MESH_FACES = 2_000_000


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


def _flat_normals(verts, faces):
    """Unshared vertices with their face's normal (a flat-shaded mesh with vertex normals)."""
    tri = verts[faces]                                   # (F, 3, 3)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return tri.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3), np.repeat(n, 3, axis=0)


def _grid_faces(nu: int, nv: int, wrap_u: bool, wrap_v: bool):
    """Two triangles per cell of an (nu, nv) vertex grid (row-major), wrapping as asked."""
    iu = np.arange(nu if wrap_u else nu - 1)
    iv = np.arange(nv if wrap_v else nv - 1)
    U, V = np.meshgrid(iu, iv, indexing="ij")
    a = U * nv + V
    b = ((U + 1) % nu) * nv + V
    c = ((U + 1) % nu) * nv + (V + 1) % nv
    d = U * nv + (V + 1) % nv
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])


def _orient(verts, faces, normals):
    """Wind every triangle so that its geometric normal agrees with its vertex normals, and
    drop degenerate ones (at poles)."""
    tri = verts[faces]
    g = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(g, axis=1)
    keep = area > 1e-12 * max(float(np.max(area)), 1e-300)
    faces, g = faces[keep], g[keep]
    flip = np.einsum("ij,ij->i", g, normals[faces].sum(axis=1)) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _revolve(r, z, nr, nz, closed_profile: bool, sections: int = MESH_SECTIONS):
    """A surface of revolution about the z axis from a profile (r_k, z_k) with profile
    normals (nr_k, nz_k). Ends of an open profile on the axis (r = 0) become single pole
    vertices."""
    r, z, nr, nz = (np.asarray(a, dtype=np.float64) for a in (r, z, nr, nz))
    phi = 2.0 * np.pi * np.arange(sections) / sections
    c, s = np.cos(phi), np.sin(phi)
    P = np.stack([r[:, None] * c, r[:, None] * s, np.broadcast_to(z[:, None], (r.size, sections))], -1)
    N = np.stack([nr[:, None] * c, nr[:, None] * s, np.broadcast_to(nz[:, None], (r.size, sections))], -1)
    verts, normals = P.reshape(-1, 3), N.reshape(-1, 3)
    faces = _grid_faces(r.size, sections, closed_profile, True)
    # merge the vertices of a pole ring into one
    for k in ((0, r.size - 1) if not closed_profile else ()):
        if r[k] == 0.0:
            ring = k * sections + np.arange(sections)
            faces = np.where(np.isin(faces, ring), ring[0], faces)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    return verts, _orient(verts, faces, normals), normals


def _sphere_profile(polar_max: float, count: int):
    """Profile of a unit sphere from the pole (polar angle 0) to ``polar_max``."""
    t = np.linspace(0.0, polar_max, count)
    return np.sin(t), np.cos(t), np.sin(t), np.cos(t)


def _sphere(radius: float):
    r, z, nr, nz = _sphere_profile(np.pi, MESH_SECTIONS // 2 + 1)
    v, f, n = _revolve(r, z, nr, nz, False)
    return v * radius, f, n


def _ellipsoid(axes):
    a = np.asarray(axes, dtype=np.float64)
    v, f, n = _sphere(1.0)
    n = n / a                      # normals transform by the inverse transpose
    return v * a, f, n / np.linalg.norm(n, axis=1, keepdims=True)


def _cap(radius: float, height: float):
    polar = np.arccos(np.clip(1.0 - height / radius, -1.0, 1.0))
    count = max(8, int(np.ceil(polar / np.pi * MESH_SECTIONS)) + 1)
    r, z, nr, nz = _sphere_profile(polar, count)
    v, f, n = _revolve(r, z, nr, nz, False)
    return v * radius, f, n


def _torus(major: float, minor: float):
    t = 2.0 * np.pi * np.arange(MESH_SECTIONS // 2) / (MESH_SECTIONS // 2)
    return _revolve(major + minor * np.cos(t), minor * np.sin(t), np.cos(t), np.sin(t), True)


def _capsule(radius: float, length: float):
    """Axis along y: built about z (hemisphere, tube, hemisphere), then turned."""
    k = MESH_SECTIONS // 4 + 1
    t = np.linspace(0.0, 0.5 * np.pi, k)
    h = 0.5 * length
    top = (radius * np.sin(t), h + radius * np.cos(t), np.sin(t), np.cos(t))
    tube_z = np.linspace(h, -h, max(2, int(np.ceil(length / radius * k / 2)) + 1))[1:-1]
    tube = (np.full(tube_z.size, radius), tube_z, np.ones(tube_z.size), np.zeros(tube_z.size))
    bottom = tuple(np.asarray(a)[::-1] * sgn for a, sgn in zip(top, (1, -1, 1, -1)))
    prof = [np.concatenate([a, b, c]) for a, b, c in zip(top, tube, bottom)]
    v, f, n = _revolve(*prof, closed_profile=False)
    turn = _rotation([-90.0, 0.0, 0.0])          # z -> y
    return v @ turn.T, f, n @ turn.T


def _open_tube(radius: float, length: float):
    """The analytic cylinder's open tube as a mesh, axis along y."""
    k = MESH_SECTIONS
    z = np.linspace(-0.5 * length, 0.5 * length, max(2, int(np.ceil(length / radius * k / (2 * np.pi))) + 1))
    v, f, n = _revolve(np.full(z.size, radius), z, np.ones(z.size), np.zeros(z.size), False)
    turn = _rotation([-90.0, 0.0, 0.0])
    return v @ turn.T, f, n @ turn.T


def _sheet(p: dict):
    size, amp, lam = p["size"], p["amplitude"], p["wavelength"]
    count = MESH_SECTIONS + 1
    x = np.linspace(-0.5 * size, 0.5 * size, count)
    X, Y = np.meshgrid(x, x, indexing="ij")
    a = np.radians(p["direction_deg"])
    u = X * np.cos(a) + Y * np.sin(a)
    v = -X * np.sin(a) + Y * np.cos(a)
    k = 2.0 * np.pi / lam
    ph = np.radians(p["phase_deg"])
    wave_u, dwave_u = np.sin(k * u + ph), k * np.cos(k * u + ph)
    wave_v, dwave_v = (np.cos(k * v), -k * np.sin(k * v)) if p["cross"] else (np.ones_like(v), np.zeros_like(v))
    Z = amp * wave_u * wave_v
    dz_du, dz_dv = amp * dwave_u * wave_v, amp * wave_u * dwave_v
    zx = dz_du * np.cos(a) - dz_dv * np.sin(a)
    zy = dz_du * np.sin(a) + dz_dv * np.cos(a)
    verts = np.stack([X, Y, Z], -1).reshape(-1, 3)
    n = np.stack([-zx, -zy, np.ones_like(Z)], -1).reshape(-1, 3)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return verts, _orient(verts, _grid_faces(count, count, False, False), n), n


def part_mesh(kind: str, params: dict):
    """Vertices (V, 3), faces (F, 3) and unit vertex normals (V, 3) of a shape built here
    (any kind but ``mesh`` and ``group``), rotated by its ``rotate_deg`` when it has one;
    centred on its own origin (a ``pyramid`` and a ``cap`` stand on z = 0, a ``hemisphere``
    is a whole sphere)."""
    if kind == "hemisphere":
        v, f, n = _sphere(params["radius"])
    elif kind == "cylinder":
        v, f, n = _open_tube(params["radius"], params["length"])
    elif kind == "pyramid":
        v, f, n = _flat_normals(*_pyramid_mesh(params["base"], params["height"])[:2])
    elif kind == "torus":
        v, f, n = _torus(params["major_radius"], params["minor_radius"])
    elif kind == "capsule":
        v, f, n = _capsule(params["radius"], params["length"])
    elif kind == "ellipsoid":
        v, f, n = _ellipsoid(params["semi_axes"])
    elif kind == "cap":
        v, f, n = _cap(params["radius"], params["height"])
        v = v - [0.0, 0.0, params["radius"] - params["height"]]
    elif kind == "sheet":
        v, f, n = _sheet(params)
    else:  # pragma: no cover - load_spec validated it
        raise UserError(f"shape kind {kind!r} cannot be built as a mesh")
    rot = _rotation(params.get("rotate_deg", [0.0, 0.0, 0.0]))
    return v @ rot.T, f, n @ rot.T


def _group(parts):
    verts, faces, normals = [], [], []
    count = 0
    for part in parts:
        params = {k: v for k, v in part.items() if k not in ("kind", "offset")}
        v, f, n = part_mesh(part["kind"], params)
        verts.append(v + np.asarray(part["offset"], dtype=np.float64))
        faces.append(f + count)
        normals.append(n)
        count += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(normals)


def _load_mesh(shape):
    import trimesh

    path = shape.params["path"]
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise UserError(f"{path}: cannot load mesh ({e})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise UserError(f"{path}: no triangles found in the mesh file")
    if len(loaded.faces) > MAX_MESH_FACES:
        raise UserError(f"{path}: the mesh has {len(loaded.faces)} faces, at most {MAX_MESH_FACES} are taken "
                        f"(decimate it first)")
    # before trimesh's processing, which drops non-finite vertices (and the faces using them)
    if not np.all(np.isfinite(loaded.vertices)):
        raise UserError(f"{path}: mesh has non-finite vertex positions (NaN or infinite)")
    loaded.process()
    if len(loaded.faces) == 0:
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
    elif kind == "group":
        verts, faces, normals = _group(shape.params["parts"])
    else:
        verts, faces, normals = part_mesh(kind, shape.params)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = 0.5 * (lo[:2] + hi[:2])
    rim = float(np.max(np.hypot(verts[:, 0] - centre[0], verts[:, 1] - centre[1])))
    if not (hi[0] > lo[0] and hi[1] > lo[1]):
        raise UserError(f"{shape.params.get('path', kind)}: the shape has no extent in the image plane")
    return ("mesh", {"vertices": verts, "faces": faces, "normals": normals},
            (lo[0], hi[0], lo[1], hi[1]), float(lo[2]), float(hi[2]), rim)
