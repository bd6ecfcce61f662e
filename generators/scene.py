"""Mitsuba scenes of the capture generator: the object under the lighting dome, seen by the
orthographic camera, and the scene that re-renders a per-pixel normal and thickness field.

Lighting is a uniform, unpolarized dome around the object (the paper's geodesic dome), so
every visible point reflects it specularly; :func:`normal_map_scene` also renders
rectangular images. Shapes are in :mod:`.shapes`, the view in :mod:`.frame`, thickness in
:mod:`.thickness`, ground truth in :mod:`.ground_truth`.
"""

from __future__ import annotations

import numpy as np

from .frame import Frame, frame_for
from .shapes import geometry
from .thickness import film_bsdf, thickness_map

__all__ = [
    "ENVMAP_ROWS",
    "CONVEX_SHAPES",
    "BSDF_SAMPLING_INTEGRATOR",
    "register_plugins",
    "dome_dict",
    "build_scene_dict",
    "build_scene",
    "rough_integrator",
    "normal_map_scene",
]

ENVMAP_ROWS = 2048  # latitude rows of the dome-with-hole environment map (0.088 deg each)
#: shape kinds that are (the outside of) a convex body: no light reflected by them reaches
#: them again, so one bounce to the dome is the whole light path
CONVEX_SHAPES = frozenset({"hemisphere", "cylinder", "pyramid"})
#: nested integrator of the many-sample path of :func:`.render.render_stokes_cube` for objects
#: that cannot reflect light onto themselves (convex ones): one BSDF sample per camera ray,
#: traced to the dome, no light sampling. For them it gives what the path tracer gives (light
#: sampling adds nothing under a dome that fills the sky), about as noisy, in about half the
#: time (40-50 % measured at 64 samples per pixel).
BSDF_SAMPLING_INTEGRATOR = {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1,
                            "hide_emitters": True}


def register_plugins() -> None:
    """Register the ``thinfilm`` BSDF and the ``imagespace`` texture in the current variant."""
    import mitsuba as mi

    if mi.variant() is None:
        raise RuntimeError("set a Mitsuba variant (llvm_ad_mono_polarized) before building scenes")
    import thinfilm.bsdf

    from . import textures

    thinfilm.bsdf.register()
    textures.register()


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


def _path_integrator(max_depth: int) -> dict:
    return {"type": "path", "max_depth": int(max_depth), "hide_emitters": True}


def _scene_dict(shape_entry, frame: Frame, hole_deg: float, max_depth: int) -> dict:
    import mitsuba as mi

    h = frame.half_width
    to_world = (mi.ScalarTransform4f().look_at(origin=[frame.cx, frame.cy, frame.camera_z],
                                               target=[frame.cx, frame.cy, frame.camera_z - 1.0],
                                               up=[0, 1, 0])
                @ mi.ScalarTransform4f().scale([h, h, 1.0]))
    return {
        "type": "scene",
        "integrator": {"type": "stokes", "nested": _path_integrator(max_depth)},
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


def build_scene_dict(spec):
    """The Mitsuba scene dictionary of a :class:`~.spec.SceneSpec`, its :class:`Frame` and
    thickness map.

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
    kind, geo, extent, zmin, zmax, rim = geometry(spec.shape)
    frame = frame_for(extent, zmin, zmax, rim, spec.rig.resolution, spec.rig.fill,
                      offset_px=(0.25, 0.125) if kind == "mesh" else (0.0, 0.0))
    thickness = thickness_map(spec.thickness, frame)
    bsdf = film_bsdf(spec.film, thickness, frame, roughness=spec.roughness)
    if kind == "sphere":
        shape_entry = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": geo["radius"], "bsdf": bsdf}
    elif kind == "cylinder":
        shape_entry = {"type": "cylinder", "p0": [0.0, -geo["half_length"], 0.0],
                       "p1": [0.0, geo["half_length"], 0.0], "radius": geo["radius"], "bsdf": bsdf}
    else:
        shape_entry = _mi_mesh("object", geo["vertices"], geo["faces"], geo["normals"], bsdf)
    return _scene_dict(shape_entry, frame, spec.rig.dome_hole_deg, spec.rig.max_depth), frame, thickness


def build_scene(spec):
    """Scene dictionary and ground truth of a :class:`~.spec.SceneSpec`.

    Returns
    -------
    scene_dict : dict
        For ``mi.load_dict`` or :func:`thinfilm.generators.render.render_stokes_cube`.
    ground_truth : dict
        As :func:`.ground_truth.cast_ground_truth`, plus ``frame`` (:class:`Frame`).
    """
    import mitsuba as mi

    from .ground_truth import cast_ground_truth

    scene_dict, frame, thickness = build_scene_dict(spec)
    gt = cast_ground_truth(mi.load_dict(scene_dict), thickness, frame)
    gt["frame"] = frame
    return scene_dict, gt


def rough_integrator(spec) -> dict:
    """The nested integrator that renders a rough film of a :class:`~.spec.SceneSpec` with
    many samples per pixel (:func:`thinfilm.generators.render.render_stokes_cube`).

    A shape of :data:`CONVEX_SHAPES` gets
    :data:`BSDF_SAMPLING_INTEGRATOR` (one BSDF sample traced to
    the dome: all there is for it, in about half the path tracer's time); any other gets the
    path tracer of the scene, ``rig.max_depth`` included, so that light reflected between its
    parts is kept.
    """
    if spec.shape.kind in CONVEX_SHAPES:
        return dict(BSDF_SAMPLING_INTEGRATOR)
    return _path_integrator(spec.rig.max_depth)


def normal_map_scene(normals, thickness_nm, mask, film, dome_hole_deg: float = 0.0, max_depth: int = 3,
                     roughness: float = 0.0) -> dict:
    """A scene that renders a per-pixel normal and thickness field through the same plugin
    and rig as the generator.

    Each masked pixel becomes a small flat triangle in the plane z = 0 around its pixel
    centre (not touching its neighbours), whose three vertices carry that pixel's normal as
    shading normal; the pixel-centre ray hits its interior, so the BSDF sees exactly the
    given normal, and the thickness is the given map looked up at the pixel centre. The
    camera, dome (with its hole) and integrator are the generator's.
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
    film : :class:`thinfilm.core.film.Film`
    dome_hole_deg : float
        Angular radius of the camera's hole in the lighting dome.
    roughness : float
        Microfacet roughness of the film (the plugin's ``alpha``; 0 is smooth).
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
    bsdf = film_bsdf(film, thickness, frame, roughness=roughness)
    hole = float(dome_hole_deg)
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
