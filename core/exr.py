"""EXR files: channel names, reading and writing, and OpenEXR's thread pool.

Every image of a dataset, estimate or evaluation folder is a single-part scanline EXR of
float32 channels, ZIP-compressed, all of one height and width, row 0 at the top
(``docs/design.md``, *Dataset folder*). Channel names: a polarizer angle's layer is
``pol000``, ``pol045`` … (whole degrees, three digits) with channels ``R``, ``G``, ``B``; a
spectral band is ``band000`` … in the order of ``wavelengths_nm``.

Errors
------
Each call reports its own failure as one :class:`ExrError` (a
:class:`~thinfilm.core.errors.UserError`) that names the file, with a ``reason``: the file
is not found, a folder, unreadable, not an EXR file, truncated, damaged, or lacks a channel
asked for; a write that the file system refuses (a missing or read-only folder, a full disk)
is an :class:`ExrWriteError`, which is an :class:`OSError` too.

Nothing here redirects the process's file descriptors, so reading and writing from several
threads at once is safe. The OpenEXR binding (3.5 and later) raises ``RuntimeError`` or
``ValueError`` for files it cannot read, but its C library also prints its own message on
the process's standard error, and the binding one on ``sys.stdout``. So OpenEXR reads and
writes only memory here: Python reads the file and checks its structure first
(:func:`check_exr_bytes`: the header, the chunk table, every chunk's place and size, and
for ZIP the compressed data itself), so that a file cut off, not an EXR or damaged in the
places the check sees is refused before OpenEXR sees it; and OpenEXR encodes into memory
that Python writes, so the system's own error (``errno``) reports a failed write.

Examples
--------
>>> pol_layer(45), pol_layer(135.0), band_channel(7)
('pol045', 'pol135', 'band007')
>>> sorted(polarized_rgb_channels({0: np.zeros((1, 1, 3))}))
['pol000.B', 'pol000.G', 'pol000.R']
"""

from __future__ import annotations

import io
import struct
import threading
import zlib
from pathlib import Path

import numpy as np

from .errors import UserError
from .threads import thread_budget

__all__ = ["pol_layer", "band_channel", "polarized_rgb_channels", "band_channels", "read_exr", "write_exr",
           "check_exr_bytes", "set_exr_threads", "MAX_EXR_THREADS", "ExrError", "ExrWriteError",
           "EXR_ERROR_REASONS"]


def pol_layer(angle_deg: float) -> str:
    """Layer name of a polarizer angle: ``pol000``, ``pol045`` …"""
    return f"pol{int(round(angle_deg)) % 360:03d}"


def band_channel(index: int) -> str:
    """Channel name of spectral band ``index``: ``band000`` …"""
    return f"band{index:03d}"


def polarized_rgb_channels(polarized_rgb: dict) -> dict:
    """EXR channels of polarizer images ``{angle: (H, W, 3)}``: ``pol000.R``, ``pol000.G``, …"""
    return {f"{pol_layer(angle)}.{name}": img[..., c]
            for angle, img in polarized_rgb.items() for c, name in enumerate("RGB")}


def band_channels(cube, prefix: str = "") -> dict:
    """EXR channels of a spectral cube (H, W, B): ``{prefix}band000``, …"""
    return {f"{prefix}{band_channel(b)}": cube[..., b] for b in range(cube.shape[-1])}


# -- OpenEXR's thread pool ---------------------------------------------------------------------

#: the most threads OpenEXR's pool gets from the thread budget
MAX_EXR_THREADS = 8

_pool_lock = threading.Lock()
_pool_threads: int | None = None     # the size given to OpenEXR's pool, None before the first call
_pool_choice: int | None = None      # set_exr_threads's value; None: follow the thread budget


