"""The orthographic view of the capture generator: where the camera looks and its pixels.

Conventions (``docs/design.md``, *Conventions*): orthographic camera looking along -z with
image x to the right and y up, row 0 at the top; one ray per pixel through its centre, square
pixels. The generator's object is centred in a square image (meshes: offset by a fraction of a
pixel, see :func:`frame_for`) and its larger projected extent fills ``rig.fill`` of it.

Examples
--------
>>> f = frame_for((-1.0, 1.0, -1.0, 1.0), 0.0, 1.0, 1.0, resolution=4, fill=1.0)
>>> f.pixel_size
0.5
>>> xs, ys = f.pixel_centres()
>>> xs[0].tolist(), ys[:, 0].tolist()
([-0.75, -0.25, 0.25, 0.75], [0.75, 0.25, -0.25, -0.75])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Frame", "frame_for"]


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
