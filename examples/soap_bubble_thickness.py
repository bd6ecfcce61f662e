"""Write ``soap_bubble_thickness.exr``: the wall thickness (nm) of a draining soap bubble.

The texture is indexed by the sphere's (u, v) = (azimuth / 2π, polar angle / π), v = 0 at the
top. Gravity drains the film: about 100 nm at the top (where a bubble first turns dark before
it bursts) growing to about 900 nm at the bottom, with a few slow swirls of thickness (the
Marangoni flows that make bubbles shimmer). Run it again to regenerate the file (the same
numbers every time):

    python examples/soap_bubble_thickness.py
"""

from pathlib import Path

import numpy as np


def thickness_nm(u, v):
    """Film thickness at texture coordinates (u, v) in [0, 1]²."""
    drained = 100.0 + 800.0 * v**1.6
    swirl = (np.sin(2 * np.pi * (2 * u + 1.5 * v) + 4.0 * np.sin(2 * np.pi * v))
             + 0.6 * np.sin(2 * np.pi * (5 * u - 3 * v) + 1.3))
    return drained + 70.0 * swirl * np.sin(np.pi * v) ** 2


def main():
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    height, width = 96, 192
    v, u = np.meshgrid((np.arange(height) + 0.5) / height, (np.arange(width) + 0.5) / width,
                       indexing="ij")
    data = thickness_nm(u, v).astype(np.float32)[..., None]
    out = Path(__file__).with_suffix(".exr")
    bitmap = mi.Bitmap(data, mi.Bitmap.PixelFormat.Y)
    bitmap.convert(component_format=mi.Struct.Type.Float16).write(str(out))  # half: ample for nm
    print(f"wrote {out} ({width}x{height}, {data.min():.0f}-{data.max():.0f} nm)")


if __name__ == "__main__":
    main()
