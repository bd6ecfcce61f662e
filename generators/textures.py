"""Mitsuba texture plugin ``imagespace``: a texture looked up by image position.

The capture generator describes spatially varying film thickness as an image (one value
per pixel of the orthographic camera). This texture maps a surface point ``si.p`` to that
image through the orthographic projection along -z, so any shape (Mitsuba's analytic
``sphere`` and ``cylinder``, meshes with or without UVs) can carry it, and the ground truth
read at a pixel centre is exactly the value the renderer used there.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Meaning
   * - ``nested``
     - texture
     - The image, usually ``bitmap`` with ``raw: True``: row 0 is the top (largest y).
   * - ``x0``, ``y1``
     - float
     - World x of the image's left edge and world y of its top edge.
   * - ``width``, ``height``
     - float
     - World size of the image (> 0).

Only the nested texture is exposed through ``traverse`` (as ``nested``).

Example
-------
>>> import mitsuba as mi                                   # doctest: +SKIP
>>> mi.set_variant("llvm_ad_mono_polarized")               # doctest: +SKIP
>>> register()                                             # doctest: +SKIP
>>> tex = mi.load_dict({"type": "imagespace", "x0": -1.0, "y1": 1.0, "width": 2.0,
...                     "height": 2.0, "nested": {"type": "bitmap", "raw": True,
...                     "data": mi.TensorXf(image[..., None])}})  # doctest: +SKIP
"""

from __future__ import annotations

import mitsuba as mi

__all__ = ["register", "texture_class"]


class _ImageSpaceMixin:
    """Texture evaluated at the orthographic image position of ``si.p``."""

    def __init__(self, props):
        mi.Texture.__init__(self, props)
        self.m_nested = props.get("nested")
        if not isinstance(self.m_nested, mi.Texture):
            raise ValueError("imagespace: parameter 'nested' must be a texture")
        self.m_x0 = float(props.get("x0"))
        self.m_y1 = float(props.get("y1"))
        width, height = float(props.get("width")), float(props.get("height"))
        if not (width > 0 and height > 0):
            raise ValueError("imagespace: 'width' and 'height' must be > 0")
        self.m_inv_w = 1.0 / width
        self.m_inv_h = 1.0 / height

    def _remap(self, si):
        out = mi.SurfaceInteraction3f(si)
        out.uv = mi.Point2f((si.p.x - self.m_x0) * self.m_inv_w, (self.m_y1 - si.p.y) * self.m_inv_h)
        return out

    def eval(self, si, active=True):
        return self.m_nested.eval(self._remap(si), active)

    def eval_1(self, si, active=True):
        return self.m_nested.eval_1(self._remap(si), active)

    def mean(self):
        return self.m_nested.mean()

    def max(self):
        return self.m_nested.max()

    def traverse(self, callback):
        callback.put("nested", self.m_nested, mi.ParamFlags.Differentiable)

    def to_string(self):
        return (f"ImageSpaceTexture[x0={self.m_x0}, y1={self.m_y1}, "
                f"width={1.0 / self.m_inv_w}, height={1.0 / self.m_inv_h}]")


def texture_class():
    """The plugin class for the current Mitsuba variant."""
    from thinfilm.bsdf.bsdf_common import variant_class

    return variant_class(_ImageSpaceMixin, "Texture", "ImageSpaceTexture")


def register() -> None:
    """Make ``'type': 'imagespace'`` loadable in the current variant (idempotent)."""
    cls = texture_class()
    mi.register_texture("imagespace", lambda props: cls(props))
