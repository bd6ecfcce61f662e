"""Ground truth by ray casting the camera's pixel-centre rays into the rendered scene.

The normal is the shading normal ``si.sh_frame.n`` the BSDF is evaluated with, the thickness
is the same texture lookup, and depth is the ray distance from the image plane: ground truth
equals what the renderer shades with, by construction.
"""

from __future__ import annotations

import numpy as np

from thinfilm.core.conventions import normals_to_angles

from .frame import Frame
from .thickness import thickness_texture

__all__ = ["cast_ground_truth", "ground_truth_from_normals"]


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
        tex = mi.load_dict(thickness_texture(thickness, frame))
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
    (degrees, :func:`thinfilm.core.conventions.normals_to_angles`), zero outside ``mask``;
    ``mask`` as bool."""
    mask = np.asarray(mask, dtype=bool)
    normal = np.where(mask[..., None], normal, 0.0)
    zenith, azimuth = normals_to_angles(normal)
    return {"normal": normal, "zenith": np.where(mask, zenith, 0.0),
            "azimuth": np.where(mask, azimuth, 0.0), "mask": mask}
