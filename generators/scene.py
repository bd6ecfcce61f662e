"""Mitsuba scenes for the capture generator, and their ground truth by ray casting.

Conventions (``DESIGN.md``): orthographic camera looking along -z with image x to the
right and y up, row 0 at the top; one ray per pixel through its centre, square pixels. The
generator's object is centred in a square image (meshes: offset by a fraction of a pixel,
see :func:`frame_for`) and its larger projected extent fills ``rig.fill`` of it;
:func:`normal_map_scene` also renders rectangular images.

Shapes
------
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

Ground truth is obtained by casting exactly the camera's pixel-centre rays into the same
scene (:func:`cast_ground_truth`): the normal is the shading normal ``si.sh_frame.n`` the
BSDF is evaluated with, the thickness is the same texture lookup, and depth is the ray
distance from the image plane. Ground truth equals what the renderer shades with, by
construction.

Thickness lives in image space (:mod:`thinfilm.generators.textures`): a per-pixel map
sampled at pixel centres, looked up bilinearly at the orthographic image position of a
surface point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from thinfilm.errors import UserError

__all__ = [
    "Frame",
    "register_plugins",
    "frame_for",
    "thickness_map",
    "dome_dict",
    "build_scene",
    "build_scene_dict",
    "normal_map_scene",
    "cast_ground_truth",
    "ground_truth_from_normals",
]

ENVMAP_ROWS = 2048  # latitude rows of the dome-with-hole environment map (0.088 deg each)


@dataclass(frozen=True)
class Frame:
    """The orthographic view: a rectangle ``2 * half_width`` scene units wide centred at
    (``cx``, ``cy``), seen from ``camera_z`` along -z, ``resolution`` pixels wide and
    ``rows`` pixels high (square pixels).

    Attributes
    ----------
    rows : int or None
        Image height in pixels; ``None`` for a square image (``resolution`` rows).
    object_extent : tuple
        (xmin, xmax, ymin, ymax) of the object's projection, scene units.
    object_center : tuple
        (x, y) centre of that extent.
    rim_radius : float
        Largest distance of the object's silhouette from ``object_center``.
    """

    cx: float
    cy: float
    half_width: float
    camera_z: float
    far_clip: float
    resolution: int
    object_extent: tuple = (-1.0, 1.0, -1.0, 1.0)
    object_center: tuple = (0.0, 0.0)
    rim_radius: float = 1.0
    rows: int | None = None

    @property
    def height_px(self) -> int:
        """Image height in pixels (``resolution`` for a square image)."""
        return self.resolution if self.rows is None else int(self.rows)

    @property
    def pixel_size(self) -> float:
        return 2.0 * self.half_width / self.resolution

    @property
    def half_height(self) -> float:
        """Half the image height in scene units (``half_width`` for a square image)."""
        return self.half_width * self.height_px / self.resolution

    def pixel_centres(self):
        """World (x, y) of the pixel centres: two (H, W) arrays, row 0 at the top."""
        i = np.arange(self.resolution, dtype=np.float64) + 0.5
        j = np.arange(self.height_px, dtype=np.float64) + 0.5
        xs = self.cx - self.half_width + i * self.pixel_size
        ys = self.cy + self.half_height - j * self.pixel_size
        return np.meshgrid(xs, ys)

    def as_dict(self) -> dict:
        """JSON-ready description (the ``projection`` entry of ``meta.json``)."""
        x0, y1 = self.cx - self.half_width, self.cy + self.half_height
        return {
            "type": "orthographic",
            "view_direction": [0.0, 0.0, -1.0],
            "image_extent": [x0, x0 + 2 * self.half_width, y1 - 2 * self.half_height, y1],
            "pixel_size": self.pixel_size,
            "camera_z": self.camera_z,
            "depth": "distance from the image plane z = camera_z along -z (height = camera_z - depth)",
        }


def register_plugins() -> None:
    """Register the ``thinfilm`` BSDF and the ``imagespace`` texture in the current variant."""
    import mitsuba as mi

    if mi.variant() is None:
        raise RuntimeError("set a Mitsuba variant (llvm_ad_mono_polarized) before building scenes")
    import thinfilm.bsdf

    from . import textures

    thinfilm.bsdf.register()
    textures.register()


# --- geometry ------------------------------------------------------------------------------

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

    path = shape["path"]
    try:
        loaded = trimesh.load(path, force="mesh", process=True)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise UserError(f"{path}: cannot load mesh ({e})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise UserError(f"{path}: no triangles found in the mesh file")
    mesh = loaded.copy()
    mesh.apply_transform(np.block([[_rotation(shape["rotate_deg"]) * shape["scale"], np.zeros((3, 1))],
                                   [np.zeros((1, 3)), np.ones((1, 1))]]))
    if not np.all(np.isfinite(mesh.vertices)):
        raise UserError(f"{path}: mesh has non-finite vertex positions")
    lo, hi = mesh.bounds
    mesh.apply_translation([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    if mesh.is_watertight:
        mesh.fix_normals()  # consistent winding, normals pointing out of the solid
    elif np.sum(mesh.area_faces * mesh.face_normals[:, 2]) < -1e-9 * mesh.area:
        # An open surface (a sheet, a relief): orient it so that most of its projected
        # area faces the camera.
        mesh.invert()
    if shape["smooth"]:
        return (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64),
                np.asarray(mesh.vertex_normals, dtype=np.float64))
    tri = mesh.vertices[mesh.faces].reshape(-1, 3)
    return tri, np.arange(len(tri)).reshape(-1, 3), None


def _geometry(shape: dict):
    """(kind of Mitsuba shape, its parameters, projected extent, zmin, zmax, rim radius)."""
    kind = shape["kind"]
    if kind == "hemisphere":
        r = shape["radius"]
        return ("sphere", {"radius": r}, (-r, r, -r, r), 0.0, r, r)
    if kind == "cylinder":
        r, half = shape["radius"], 0.5 * shape["length"]
        return ("cylinder", {"radius": r, "half_length": half}, (-r, r, -half, half), 0.0, r,
                float(np.hypot(r, half)))
    if kind == "pyramid":
        verts, faces, normals = _pyramid_mesh(shape["base"], shape["height"])
    elif kind == "mesh":
        verts, faces, normals = _load_mesh(shape)
    else:  # pragma: no cover - load_spec validated it
        raise UserError(f"unknown shape kind {kind!r}")
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = 0.5 * (lo[:2] + hi[:2])
    rim = float(np.max(np.hypot(verts[:, 0] - centre[0], verts[:, 1] - centre[1])))
    if not (hi[0] > lo[0] and hi[1] > lo[1]):
        raise UserError(f"{shape.get('path', kind)}: the shape has no extent in the image plane")
    return ("mesh", {"vertices": verts, "faces": faces, "normals": normals},
            (lo[0], hi[0], lo[1], hi[1]), float(lo[2]), float(hi[2]), rim)


def frame_for(extent, zmin, zmax, rim, resolution, fill, offset_px=(0.0, 0.0)) -> Frame:
    """The camera frame that centres ``extent`` and lets its larger side fill ``fill``.

    ``offset_px`` shifts the object by that fraction of a pixel (x, y) from the image centre.
    Meshes use (1/4, 1/8): then no pixel centre lies exactly on a face edge through the
    object's centre along x, y or a diagonal (as the pyramid's are), where a ray hits two
    faces at the same distance and the choice between them is arbitrary.
    """
    xmin, xmax, ymin, ymax = (float(v) for v in extent)
    half = 0.5 * max(xmax - xmin, ymax - ymin) / fill
    depth_range = max(zmax - zmin, 0.0)
    camera_z = zmax + half
    pixel = 2.0 * half / int(resolution)
    cx = 0.5 * (xmin + xmax) - offset_px[0] * pixel
    cy = 0.5 * (ymin + ymax) - offset_px[1] * pixel
    return Frame(cx=cx, cy=cy, half_width=half, camera_z=camera_z,
                 far_clip=10.0 * (depth_range + 2 * half), resolution=int(resolution),
                 object_extent=(xmin, xmax, ymin, ymax),
                 object_center=(0.5 * (xmin + xmax), 0.5 * (ymin + ymax)), rim_radius=float(rim))


# --- thickness -----------------------------------------------------------------------------

def _read_bitmap(path: str) -> np.ndarray:
    from thinfilm.dataset import read_exr

    lower = path.lower()
    if lower.endswith(".npy"):
        try:
            img = np.load(path, allow_pickle=False)
        except Exception as e:
            raise UserError(f"{path}: cannot read thickness bitmap ({e})") from None
    elif lower.endswith(".exr"):
        ch = read_exr(path)
        for name in ("thickness", "Y", "R"):
            if name in ch:
                img = ch[name]
                break
        else:
            if len(ch) != 1:
                raise UserError(f"{path}: thickness bitmap needs a channel 'thickness', 'Y' or 'R', "
                                f"found {', '.join(sorted(ch))}")
            img = next(iter(ch.values()))
    else:
        raise UserError(f"{path}: thickness bitmap must be an .exr or .npy file of thickness in nm")
    img = np.asarray(img, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 1:
        raise UserError(f"{path}: thickness bitmap must be a 2-D image, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise UserError(f"{path}: thickness bitmap contains NaN or infinite values")
    if img.min() < 0:
        raise UserError(f"{path}: thickness bitmap has negative thickness {img.min():g} nm")
    return img


def _resample(img: np.ndarray, resolution: int) -> np.ndarray:
    """Bilinear resampling of an image covering the frame to ``resolution`` pixel centres."""
    if img.shape == (resolution, resolution):
        return img
    from scipy.ndimage import map_coordinates

    h, w = img.shape
    centres = (np.arange(resolution) + 0.5) / resolution
    rows, cols = np.meshgrid(centres * h - 0.5, centres * w - 0.5, indexing="ij")
    return map_coordinates(img, [rows, cols], order=1, mode="nearest")


def thickness_map(profile: dict, frame: Frame):
    """Film thickness (nm) at every pixel centre, (H, W) float32, or a float if uniform.

    ``linear`` runs from ``start`` to ``end`` across the object's projected extent (x: left
    to right, y: bottom to top), constant beyond it. ``radial`` falls linearly with the
    distance from the object's centre from ``center`` to ``edge`` at ``radius`` (0: the
    silhouette radius) and stays at ``edge`` beyond. ``bitmap`` stretches the image over the
    whole square frame (row 0 at the top).
    """
    kind = profile["profile"]
    if kind == "uniform":
        return float(profile["value"])
    x, y = frame.pixel_centres()
    if kind == "linear":
        xmin, xmax, ymin, ymax = frame.object_extent
        u = (x - xmin) / (xmax - xmin) if profile["axis"] == "x" else (y - ymin) / (ymax - ymin)
        t = profile["start"] + (profile["end"] - profile["start"]) * np.clip(u, 0.0, 1.0)
    elif kind == "radial":
        radius = profile["radius"] or frame.rim_radius
        r = np.hypot(x - frame.object_center[0], y - frame.object_center[1]) / radius
        t = profile["center"] + (profile["edge"] - profile["center"]) * np.clip(r, 0.0, 1.0)
    elif kind == "bitmap":
        t = _resample(_read_bitmap(profile["path"]), frame.resolution)
    else:  # pragma: no cover - validated by load_spec
        raise UserError(f"unknown thickness profile {kind!r}")
    return np.asarray(t, dtype=np.float32)


def _thickness_param(thickness, frame: Frame):
    """The ``thickness`` parameter of the BSDF: a float, or an ``imagespace`` texture dict."""
    if np.isscalar(thickness):
        return float(thickness)
    import mitsuba as mi

    data = np.ascontiguousarray(np.asarray(thickness, dtype=np.float32)[..., None])
    return {
        "type": "imagespace",
        "x0": frame.cx - frame.half_width,
        "y1": frame.cy + frame.half_height,
        "width": 2.0 * frame.half_width,
        "height": 2.0 * frame.half_height,
        "nested": {"type": "bitmap", "data": mi.TensorXf(data), "raw": True,
                   "filter_type": "bilinear", "wrap_mode": "clamp"},
    }


# --- scene pieces --------------------------------------------------------------------------

def dome_dict(hole_deg: float = 0.0) -> dict:
    """The lighting dome: uniform unpolarized radiance 1 from every direction; with
    ``hole_deg`` > 0, no light from within that angle of the camera direction (+z)."""
    if hole_deg <= 0:
        return {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}
    import mitsuba as mi

    rows, cols = ENVMAP_ROWS, 8
    theta = (np.arange(rows) + 0.5) * (180.0 / rows)  # row centre, angle from the pole
    img = np.ones((rows, cols, 3), dtype=np.float32)
    img[theta < hole_deg] = 0.0
    # The envmap's pole (row 0) is its local +y; rotate it onto +z, the camera direction.
    return {"type": "envmap", "bitmap": mi.Bitmap(img),
            "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}


def _mi_mesh(name, vertices, faces, normals, bsdf_dict):
    import drjit as dr
    import mitsuba as mi

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf_dict)
    mesh = mi.Mesh(name, len(vertices), len(faces), props=props,
                   has_vertex_normals=normals is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(np.asarray(vertices, dtype=np.float32).T))
    params["faces"] = dr.ravel(mi.Point3u(np.asarray(faces, dtype=np.uint32).T))
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        params["vertex_normals"] = dr.ravel(mi.Normal3f(n.astype(np.float32).T))
    params.update()
    return mesh


def _scene_dict(shape_entry, frame: Frame, hole_deg: float, max_depth: int) -> dict:
    import mitsuba as mi

    h = frame.half_width
    to_world = (mi.ScalarTransform4f().look_at(origin=[frame.cx, frame.cy, frame.camera_z],
                                               target=[frame.cx, frame.cy, frame.camera_z - 1.0],
                                               up=[0, 1, 0])
                @ mi.ScalarTransform4f().scale([h, h, 1.0]))
    return {
        "type": "scene",
        "integrator": {"type": "stokes",
                       "nested": {"type": "path", "max_depth": int(max_depth), "hide_emitters": True}},
        "sensor": {
            "type": "orthographic",
            "to_world": to_world,
            "near_clip": 1e-3 * h,
            "far_clip": frame.far_clip,
            "film": {"type": "hdrfilm", "width": frame.resolution, "height": frame.height_px,
                     "rfilter": {"type": "box"}, "pixel_format": "luminance", "sample_border": False},
            "sampler": {"type": "stratified", "sample_count": 1, "jitter": False},
        },
        "object": shape_entry,
        "dome": dome_dict(hole_deg),
    }


def _bsdf_dict(film_ior, substrate_ior, substrate_k, thickness_param) -> dict:
    return {"type": "thinfilm", "thickness": thickness_param, "film_ior": film_ior,
            "substrate_ior": float(substrate_ior), "substrate_k": float(substrate_k)}


def build_scene_dict(spec: dict):
    """The Mitsuba scene dictionary of a resolved spec, its :class:`Frame` and thickness map.

    Returns
    -------
    scene_dict : dict
        Loadable with ``mi.load_dict`` (needs :func:`register_plugins`; the mesh of a
        ``pyramid`` or ``mesh`` shape is already an ``mi.Mesh``).
    frame : Frame
    thickness : float or ndarray (H, W) float32
        What the BSDF's thickness texture holds (nm).
    """
    register_plugins()
    kind, geo, extent, zmin, zmax, rim = _geometry(spec["shape"])
    frame = frame_for(extent, zmin, zmax, rim, spec["rig"]["resolution"], spec["rig"]["fill"],
                      offset_px=(0.25, 0.125) if kind == "mesh" else (0.0, 0.0))
    thickness = thickness_map(spec["film"]["thickness"], frame)
    bsdf = _bsdf_dict(spec["film"]["ior"], spec["substrate"]["ior"], spec["substrate"]["k"],
                      _thickness_param(thickness, frame))
    if kind == "sphere":
        shape_entry = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": geo["radius"], "bsdf": bsdf}
    elif kind == "cylinder":
        shape_entry = {"type": "cylinder", "p0": [0.0, -geo["half_length"], 0.0],
                       "p1": [0.0, geo["half_length"], 0.0], "radius": geo["radius"], "bsdf": bsdf}
    else:
        shape_entry = _mi_mesh("object", geo["vertices"], geo["faces"], geo["normals"], bsdf)
    return _scene_dict(shape_entry, frame, spec["rig"]["dome_hole_deg"], spec["rig"]["max_depth"]), \
        frame, thickness


# --- ground truth --------------------------------------------------------------------------

def _pixel_rays(sensor, width, height):
    """The rays of a 1-spp, non-jittered render: through the pixel centres, row-major."""
    import drjit as dr
    import mitsuba as mi

    idx = dr.arange(mi.UInt32, width * height)
    row = idx // width
    col = idx - row * width
    pos = mi.Point2f((mi.Float(col) + 0.5) * mi.Float(1.0 / width),
                     (mi.Float(row) + 0.5) * mi.Float(1.0 / height))
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    return ray


def cast_ground_truth(scene, thickness=None, frame: Frame | None = None) -> dict:
    """Ground truth at the pixel centres of a loaded scene's sensor.

    Parameters
    ----------
    scene : mitsuba.Scene
    thickness : float or ndarray (H, W), optional
        The thickness the BSDF was given; a map is looked up through the same
        ``imagespace`` texture at the hit points (needs ``frame``).
    frame : Frame, optional

    Returns
    -------
    dict
        ``normal`` (H, W, 3), ``zenith``, ``azimuth`` (deg), ``thickness`` (nm), ``depth``
        (distance from the image plane through the camera origin, along -z), ``mask`` (bool: a hit whose shading normal faces
        the camera). Background pixels hold 0.
    """
    import drjit as dr
    import mitsuba as mi

    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    ray = _pixel_rays(sensor, width, height)
    si = scene.ray_intersect(mi.Ray3f(ray))
    valid = si.is_valid()
    n = si.sh_frame.n
    values = [valid, n.x, n.y, n.z, si.p]
    t_nm = None
    if thickness is not None and not np.isscalar(thickness):
        if frame is None:
            raise ValueError("cast_ground_truth: a thickness map needs its frame")
        tex = mi.load_dict(_thickness_param(thickness, frame))
        t_nm = tex.eval_1(si, valid)
        values.append(t_nm)
    dr.eval(*values)
    hit = np.asarray(valid, dtype=bool).reshape(height, width)
    normal = np.stack([np.asarray(c, dtype=np.float64).reshape(height, width) for c in (n.x, n.y, n.z)], axis=-1)
    mask = hit & (normal[..., 2] > 0)
    normal[~mask] = 0.0
    # Depth from the image plane through the camera origin (rays start at the near clip).
    camera_z = float(np.asarray((sensor.world_transform() @ mi.Point3f(0, 0, 0)).z)[0])
    depth = np.where(mask, camera_z - np.asarray(si.p.z, dtype=np.float64).reshape(height, width), 0.0)
    if t_nm is not None:
        thick = np.asarray(t_nm, dtype=np.float64).reshape(height, width)
    else:
        thick = np.full((height, width), float(thickness) if thickness is not None else 0.0)
    thick = np.where(mask, thick, 0.0)
    gt = ground_truth_from_normals(normal, mask)
    gt.update(thickness=thick, depth=depth)
    return gt


def ground_truth_from_normals(normal: np.ndarray, mask: np.ndarray) -> dict:
    """``normal``, ``zenith`` = arccos(n_z) and ``azimuth`` = atan2(n_y, n_x) in [0, 360)
    (degrees, :func:`thinfilm.reconstruction.estimate.normals_to_angles`), zero outside
    ``mask``; ``mask`` as bool."""
    from thinfilm.reconstruction.estimate import normals_to_angles

    mask = np.asarray(mask, dtype=bool)
    normal = np.where(mask[..., None], normal, 0.0)
    zenith, azimuth = normals_to_angles(normal)
    return {"normal": normal, "zenith": np.where(mask, zenith, 0.0),
            "azimuth": np.where(mask, azimuth, 0.0), "mask": mask}


def build_scene(spec: dict):
    """Scene dictionary and ground truth of a resolved spec.

    Returns
    -------
    scene_dict : dict
        For ``mi.load_dict`` or :func:`thinfilm.generators.render.render_stokes_cube`.
    ground_truth : dict
        As :func:`cast_ground_truth`, plus ``frame`` (:class:`Frame`).
    """
    import mitsuba as mi

    scene_dict, frame, thickness = build_scene_dict(spec)
    gt = cast_ground_truth(mi.load_dict(scene_dict), thickness, frame)
    gt["frame"] = frame
    return scene_dict, gt


# --- re-rendering estimates ----------------------------------------------------------------

def normal_map_scene(normals, thickness_nm, mask, film_ior, substrate_ior, substrate_k=0.0,
                     rig=None, max_depth: int = 3) -> dict:
    """A scene that renders a per-pixel normal and thickness field through the same plugin
    and rig as the generator.

    Each masked pixel becomes a small flat triangle in the plane z = 0 around its pixel
    centre (not touching its neighbours), whose three vertices carry that pixel's normal as
    shading normal; the pixel-centre ray hits its interior, so the BSDF sees exactly the
    given normal, and the thickness is the given map looked up at the pixel centre. The
    camera, dome and integrator are the generator's (``rig["dome_hole_deg"]`` is honoured).
    Inter-reflections and self-shadowing of the true surface are not reproduced: exact for
    convex objects (the presets), an approximation otherwise. Images may be rectangular:
    the orthographic view is 2 scene units wide and ``2 H / W`` high (square pixels).

    Parameters
    ----------
    normals : array (H, W, 3)
        Unit normals in the camera frame (x right, y up, z towards the camera). Pixels with
        n_z <= 0 or non-finite entries are left out (render black).
    thickness_nm : float or array (H, W)
        Film thickness in nm (non-finite or negative values are treated as 0).
    mask : array (H, W) of bool
        Pixels to render; others are background (0).
    film_ior, substrate_ior, substrate_k : float (film_ior may be a material name)
    rig : dict, optional
        Only ``dome_hole_deg`` is read (default 0).
    max_depth : int

    Returns
    -------
    dict
        A scene dictionary for ``mi.load_dict`` or ``render_stokes_cube``.
    """
    normals = np.asarray(normals, dtype=np.float64)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise ValueError(f"normals must be (H, W, 3), got {normals.shape}")
    height, width = normals.shape[:2]
    mask = np.asarray(mask, dtype=bool) & np.all(np.isfinite(normals), axis=-1) & (normals[..., 2] > 0)
    register_plugins()
    frame = Frame(cx=0.0, cy=0.0, half_width=1.0, camera_z=1.0, far_clip=100.0, resolution=width,
                  rows=None if height == width else height)
    if np.isscalar(thickness_nm):
        thickness = max(float(thickness_nm), 0.0) if np.isfinite(thickness_nm) else 0.0
    else:
        thickness = np.asarray(thickness_nm, dtype=np.float64)
        if thickness.shape != (height, width):
            raise ValueError(f"thickness_nm must be ({height}, {width}), got {thickness.shape}")
        thickness = np.where(np.isfinite(thickness), np.maximum(thickness, 0.0), 0.0).astype(np.float32)
    bsdf = _bsdf_dict(film_ior, substrate_ior, substrate_k, _thickness_param(thickness, frame))
    hole = float((rig or {}).get("dome_hole_deg", 0.0))
    rows, cols = np.nonzero(mask)
    if rows.size == 0:
        # Nothing to render: a tiny triangle outside the view keeps the scene valid.
        rows, cols, far = np.array([0]), np.array([0]), True
    else:
        far = False
    x, y = frame.pixel_centres()
    cx, cy = x[rows, cols], y[rows, cols]
    r = 0.45 * frame.pixel_size
    angles = np.radians([90.0, 210.0, 330.0])
    verts = np.empty((rows.size, 3, 3))
    verts[:, :, 0] = cx[:, None] + r * np.cos(angles)[None, :]
    verts[:, :, 1] = cy[:, None] + r * np.sin(angles)[None, :]
    verts[:, :, 2] = -50.0 if far else 0.0
    n = normals[rows, cols] / np.linalg.norm(normals[rows, cols], axis=-1, keepdims=True)
    vnorm = np.repeat(n[:, None, :], 3, axis=1) if not far else np.tile([0.0, 0.0, 1.0], (1, 3, 1))
    faces = np.arange(3 * rows.size).reshape(-1, 3)
    if far:
        verts[:, :, 0] += 100.0
    shape = _mi_mesh("object", verts.reshape(-1, 3), faces, vnorm.reshape(-1, 3), bsdf)
    return _scene_dict(shape, frame, hole, max_depth)