def set_exr_threads(threads: int | None) -> None:
    """Size OpenEXR's thread pool, which compresses and decompresses the ZIP blocks of EXR
    files in parallel (the bytes written are the same for any number of threads); 1 or less:
    no pool. None: follow the process's thread budget again
    (:func:`thinfilm.core.threads.thread_budget`, at most :data:`MAX_EXR_THREADS`), which is
    what the pool does until this is called: each read and write sizes it to the budget of the
    moment, so :func:`thinfilm.core.threads.set_thread_budget` reaches it too."""
    global _pool_choice
    with _pool_lock:
        _pool_choice = None if threads is None else int(threads)
    _openexr()


def _openexr():
    """The OpenEXR module, its thread pool sized to :func:`set_exr_threads`'s choice or the
    thread budget."""
    import OpenEXR

    global _pool_threads
    want = _pool_choice if _pool_choice is not None else min(thread_budget(), MAX_EXR_THREADS)
    want = want if want > 1 else 0
    if want != _pool_threads:
        with _pool_lock:
            if want != _pool_threads:
                OpenEXR.set_global_thread_count(want)
                _pool_threads = want
    return OpenEXR


# -- errors ------------------------------------------------------------------------------------

class ExrError(UserError):
    """An EXR file that cannot be read or written, in one line that names it.

    Attributes
    ----------
    path : str
        The file.
    reason : str
        What is wrong, one of :data:`EXR_ERROR_REASONS`.
    """

    def __init__(self, path, reason: str, message: str):
        super().__init__(f"{path}: {message}")
        self.path = str(path)
        self.reason = reason
        self.detail = message

    def __reduce__(self):  # the same error after pickling (Dask workers)
        return (type(self), (self.path, self.reason, self.detail))


#: the kinds of :class:`ExrError`
EXR_ERROR_REASONS = ("not-found", "folder", "unreadable", "not-exr", "truncated", "damaged", "missing-channel",
                     "unwritable")


class ExrWriteError(ExrError, OSError):
    """A file system that refuses an EXR file (a missing or read-only folder, a full disk): an
    :class:`ExrError` (reason ``unwritable``) and an :class:`OSError` with the ``errno``,
    ``strerror`` and ``filename`` of the failure, so that output folders
    (:mod:`thinfilm.core.outputs`) report it as their own."""

    def __init__(self, path, error: OSError):
        reason = error.strerror or str(error)
        ExrError.__init__(self, path, "unwritable", f"cannot write the EXR file ({reason})")
        self.errno, self.strerror, self.filename = error.errno, reason, str(path)

    def __str__(self):
        return self.args[0]

    def __reduce__(self):
        return (type(self), (self.path, OSError(self.errno, self.strerror)))


# -- the layout of a file ------------------------------------------------------------------------

_MAGIC = b"\x76\x2f\x31\x01"
_TILED, _LONG_NAMES, _DEEP, _MULTIPART = 0x200, 0x400, 0x800, 0x1000
#: scanlines per chunk of each compression (OpenEXR's numbering)
_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256, 10: 256, 11: 32}
_NO_COMPRESSION, _ZIPS, _ZIP = 0, 2, 3
_BYTES_PER_SAMPLE = {0: 4, 1: 2, 2: 4}   # UINT, HALF, FLOAT


class _Damaged(Exception):
    """What :func:`check_exr_bytes` found: ``reason`` (``truncated``, ``damaged``, ``not-exr``)
    and the detail."""

    def __init__(self, reason, detail):
        super().__init__(detail)
        self.reason = reason


def _text(raw: bytes, what: str) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        raise _Damaged("damaged", f"{what} is not UTF-8 text") from None


def _cstring(data, pos, limit, what):
    end = data.find(b"\0", pos, pos + limit + 1)
    if end < 0:
        if len(data) - pos <= limit:
            raise _Damaged("truncated", f"the header ends inside {what}")
        raise _Damaged("damaged", f"{what} is longer than {limit} characters")
    return _text(data[pos:end], what), end + 1


