"""Reading camera images: 8-, 12- and 16-bit PNG and TIFF, kept as the integers they hold.

:func:`read_image` returns the samples as stored (no scaling, no gamma) with their bit depth:

* TIFF through ``tifffile``: unsigned 8- or 16-bit samples (``BitsPerSample`` gives the depth,
  12 for packed 12-bit files), or 32/64-bit floats, which are taken as values already
  normalized to [0, 1] (no bit depth, no saturation level).
* PNG through Pillow, except 16-bit colour PNGs, which Pillow reduces to 8 bits: those are
  decoded here (:func:`_decode_png`, zlib and the five PNG row filters). A PNG ``sBIT`` chunk
  that declares fewer significant bits (a 12-bit camera image scaled up to 16 bits, as the PNG
  standard asks) brings the samples back to that depth.

A 12-bit camera usually stores its values unshifted in 16-bit files (0 … 4095): give the
depth with ``--bit-depth 12`` then (the file cannot tell). Bad files stop with one line naming
the file (:class:`~thinfilm.core.errors.UserError`).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thinfilm.core.errors import UserError

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
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: {what} file not found")
    try:
        head = p.read_bytes()[:8]
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
    import tifffile

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
    raw = p.read_bytes()
    chunks = list(_png_chunks(raw, p))
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        raise UserError(f"{p}: damaged PNG file (no IHDR chunk)")
    width, height, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    if ctype == 3:
        raise UserError(f"{p}: the {what} is a palette PNG; expected gray or RGB camera values")
    if depth not in (8, 16):
        raise UserError(f"{p}: the {what} has {depth}-bit samples; expected 8 or 16 bits")
    if depth == 16 and ctype in (2, 4, 6):
        if interlace:
            raise UserError(f"{p}: interlaced 16-bit colour PNGs are not supported; save it without interlacing")
        data = _decode_png(chunks, width, height, ctype, p)
    else:
        from PIL import Image

        try:
            with Image.open(p) as im:
                im.load()
                data = np.asarray(im)
        except Exception as e:
            raise UserError(f"{p}: cannot read the PNG {what} ({_one_line(e)})") from None
        data = data.astype(np.uint16 if depth == 16 else np.uint8, copy=False)
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


def _decode_png(chunks, width, height, ctype, p: Path) -> np.ndarray:
    """16-bit colour PNG samples (H, W, C) uint16: inflate the IDAT stream and undo the row
    filters (PNG spec, section 9) on all rows at once, one anti-diagonal of pixels per step
    (a pixel's prediction needs its left, upper and upper-left neighbours)."""
    channels = {2: 3, 4: 2, 6: 4}[ctype]
    bpp = 2 * channels
    try:
        stream = zlib.decompress(b"".join(d for t, d in chunks if t == b"IDAT"))
    except zlib.error as e:
        raise UserError(f"{p}: damaged PNG data ({e})") from None
    row_bytes = width * bpp
    if len(stream) < height * (row_bytes + 1):
        raise UserError(f"{p}: truncated PNG data")
    rows = np.frombuffer(stream, dtype=np.uint8, count=height * (row_bytes + 1)).reshape(height, row_bytes + 1)
    filters = rows[:, 0].astype(np.int64)
    if np.any(filters > 4):
        raise UserError(f"{p}: damaged PNG data (unknown row filter)")
    coded = rows[:, 1:].reshape(height, width, bpp).astype(np.int64)
    out = np.zeros((height + 1, width + 1, bpp), dtype=np.int64)  # row 0 / column 0: zeros
    if np.all(filters == 0):
        out[1:, 1:] = coded
    else:
        r_all = np.arange(height)
        for d in range(height + width - 1):
            r = r_all[max(0, d - width + 1):min(height - 1, d) + 1]
            x = d - r
            a = out[r + 1, x]          # left
            b = out[r, x + 1]          # up
            c = out[r, x]              # up-left
            f = filters[r][:, None]
            pa, pb, pc = np.abs(b - c), np.abs(a - c), np.abs(a + b - 2 * c)
            paeth = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, c))
            pred = np.select([f == 1, f == 2, f == 3, f == 4], [a, b, (a + b) // 2, paeth], 0)
            out[r + 1, x + 1] = (coded[r, x] + pred) & 0xFF
    byte = out[1:, 1:].astype(np.uint16)
    return (byte[..., 0::2] << 8) | byte[..., 1::2]


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
