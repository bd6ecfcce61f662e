"""Reading camera images: 8-, 12- and 16-bit PNG and TIFF, kept as the integers they hold.

:func:`read_image` returns the samples as stored (no scaling, no gamma) with their bit depth:

* TIFF through ``tifffile``: unsigned 8- or 16-bit samples (``BitsPerSample`` gives the depth,
  12 for packed 12-bit files), or 32/64-bit floats, which are taken as values already
  normalized to [0, 1] (no bit depth, no saturation level).
* PNG through ``imagecodecs`` (libpng), which keeps 16-bit colour samples (Pillow reduces
  them to 8 bits); the chunk headers are read here for the bit depth. A PNG ``sBIT`` chunk
  that declares fewer significant bits (a 12-bit camera image scaled up to 16 bits, as the PNG
  standard asks) brings the samples back to that depth.

A 12-bit camera usually stores its values unshifted in 16-bit files (0 … 4095): give the
depth with ``--bit-depth 12`` then (the file cannot tell). Bad files stop with one line naming
the file (:class:`~thinfilm.core.errors.UserError`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError
from thinfilm.core.extras import require_extra

__all__ = ["CameraImage", "read_image", "apply_bit_depth"]


@dataclass
class CameraImage:
    """Samples of one image file.

    Attributes
    ----------
    data : (H, W) or (H, W, C) unsigned integers, or floats for float TIFFs.
    bits : bit depth of the values (8, 12, 16, …); None for float data.
    container_bits : bits per sample in the file (8 or 16; None for floats).
    path : the file.
    """

    data: np.ndarray
    bits: int | None
    container_bits: int | None
    path: Path

    @property
    def is_float(self) -> bool:
        return self.bits is None

    @property
    def max_code(self) -> float | None:
        """The largest value the bit depth can hold, ``2^bits − 1`` (None for floats)."""
        return None if self.bits is None else float(2 ** self.bits - 1)


def read_image(path, what: str = "image") -> CameraImage:
    """Read a PNG or TIFF camera image (see the module docstring). ``what`` names the role
    in errors (``"image"``, ``"--dark"`` …)."""
    from thinfilm.core.files import open_regular

    p = Path(path)
    with open_regular(p, f"{what} file") as f:
        try:
            head = f.read(8)
        except OSError as e:
            raise UserError(f"{p}: cannot read the {what} ({e.strerror})") from None
    if head.startswith(b"\x89PNG\r\n\x1a\n"):
        img = _read_png(p, what)
    elif head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        img = _read_tiff(p, what)
    else:
        raise UserError(f"{p}: the {what} is neither a PNG nor a TIFF file")
    if img.data.size == 0:
        raise UserError(f"{p}: the {what} holds no pixels")
    if img.is_float and not np.all(np.isfinite(img.data)):
        raise UserError(f"{p}: the {what} contains NaN or infinite values")
    return img


def apply_bit_depth(img: CameraImage, bits: int | None, where: str = "--bit-depth") -> CameraImage:
    """The image with its values declared ``bits`` deep (``--bit-depth``): the container must
    be at least that deep and no value may exceed ``2^bits − 1``."""
    if bits is None or img.is_float:
        return img
    if bits > img.container_bits:
        raise UserError(f"{img.path}: {where} is {bits} bits but the file holds {img.container_bits}-bit samples")
    top = int(img.data.max())
    if top > 2 ** bits - 1:
        raise UserError(f"{img.path}: holds values up to {top}, above the largest {bits}-bit value "
                        f"{2 ** bits - 1} ({where})")
    return CameraImage(img.data, int(bits), img.container_bits, img.path)


# -- TIFF -------------------------------------------------------------------------------------

def _read_tiff(p: Path, what: str) -> CameraImage:
    tifffile = require_extra("tifffile", "import", what=f"{p}: reading a TIFF {what}")
    try:
        with tifffile.TiffFile(p) as tif:
            if len(tif.series) != 1 or len(tif.pages) != 1:
                raise UserError(f"{p}: the {what} must be one image, the TIFF holds {len(tif.pages)} pages")
            page = tif.pages[0]
            data = page.asarray()
            bits_tag = page.bitspersample
    except UserError:
        raise
    except Exception as e:  # tifffile raises many types for damaged or unsupported files
        raise UserError(f"{p}: cannot read the TIFF {what} ({_one_line(e)})") from None
    data = np.asarray(data)
    if data.dtype.kind == "f":
        return CameraImage(data.astype(np.float64), None, None, p)
    if data.dtype not in (np.uint8, np.uint16):
        raise UserError(f"{p}: the {what} has {data.dtype} samples; expected unsigned 8- or 16-bit "
                        f"integers (or floats)")
    container = 8 * data.dtype.itemsize
    bits = int(bits_tag) if bits_tag and int(bits_tag) <= container else container
    return _squeeze(CameraImage(data, bits, container, p), what)


# -- PNG --------------------------------------------------------------------------------------

def _png_chunks(raw: bytes, p: Path):
    """(type, data) of every chunk; damaged structure → UserError."""
    pos = 8
    while pos + 8 <= len(raw):
        length, ctype = struct.unpack(">I4s", raw[pos:pos + 8])
        data = raw[pos + 8:pos + 8 + length]
        if len(data) != length:
            raise UserError(f"{p}: truncated PNG file")
        yield ctype, data
        pos += 12 + length
        if ctype == b"IEND":
            return
    raise UserError(f"{p}: truncated PNG file (no IEND chunk)")


def _read_png(p: Path, what: str) -> CameraImage:
    from thinfilm.core.files import read_bytes_file

    raw = read_bytes_file(p, f"{what} file")
    chunks = list(_png_chunks(raw, p))
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        raise UserError(f"{p}: damaged PNG file (no IHDR chunk)")
    width, height, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    if ctype == 3:
        raise UserError(f"{p}: the {what} is a palette PNG; expected gray or RGB camera values")
    if depth not in (8, 16):
        raise UserError(f"{p}: the {what} has {depth}-bit samples; expected 8 or 16 bits")
    # imagecodecs (libpng) keeps 16-bit colour samples, which Pillow reduces to 8 bits
    imagecodecs = require_extra("imagecodecs", "import", what=f"{p}: reading a PNG {what}")
    try:
        data = imagecodecs.png_decode(raw)
    except Exception as e:
        raise UserError(f"{p}: cannot read the PNG {what} ({_one_line(e)})") from None
    data = np.asarray(data).astype(np.uint16 if depth == 16 else np.uint8, copy=False)
    if ctype in (4, 6):  # drop alpha
        data = data[..., :-1]
    bits = depth
    sbit = next((d for t, d in chunks if t == b"sBIT"), None)
    if sbit:
        significant = max(sbit[:3] if ctype in (2, 6) else sbit[:1])
        if 0 < significant < depth:
            data = data >> (depth - significant)
            bits = int(significant)
    return _squeeze(CameraImage(np.ascontiguousarray(data), bits, depth, p), what)


def _squeeze(img: CameraImage, what: str) -> CameraImage:
    d = img.data
    if d.ndim == 3 and d.shape[-1] == 1:
        d = d[..., 0]
    if d.ndim not in (2, 3) or (d.ndim == 3 and d.shape[-1] not in (3, 4)):
        raise UserError(f"{img.path}: the {what} has shape {d.shape}; expected a gray (H, W) or RGB "
                        f"(H, W, 3) image")
    if d.ndim == 3 and d.shape[-1] == 4:
        d = d[..., :3]
    return CameraImage(d, img.bits, img.container_bits, img.path)


def _one_line(e: Exception) -> str:
    return " ".join(str(e).split())[:200] or type(e).__name__