def _header(data, pos, long_names):
    """The attributes of one header from ``pos``: ``{name: (type, value bytes)}``, and the
    position after it."""
    limit = 255 if long_names else 31
    attrs = {}
    while True:
        if pos >= len(data):
            raise _Damaged("truncated", "the header is cut off")
        if data[pos] == 0:
            return attrs, pos + 1
        name, pos = _cstring(data, pos, limit, "an attribute name")
        kind, pos = _cstring(data, pos, limit, f"the type of attribute '{name}'")
        if pos + 4 > len(data):
            raise _Damaged("truncated", "the header is cut off")
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        if size < 0:
            raise _Damaged("damaged", f"attribute '{name}' has a negative size")
        if pos + size > len(data):
            raise _Damaged("truncated", "the header is cut off")
        value = data[pos:pos + size]
        if kind == "string":
            _text(value, f"attribute '{name}'")
        attrs[name] = (kind, value)
        pos += size


#: the attributes every header has, and their types and sizes (None: any size)
_REQUIRED = {"channels": ("chlist", None), "compression": ("compression", 1), "dataWindow": ("box2i", 16),
             "displayWindow": ("box2i", 16), "lineOrder": ("lineOrder", 1), "pixelAspectRatio": ("float", 4),
             "screenWindowCenter": ("v2f", 8), "screenWindowWidth": ("float", 4)}


def _check_required(attrs) -> None:
    for name, (kind, size) in _REQUIRED.items():
        if name not in attrs:
            raise _Damaged("damaged", f"the header has no '{name}'")
        got, value = attrs[name]
        if got != kind or (size is not None and len(value) != size):
            raise _Damaged("damaged", f"the header's '{name}' is malformed")
    if attrs["lineOrder"][1][0] > 2:
        raise _Damaged("damaged", "the header's 'lineOrder' is malformed")


def _channel_list(value):
    """``[(name, pixel type, x sampling, y sampling)]`` of a ``chlist`` attribute."""
    out, pos = [], 0
    while pos < len(value) and value[pos] != 0:
        end = value.find(b"\0", pos)
        if end < 0 or end + 17 > len(value):
            raise _Damaged("damaged", "the channel list is malformed")
        kind, xs, ys = struct.unpack_from("<i4xii", value, end + 1)
        name = _text(value[pos:end], "a channel name")
        if kind not in _BYTES_PER_SAMPLE or xs < 1 or ys < 1:
            raise _Damaged("damaged", f"channel '{name}' has an unknown pixel type or sampling")
        out.append((name, kind, xs, ys))
        pos = end + 17
    if pos != len(value) - 1:
        raise _Damaged("damaged", "the channel list is malformed")
    return out


def check_exr_bytes(data: bytes, path="EXR file") -> None:
    """Check the structure of an EXR file's bytes without decoding its pixels, so that
    OpenEXR is handed only files it can read.

    Every file: the magic number, the version and the header's attributes. A single-part
    scanline file (what :func:`write_exr` writes): its data window, channels and
    compression, its table of chunk offsets, and each chunk's place, first line and size
    inside the file; ZIP, ZIPS and uncompressed chunks are also decompressed (zlib checks
    them) and their sizes compared with the channels'.

    Raises
    ------
    ExrError
        ``path: not a readable EXR file (<reason>: <detail>)``, its ``reason`` one of
        ``not-exr``, ``truncated``, ``damaged``.

    Examples
    --------
    >>> try:
    ...     check_exr_bytes(b"hello", "a.exr")
    ... except ExrError as e:
    ...     print(e.reason, "|", e)
    not-exr | a.exr: not a readable EXR file (not-exr: it does not start with the EXR magic number)
    """
    try:
        _check_layout(bytes(data))
    except _Damaged as e:
        raise ExrError(path, e.reason, f"not a readable EXR file ({e.reason}: {e})") from None


