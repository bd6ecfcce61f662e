"""Helpers for the import tests: image writers and an independently written sensor layout."""

from __future__ import annotations

import struct
import zlib

import numpy as np

#: Sony IMX250MYR, copied from its datasheet's figure (row 0 = top row of the image): polarizer
#: blocks [[90, 45], [135, 0]] under an RGGB Bayer of 2 x 2 blocks. Written out cell by cell,
#: independently of thinfilm.core.mosaic.
IMX250MYR = [["R90", "R45", "G90", "G45"],
             ["R135", "R0", "G135", "G0"],
             ["G90", "G45", "B90", "B45"],
             ["G135", "G0", "B135", "B0"]]


def build_mosaic(images: dict, table=IMX250MYR) -> np.ndarray:
    """Mosaic of per-angle RGB images, pixel by pixel from a table of cells ('R90' …)."""
    first = next(iter(images.values()))
    h, w = first.shape[:2]
    p, q = len(table), len(table[0])
    out = np.zeros((h, w))
    for r in range(h):
        for c in range(w):
            cell = table[r % p][c % q]
            out[r, c] = images[int(cell[1:])][r, c, "RGB".index(cell[0])]
    return out


def write_png16_rgb(path, arr, filters=(0,)):
    """A 16-bit RGB PNG written by hand, row filters cycling through ``filters`` (0 None,
    1 Sub, 2 Up, 3 Average, 4 Paeth; PNG spec section 9)."""
    arr = np.asarray(arr, dtype=np.uint16)
    h, w, ch = arr.shape
    data = arr.astype(">u2").tobytes()
    bpp = 2 * ch
    stride = w * bpp
    rows = [np.frombuffer(data[i * stride:(i + 1) * stride], dtype=np.uint8).astype(int) for i in range(h)]
    out = b""
    prev = np.zeros(stride, dtype=int)
    for i, row in enumerate(rows):
        f = filters[i % len(filters)]
        left = np.concatenate([np.zeros(bpp, dtype=int), row[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, dtype=int), prev[:-bpp]])
        if f == 0:
            enc = row
        elif f == 1:
            enc = row - left
        elif f == 2:
            enc = row - prev
        elif f == 3:
            enc = row - (left + prev) // 2
        else:
            pred = []
            for a, b, c in zip(left, prev, upleft):
                p0 = a + b - c
                pa, pb, pc = abs(p0 - a), abs(p0 - b), abs(p0 - c)
                pred.append(a if pa <= pb and pa <= pc else (b if pb <= pc else c))
            enc = row - np.asarray(pred)
        out += bytes([f]) + (enc % 256).astype(np.uint8).tobytes()
        prev = row

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 16, 2 if ch == 3 else 6, 0, 0, 0)
    with open(path, "wb") as fh:
        fh.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(out)) + chunk(b"IEND", b""))
    return path


def write_png(path, arr, sbit=None):
    """8-bit (uint8) or 16-bit gray / 8-bit RGB PNG through Pillow; ``sbit`` adds an sBIT chunk."""
    from PIL import Image

    arr = np.asarray(arr)
    Image.fromarray(arr).save(path)
    if sbit is not None:
        raw = open(path, "rb").read()
        d = bytes([sbit] * (3 if arr.ndim == 3 else 1))
        c = struct.pack(">I", len(d)) + b"sBIT" + d + struct.pack(">I", zlib.crc32(b"sBIT" + d) & 0xFFFFFFFF)
        pos = 8 + 8 + 13 + 4  # after IHDR
        open(path, "wb").write(raw[:pos] + c + raw[pos:])
    return path


def write_tiff(path, arr):
    import tifffile

    arr = np.asarray(arr)
    tifffile.imwrite(path, arr, photometric="rgb" if arr.ndim == 3 and arr.shape[-1] == 3 else "minisblack")
    return path


def smooth_images(h, w, angles=(0, 45, 90, 135), seed=0):
    """Smooth, positive, polarized RGB images (Malus' law of a smooth Stokes field)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
    S0 = np.stack([0.3 + 0.2 * np.sin(2 + 3 * xx + k) * np.cos(1 + 2 * yy) for k in range(3)], -1)
    rho = 0.3 + 0.2 * xx[..., None]
    phi = np.pi * (yy[..., None] + 0.1 * rng.random(3))
    out = {}
    for a in angles:
        t = np.radians(a)
        out[int(a)] = 0.5 * S0 * (1 + rho * np.cos(2 * t - 2 * phi))
    return out