def _check_layout(data: bytes) -> None:
    if data[:4] != _MAGIC:
        if len(data) < 4 and _MAGIC.startswith(data):
            raise _Damaged("truncated", "the file is empty" if not data else "the file is cut off")
        raise _Damaged("not-exr", "it does not start with the EXR magic number")
    if len(data) < 8:
        raise _Damaged("truncated", "the file is cut off")
    (version,) = struct.unpack_from("<I", data, 4)
    if version & 0xFF != 2 or version & ~(0xFF | _TILED | _LONG_NAMES | _DEEP | _MULTIPART):
        raise _Damaged("damaged", f"unknown EXR version or flags {version:#x}")
    if version & _MULTIPART:
        pos = 8
        while True:
            if pos >= len(data):
                raise _Damaged("truncated", "the header is cut off")
            if data[pos] == 0:
                return  # the parts' offsets and chunks are left to OpenEXR
            attrs, pos = _header(data, pos, version & _LONG_NAMES)
            _check_required(attrs)
            for name in ("name", "type", "chunkCount"):
                if name not in attrs:
                    raise _Damaged("damaged", f"a part's header has no '{name}'")
    attrs, pos = _header(data, 8, version & _LONG_NAMES)
    _check_required(attrs)
    kind = attrs.get("type", ("string", b"tiledimage" if version & _TILED else b"scanlineimage"))[1]
    if version & _TILED and "tiles" not in attrs:
        raise _Damaged("damaged", "the header of a tiled file has no 'tiles'")
    if not version & (_TILED | _DEEP) and kind != b"scanlineimage":
        raise _Damaged("damaged", f"the header's 'type' is {kind.decode()!r} in a scanline file")
    if version & (_TILED | _DEEP):
        return  # tiles and deep data are left to OpenEXR
    compression = attrs["compression"][1][0]
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"][1])
    lines = _LINES_PER_CHUNK.get(compression)
    if x1 < x0 or y1 < y0:
        raise _Damaged("damaged", "the header's 'dataWindow' is empty")
    if lines is None:
        return  # a compression this check does not know: OpenEXR decides
    chunks = (y1 - y0 + lines) // lines
    if "chunkCount" in attrs and attrs["chunkCount"][1] != struct.pack("<i", chunks):
        raise _Damaged("damaged", "the header's 'chunkCount' does not match its 'dataWindow'")
    table_end = pos + 8 * chunks
    if table_end > len(data):
        raise _Damaged("truncated", "the table of chunk offsets is cut off")
    offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
    channels = _channel_list(attrs["channels"][1])
    plain = all(xs == 1 and ys == 1 for _, _, xs, ys in channels)
    row_bytes = (x1 - x0 + 1) * sum(_BYTES_PER_SAMPLE.get(kind, 4) for _, kind, _, _ in channels)
    packed = []  # (start, size, expected, i) of the compressed chunks to check
    for i, offset in enumerate(offsets):
        if offset == 0 or offset + 8 > len(data):
            raise _Damaged("truncated", f"chunk {i} of {chunks} is missing")
        if offset < table_end:
            raise _Damaged("damaged", f"the offset of chunk {i} points into the header")
        y, size = struct.unpack_from("<ii", data, offset)
        if y != y0 + i * lines:
            raise _Damaged("damaged", f"chunk {i} starts at line {y}, expected {y0 + i * lines}")
        if size <= 0:
            raise _Damaged("damaged", f"chunk {i} has size {size}")
        if offset + 8 + size > len(data):
            raise _Damaged("truncated", f"chunk {i} of {chunks} is cut off")
        if plain and compression in (_NO_COMPRESSION, _ZIPS, _ZIP):
            expected = min(lines, y1 + 1 - y) * row_bytes
            if size == expected:
                continue  # stored as is (compression would not have made it smaller)
            if compression == _NO_COMPRESSION or size > expected:
                raise _Damaged("damaged", f"chunk {i} holds {size} bytes, expected {expected}")
            packed.append((offset + 8, size, expected, i))
    _check_compressed(data, packed)


def _check_compressed(data, packed) -> None:
    """Inflate the compressed chunks (their Adler-32 sums checked at the end of each stream),
    on the thread budget: zlib releases the interpreter lock while it inflates. Raises the
    first damaged chunk's error, in chunk order."""
    def check(chunk):
        try:
            _check_chunk(data, *chunk)
        except _Damaged as e:
            return e
        return None

    workers = min(thread_budget(), len(packed))
    if workers <= 1:
        errors = [check(c) for c in packed]
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(workers) as pool:
            errors = list(pool.map(check, packed))
    for e in errors:
        if e is not None:
            raise e


def _check_chunk(data, start, size, expected, i):
    stream = zlib.decompressobj()
    try:
        # at most one byte more than expected; the end of the stream checks its Adler-32 sum
        unpacked = stream.decompress(memoryview(data)[start:start + size], expected + 1)
    except zlib.error:
        raise _Damaged("damaged", f"chunk {i} does not decompress") from None
    if len(unpacked) != expected or not stream.eof or stream.unused_data:
        raise _Damaged("damaged", f"chunk {i} does not decompress to the {expected} bytes of its lines")


# -- reading and writing -------------------------------------------------------------------------

def read_exr(path, channels=None) -> dict:
    """Read the channels of an EXR file as float32 H×W arrays.

    Parameters
    ----------
    path : path-like
    channels : iterable of str, optional
        The channels wanted (each must be in the file); None: every channel.

    Raises
    ------
    ExrError
        One line naming the file, its ``reason`` one of: ``not-found``, ``folder``,
        ``unreadable`` (the system's reason), ``not-exr``, ``truncated``, ``damaged``
        (:func:`check_exr_bytes`, or OpenEXR's own refusal), ``missing-channel``.

    The file is checked (:func:`check_exr_bytes`) before OpenEXR reads it, so a file cut
    off or not an EXR at all never reaches OpenEXR, which would print about it on the
    process's standard error. Safe to call from several threads at once.
    """
    import os
    import stat

    from .files import open_regular, special_file_kind

    path = Path(path)
    try:
        kind = special_file_kind(os.stat(path).st_mode)
        if kind is not None:  # a named pipe, a device: never opened, a read could block or never end
            raise ExrError(path, "unreadable", f"not a regular file ({kind}), expected an EXR file")
        if stat.S_ISDIR(os.stat(path).st_mode):
            raise IsADirectoryError(path)
        with open_regular(path, "EXR file") as f:
            data = f.read()
    except FileNotFoundError:
        raise ExrError(path, "not-found", "file not found") from None
    except IsADirectoryError:
        raise ExrError(path, "folder", "is a folder, expected an EXR file") from None
    except OSError as e:
        raise ExrError(path, "unreadable", f"cannot read the EXR file ({e.strerror or e})") from None
    check_exr_bytes(data, path)
    OpenEXR = _openexr()
    try:
        with OpenEXR.File(io.BytesIO(data), separate_channels=True) as f:
            found = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
    except Exception as e:  # the binding raises RuntimeError or ValueError for files it refuses
        detail = " ".join((str(e) or type(e).__name__).split())[:200]
        raise ExrError(path, "damaged", f"not a readable EXR file (damaged: OpenEXR: {detail})") from None
    names = list(found) if channels is None else list(channels)
    out = {}
    for name in names:
        if name not in found:
            raise ExrError(path, "missing-channel", f"missing channel '{name}'")
        v = found[name]
        if v.ndim != 2 or v.dtype.kind not in "fui":
            raise ExrError(path, "damaged", f"channel '{name}' is not an image of numbers")
        out[name] = v.astype(np.float32, copy=False)
    return out


def write_exr(path, channels: dict) -> None:
    """Write 2-D float32 channels (name → H×W array) to an EXR file (ZIP, deterministic:
    the same arrays give the same bytes, with any number of threads).

    OpenEXR encodes the file in memory and Python writes it, so a failure of the file system
    is an :class:`ExrWriteError` (an :class:`OSError` with its ``errno``) naming the file.
    Safe to call from several threads at once. Channels that are not 2-D arrays of one shape
    are a ``ValueError`` (a caller's bug).
    """
    OpenEXR = _openexr()

    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: channels must be 2-D arrays of one shape, got {shapes}")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in sorted(channels.items())}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    encoded = io.BytesIO()
    with OpenEXR.File(header, data) as f:
        f.write(encoded)
    try:
        with open(path, "wb") as out:
            out.write(encoded.getbuffer())
    except OSError as e:
        raise ExrWriteError(path, e) from None
