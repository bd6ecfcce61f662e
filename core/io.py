"""Dataset and estimate folders: the one place that reads and writes them.

Dataset format ``thinfilm-dataset/1`` (``DESIGN.md``): ``scene.toml``, ``meta.json``,
``ground_truth.exr``, ``polarized_rgb.exr``, ``spectral_s.exr``, ``stokes_spectral.exr``,
``preview.png``, and the optional ``valid.exr`` (channel ``valid``: 1 where the captures can be
trusted, 0 where they cannot, e.g. saturated pixels of an imported capture; absent means every
pixel). Every image is float32, all of one height and width, row 0 at the top.
Estimate folders: ``estimate.exr``, ``estimate.json`` and an optional ``surface.ply``.

Readers stop with a :class:`~thinfilm.core.errors.UserError` that names the file and the
channel when a channel is missing, shapes disagree, captures hold NaN, or the ``format`` is
unknown. Writers (:func:`write_dataset`, :func:`write_estimate`) write into a folder that
exists (see :mod:`thinfilm.core.outputs` for safe output folders); files are deterministic
(same arrays, same bytes).

Examples
--------
>>> pol_layer(45), pol_layer(135.0), band_channel(7)
('pol045', 'pol135', 'band007')
>>> sorted(polarized_rgb_channels({0: np.zeros((1, 1, 3))}))
['pol000.B', 'pol000.G', 'pol000.R']
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = [
    "FORMAT",
    "GROUND_TRUTH_CHANNELS",
    "ESTIMATE_CHANNELS",
    "Dataset",
    "Estimate",
    "read_exr",
    "write_exr",
    "set_exr_threads",
    "read_dataset",
    "write_dataset",
    "dataset_meta",
    "software_versions",
    "read_estimate",
    "write_estimate",
    "write_evaluation_files",
    "read_metrics",
    "height_to_mesh",
    "read_json",
    "parse_json_text",
    "read_text_file",
    "read_toml",
    "read_mask_file",
    "write_json",
    "pol_layer",
    "band_channel",
    "polarized_rgb_channels",
    "band_channels",
]

FORMAT = "thinfilm-dataset/1"
GROUND_TRUTH_CHANNELS = ("normal.X", "normal.Y", "normal.Z", "zenith", "azimuth",
                         "thickness", "depth", "mask")


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


def set_exr_threads(threads: int) -> None:
    """Size OpenEXR's thread pool, which compresses and decompresses the ZIP blocks of EXR
    files in parallel (the bytes written are the same for any number of threads); 1 or less:
    no pool (:func:`thinfilm.core.threads.set_thread_budget` calls this)."""
    import OpenEXR

    global _EXR_THREADS_SET
    _EXR_THREADS_SET = True
    OpenEXR.set_global_thread_count(int(threads) if threads > 1 else 0)


def _openexr():
    """The OpenEXR module; unless :func:`set_exr_threads` was called, its thread pool sized
    once to the process's thread budget (:mod:`.threads`; at most 8)."""
    import OpenEXR

    if not _EXR_THREADS_SET:
        from .threads import thread_budget

        set_exr_threads(min(thread_budget(), 8))
    return OpenEXR


_EXR_THREADS_SET = False


def write_exr(path, channels: dict) -> None:
    """Write 2-D float32 channels (name → H×W array) to an EXR file (ZIP, deterministic)."""
    OpenEXR = _openexr()

    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: channels must be 2-D arrays of one shape, got {shapes}")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in sorted(channels.items())}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with _c_output() as printed:
        try:
            with OpenEXR.File(header, data) as f:
                f.write(str(path))
        except OSError:
            raise
        except Exception as e:  # OpenEXR reports a full disk as a RuntimeError
            text = f"{e} {printed()}"
            code = next((c for c, words in _ERRNO_WORDS.items() if words in text), None)
            if code is None:
                raise
            raise OSError(code, os.strerror(code), str(path)) from None


_ERRNO_WORDS = {errno.ENOSPC: "No space left on device", errno.EDQUOT: "Disk quota exceeded",
                errno.EROFS: "Read-only file system", errno.EACCES: "Permission denied",
                errno.EFBIG: "File too large"}


@contextlib.contextmanager
def _c_output():
    """Catch what C libraries print on file descriptors 1 and 2 meanwhile (OpenEXR prints
    its own messages about damaged files): yields a function that returns the text.
    Python's own ``sys.stdout`` and ``sys.stderr`` are flushed first and keep working."""
    import tempfile

    captured = {"text": ""}
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = (os.dup(1), os.dup(2))
    except (OSError, ValueError, AttributeError):
        yield lambda: captured["text"]
        return
    import io

    sink = tempfile.TemporaryFile()
    py_sink = io.StringIO()  # what the bindings print through Python's sys.stdout
    try:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)

        def text():
            _flush_c_stdio()
            sink.seek(0)
            return " ".join((sink.read().decode("utf-8", "replace") + py_sink.getvalue()).split())

        with contextlib.redirect_stdout(py_sink), contextlib.redirect_stderr(py_sink):
            yield text
    finally:
        _flush_c_stdio()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        sink.close()


def _flush_c_stdio() -> None:
    try:
        import ctypes

        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def read_exr(path) -> dict:
    """Read every channel of an EXR file as float32 H×W arrays. A missing, damaged or
    truncated file is one :class:`UserError` naming it (OpenEXR's own messages on the
    terminal are caught and left out)."""
    OpenEXR = _openexr()

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    with _c_output() as printed:
        try:
            with OpenEXR.File(str(path), separate_channels=True) as f:
                channels = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
        except Exception as e:  # OpenEXR raises plain exceptions for damaged files
            detail = printed() or str(e)
            if "EXR_ERR_BAD_CHUNK_LEADER" in detail or "corrupt" in detail or "scanline" in detail:
                reason = "damaged or truncated"
            else:
                reason = (str(e) or type(e).__name__).splitlines()[0]
            raise UserError(f"{path}: not a readable EXR file ({reason})") from None
    out = {}
    for k, v in channels.items():
        if v.ndim != 2 or v.dtype.kind not in "fui":
            raise UserError(f"{path}: channel '{k}' is not an image of numbers")
        out[k] = v.astype(np.float32, copy=False)
    return out


def _require(channels: dict, names, path, shape=None):
    out = {}
    for name in names:
        if name not in channels:
            raise UserError(f"{path}: missing channel '{name}'")
        arr = channels[name]
        if shape is not None and arr.shape != shape:
            raise UserError(f"{path}: channel '{name}' has shape {arr.shape}, expected {shape}")
        out[name] = arr
    return out


def _no_nan(arr, path, names):
    """``arr`` (..., C) holds channels ``names`` (C); name the first one with NaN or inf."""
    finite = np.isfinite(arr).reshape(-1, arr.shape[-1]).all(axis=0)
    if not finite.all():
        bad = names[int(np.argmin(finite))]
        raise UserError(f"{path}: channel '{bad}' contains NaN or infinite values")


def _check_meta(meta, meta_path):
    if not isinstance(meta, dict):
        raise UserError(f"{meta_path}: expected a JSON object, got {type(meta).__name__}")
    for key in ("wavelengths_nm", "polarizer_angles_deg"):
        if key not in meta:
            continue
        values = meta[key]
        if not isinstance(values, list) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in values):
            raise UserError(f"{meta_path}: '{key}' must be a list of numbers, got {values!r}"[:300])
    wl = meta.get("wavelengths_nm", [])
    if len(wl) > 1 and np.any(np.diff(wl) <= 0):
        raise UserError(f"{meta_path}: 'wavelengths_nm' must be increasing")
    if any(v <= 0 for v in wl):
        raise UserError(f"{meta_path}: 'wavelengths_nm' must be wavelengths in nm > 0")
    angles = meta.get("polarizer_angles_deg", [])
    if any(v != round(v) or not 0 <= v < 360 for v in angles):
        raise UserError(f"{meta_path}: 'polarizer_angles_deg' must be whole degrees from 0 to 359 "
                        f"(layer names pol000 … pol359), got {angles!r}"[:300])
    if len(set(angles)) != len(angles):
        raise UserError(f"{meta_path}: 'polarizer_angles_deg' holds an angle twice, got {angles!r}"[:300])


@dataclass
class Dataset:
    """A dataset folder in memory. Images are float32, row 0 at the top.

    Attributes
    ----------
    ground_truth : dict
        ``normal`` (H, W, 3), ``zenith``, ``azimuth`` (deg), ``thickness`` (nm), ``depth``,
        ``mask`` (bool), each H×W. Empty for a user capture without ground truth.
    polarized_rgb : dict
        polarizer angle in degrees (int) → (H, W, 3) camera RGB; empty if absent.
    spectral_s : ndarray or None
        (H, W, B) s-polarized reflectance per band.
    stokes : dict
        ``"S0"``, ``"S1"``, ``"S2"`` → (H, W, B); empty if absent.
    valid : ndarray or None
        (H, W) bool, the pixels whose captures can be trusted (``valid.exr``); None when the
        folder has no ``valid.exr`` (every pixel). Methods reconstruct only valid pixels.
    """

    path: Path
    meta: dict
    ground_truth: dict = field(default_factory=dict)
    polarized_rgb: dict = field(default_factory=dict)
    spectral_s: np.ndarray | None = None
    stokes: dict = field(default_factory=dict)
    valid: np.ndarray | None = None

    @property
    def wavelengths_nm(self) -> np.ndarray:
        return np.asarray(self.meta.get("wavelengths_nm", []), dtype=np.float64)

    @property
    def polarizer_angles_deg(self) -> list:
        return sorted(self.polarized_rgb)

    @property
    def mask(self) -> np.ndarray | None:
        return self.ground_truth.get("mask")

    def has(self, part: str) -> bool:
        """Whether the part (``ground_truth``, ``polarized_rgb``, ``spectral_s``, ``stokes``) was read."""
        value = {"ground_truth": self.ground_truth, "polarized_rgb": self.polarized_rgb,
                 "spectral_s": self.spectral_s, "stokes": self.stokes}[part]
        return value is not None and (not isinstance(value, dict) or bool(value))

    @property
    def pixel_size(self) -> float | None:
        """Scene units per pixel (``meta.json`` ``projection.pixel_size``), None when absent."""
        proj = self.meta.get("projection")
        if not isinstance(proj, dict) or proj.get("pixel_size") is None:
            return None
        value = proj["pixel_size"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (np.isfinite(value) and value > 0):
            raise UserError(f"{self.path / 'meta.json'}: 'projection.pixel_size' must be a positive number, "
                            f"got {value!r}")
        return float(value)

    def film(self):
        """The film of ``meta.json`` (:meth:`thinfilm.core.film.Film.from_meta`)."""
        from .film import Film

        return Film.from_meta(self.meta, str(self.path / "meta.json"))

    @property
    def shape(self) -> tuple:
        for img in (self.spectral_s, *self.polarized_rgb.values(), self.stokes.get("S0"), self.ground_truth.get("mask"),
                    self.valid):
            if img is not None:
                return tuple(img.shape[:2])
        raise UserError(f"{self.path}: dataset holds no image")


def read_dataset(path, need=("polarized_rgb",), optional=None) -> Dataset:
    """Read and validate a dataset folder.

    Parameters
    ----------
    path : path-like
        The folder.
    need : iterable of str
        Parts that must be present: any of ``"ground_truth"``, ``"polarized_rgb"``,
        ``"spectral_s"``, ``"stokes"``.
    optional : iterable of str or None
        Parts read (and validated) only when present. ``None``: every part not in ``need``.
        Parts in neither are not read at all.

    The optional ``valid.exr`` is read whenever it is present (:attr:`Dataset.valid`).

    Raises
    ------
    UserError
        One sentence naming the file and channel: missing folder, file or channel, unknown
        ``format``, shape mismatch, NaN in a capture.
    """
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"{root}: dataset folder not found")
    meta_path = root / "meta.json"
    meta = read_json(meta_path, missing="not a thinfilm dataset folder", finite=True)
    _check_meta(meta, meta_path)
    if meta.get("format") != FORMAT:
        raise UserError(f"{meta_path}: unknown format {meta.get('format')!r}, expected '{FORMAT}'")
    need = set(need)
    parts = {"ground_truth", "polarized_rgb", "spectral_s", "stokes"}
    unknown = need - parts
    if unknown:
        raise ValueError(f"read_dataset: unknown parts {sorted(unknown)}")
    wanted = need | (parts - need if optional is None else set(optional))
    ds = Dataset(path=root, meta=meta)
    shape = None
    file_part = {"ground_truth.exr": "ground_truth", "polarized_rgb.exr": "polarized_rgb",
                 "spectral_s.exr": "spectral_s", "stokes_spectral.exr": "stokes"}

    def load(name, required):
        p = root / name
        if file_part[name] not in wanted:
            return None
        if not p.is_file():
            if required:
                raise UserError(f"{p}: file not found")
            return None
        return p, read_exr(p)

    got = load("ground_truth.exr", "ground_truth" in need)
    if got:
        p, ch = got
        shape = next(iter(ch.values())).shape
        gt = _require(ch, GROUND_TRUTH_CHANNELS, p, shape)
        _no_nan(np.stack([gt[k] for k in GROUND_TRUTH_CHANNELS], axis=-1), p, list(GROUND_TRUTH_CHANNELS))
        ds.ground_truth = {
            "normal": np.stack([gt["normal.X"], gt["normal.Y"], gt["normal.Z"]], axis=-1),
            "zenith": gt["zenith"], "azimuth": gt["azimuth"], "thickness": gt["thickness"],
            "depth": gt["depth"], "mask": gt["mask"] > 0.5,
        }

    got = load("polarized_rgb.exr", "polarized_rgb" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        layers = sorted({k.split(".")[0] for k in ch if k.startswith("pol")})
        angles = meta.get("polarizer_angles_deg") or [int(layer[3:]) for layer in layers]
        for a in angles:
            layer = pol_layer(a)
            rgb = _require(ch, [f"{layer}.R", f"{layer}.G", f"{layer}.B"], p, shape)
            img = np.stack(list(rgb.values()), axis=-1)
            _no_nan(img, p, list(rgb))
            ds.polarized_rgb[int(round(a)) % 360] = img

    bands = meta.get("wavelengths_nm", [])
    got = load("spectral_s.exr", "spectral_s" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        names = [band_channel(i) for i in range(len(bands))]
        if not names:
            raise UserError(f"{meta_path}: 'wavelengths_nm' is empty but {p.name} is present")
        cube = np.stack(list(_require(ch, names, p, shape).values()), axis=-1)
        _no_nan(cube, p, names)
        ds.spectral_s = cube

    got = load("stokes_spectral.exr", "stokes" in need)
    if got:
        p, ch = got
        shape = shape or next(iter(ch.values())).shape
        for s in ("S0", "S1", "S2"):
            names = [f"{s}.{band_channel(i)}" for i in range(len(bands))]
            cube = np.stack(list(_require(ch, names, p, shape).values()), axis=-1)
            _no_nan(cube, p, names)
            ds.stokes[s] = cube

    p = root / "valid.exr"
    if p.is_file():
        ch = read_exr(p)
        if "valid" not in ch:
            raise UserError(f"{p}: missing channel 'valid'")
        arr = ch["valid"]
        if shape is not None and arr.shape != shape:
            raise UserError(f"{p}: channel 'valid' has shape {arr.shape}, expected {shape}")
        _no_nan(arr[..., None], p, ["valid"])
        ds.valid = arr > 0.5
    return ds


def read_text_file(path, what: str = "file", encoding: str = "utf-8") -> str:
    """The text of a file; a missing, unreadable or non-UTF-8 file is a one-line
    :class:`UserError` naming it (``what`` says what the file should be)."""
    path = Path(path)
    try:
        return path.read_text(encoding=encoding)
    except FileNotFoundError:
        raise UserError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder, expected a {what}") from None
    except UnicodeDecodeError:
        raise UserError(f"{path}: the {what} is not a UTF-8 text file") from None
    except OSError as e:
        raise UserError(f"{path}: cannot read the {what} ({e.strerror or e})") from None


def read_toml(path, what: str = "TOML file") -> dict:
    """A parsed TOML file; errors as :func:`read_text_file`, and invalid TOML, are one line."""
    import tomllib

    text = read_text_file(path, what)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{path}: not valid TOML ({e})") from None


def parse_json_text(text: str, path) -> object:
    """Parse the JSON text of file ``path``; malformed JSON is a one-line :class:`UserError`
    naming the file and line."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except RecursionError:
        raise UserError(f"{path}: not valid JSON (nested too deeply)") from None


def read_json(path, missing=None, finite=False):
    """Parse a JSON file; a missing or malformed file is a one-line :class:`UserError`
    (``missing`` adds a hint to the not-found message). With ``finite``, a ``NaN`` or
    ``Infinity`` anywhere in it is refused too, naming the field."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found" + (f" ({missing})" if missing else ""))
    data = parse_json_text(read_text_file(path, "JSON file"), path)
    if finite:
        bad = _non_finite(data)
        if bad is not None:
            raise UserError(f"{path}: '{bad}' is NaN or infinite; expected a number")
    return data


def _non_finite(data, where=""):
    """The key path of the first NaN or infinite number in parsed JSON, or None."""
    if isinstance(data, float) and not math.isfinite(data):
        return where or "(top level)"
    if isinstance(data, dict):
        items = data.items()
    elif isinstance(data, list):
        items = ((f"[{i}]", v) for i, v in enumerate(data))
    else:
        return None
    for key, value in items:
        sub = f"{where}{key}" if str(key).startswith("[") else (f"{where}.{key}" if where else str(key))
        found = _non_finite(value, sub)
        if found is not None:
            return found
    return None


def write_json(path, data) -> None:
    """JSON with sorted keys and a trailing newline (byte-for-byte reproducible)."""
    Path(path).write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")


def read_mask_file(path, shape):
    """Read a mask image (EXR, PNG, or ``.npy``; non-zero on the object) of the given shape."""
    p = Path(path)
    if not p.is_file():
        raise UserError(f"{p}: mask file not found")
    suffix = p.suffix.lower()
    try:
        if suffix == ".exr":
            ch = read_exr(p)
            name = "mask" if "mask" in ch else sorted(ch)[0]
            m = ch[name]
        elif suffix == ".npy":
            m = np.load(p)
        else:
            import matplotlib.image as mpimg

            m = mpimg.imread(str(p))
        m = np.asarray(m, dtype=np.float64)
    except UserError:
        raise
    except Exception as e:
        reason = (str(e) or type(e).__name__).splitlines()[0]
        raise UserError(f"{p}: cannot read the mask image ({reason})") from None
    if not np.all(np.isfinite(m)):
        raise UserError(f"{p}: mask image holds NaN or infinite values")
    if m.ndim == 3:
        m = m[..., :3].max(axis=-1) if m.shape[-1] >= 3 else m[..., 0]
    if m.shape != tuple(shape):
        raise UserError(f"{p}: mask has shape {m.shape}, expected the captures' {tuple(shape)}")
    return m > 0


# -- writing datasets -----------------------------------------------------------------------

def software_versions() -> dict:
    """Versions of the packages that shape a dataset's bytes (for ``meta.json``)."""
    from importlib import metadata

    import thinfilm

    out = {"thinfilm": thinfilm.__version__, "numpy": np.__version__}
    for dist in ("mitsuba", "drjit"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def dataset_meta(**fields) -> dict:
    """A ``meta.json`` dictionary: ``format`` and ``versions`` filled in, then ``fields``."""
    meta = {"format": FORMAT, "versions": software_versions()}
    meta.update(fields)
    return meta


def write_dataset(folder, meta: dict, ground_truth: dict | None = None, polarized_rgb: dict | None = None,
                  spectral_s=None, stokes: dict | None = None, scene_toml: str | None = None,
                  preview: bool = True, valid=None) -> Path:
    """Write the files of a ``thinfilm-dataset/1`` folder into ``folder`` (which exists).

    Parameters
    ----------
    meta : dict
        ``meta.json`` (see :func:`dataset_meta`); must hold ``format``.
    ground_truth : dict, optional
        ``normal`` (H, W, 3), ``zenith``, ``azimuth``, ``thickness``, ``depth``, ``mask``.
    polarized_rgb : dict, optional
        angle (deg) → (H, W, 3) camera RGB.
    spectral_s : ndarray (H, W, B), optional
    stokes : dict, optional
        ``S0``, ``S1``, ``S2`` → (H, W, B).
    scene_toml : str, optional
        The resolved scene spec (``scene.toml``).
    preview : bool
        Write ``preview.png`` (needs ``polarized_rgb``; the normal map beside it when there is
        ground truth).
    valid : (H, W) bool, optional
        Pixels whose captures can be trusted (``valid.exr``); None: every pixel, no file.
    """
    folder = Path(folder)
    if meta.get("format") != FORMAT:
        raise ValueError(f"meta.json must have format {FORMAT!r}")
    if scene_toml is not None:
        (folder / "scene.toml").write_text(scene_toml, encoding="utf-8")
    write_json(folder / "meta.json", meta)
    if ground_truth:
        gt = ground_truth
        write_exr(folder / "ground_truth.exr", {
            "normal.X": gt["normal"][..., 0], "normal.Y": gt["normal"][..., 1],
            "normal.Z": gt["normal"][..., 2], "zenith": gt["zenith"], "azimuth": gt["azimuth"],
            "thickness": gt["thickness"], "depth": gt["depth"],
            "mask": np.asarray(gt["mask"]).astype(np.float32)})
    if polarized_rgb:
        write_exr(folder / "polarized_rgb.exr", polarized_rgb_channels(polarized_rgb))
    if spectral_s is not None:
        write_exr(folder / "spectral_s.exr", band_channels(np.asarray(spectral_s)))
    if stokes:
        write_exr(folder / "stokes_spectral.exr", {
            k: v for s in ("S0", "S1", "S2") for k, v in band_channels(np.asarray(stokes[s]), f"{s}.").items()})
    if valid is not None:
        write_exr(folder / "valid.exr", {"valid": np.asarray(valid).astype(np.float32)})
    if preview and polarized_rgb:
        _write_preview(folder / "preview.png", polarized_rgb, ground_truth)
    return folder


def _srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.rint(srgb * 255.0).astype(np.uint8)


def _write_preview(path: Path, polarized_rgb: dict, ground_truth: dict | None) -> None:
    """The camera's unpolarized RGB (auto-scaled, sRGB), and the normal map when known."""
    from PIL import Image

    from .conventions import stokes_from_polarizer_images

    s0 = stokes_from_polarizer_images(polarized_rgb)[0]
    mask = None if not ground_truth else np.asarray(ground_truth["mask"], dtype=bool)
    sel = mask if mask is not None and mask.any() else np.ones(s0.shape[:2], dtype=bool)
    level = np.percentile(s0[sel], 99) if sel.any() else 1.0
    panels = [_srgb8(s0 / (level if level > 0 else 1.0))]
    if mask is not None:
        normal = np.where(mask[..., None], 0.5 * (ground_truth["normal"] + 1.0), 0.0)
        panels += [np.zeros((s0.shape[0], 4, 3), dtype=np.uint8),
                   np.rint(np.clip(normal, 0, 1) * 255).astype(np.uint8)]
    Image.fromarray(np.concatenate(panels, axis=1)).save(path, format="PNG")


# -- estimates ----------------------------------------------------------------------------------

ESTIMATE_CHANNELS = ("normal.X", "normal.Y", "normal.Z", "zenith", "azimuth", "thickness", "valid")


@dataclass
class Estimate:
    """What an estimator returns, and what an estimate folder holds.

    Attributes
    ----------
    normals : (H, W, 3) unit normals in the camera frame.
    thickness_nm : (H, W) film thickness of the (top) layer in nm.
    valid : (H, W) bool, pixels with an estimate.
    film_ior : the film index used or estimated: a number or a material name (``estimate.json``).
    substrate_ior : the substrate index used (a number), or None.
    height : (H, W) height field in scene units (``pixel_size`` per pixel), or None.
    pixel_size : scene units per pixel of ``height``.
    info : more entries for ``estimate.json`` (``method``, ``timings_s``, diagnostics).
    """

    normals: np.ndarray
    thickness_nm: np.ndarray
    valid: np.ndarray
    film_ior: object = None
    substrate_ior: float | None = None
    height: np.ndarray | None = None
    pixel_size: float = 1.0
    info: dict = field(default_factory=dict)

    @property
    def zenith_azimuth_deg(self):
        from .conventions import normals_to_angles

        return normals_to_angles(self.normals)

    def json(self) -> dict:
        """The ``estimate.json`` content."""
        out = dict(self.info)
        out["film_ior"] = self.film_ior
        out["substrate_ior"] = self.substrate_ior
        out.setdefault("method", None)
        out.setdefault("timings_s", {})
        return out


def height_to_mesh(height, mask, pixel_size=1.0):
    """A trimesh surface from a height map on a mask (x right, y up, z towards the camera).

    Vertices sit at pixel centres; two triangles per 2×2 block of masked pixels.
    """
    import trimesh

    h, w = mask.shape
    idx = -np.ones((h, w), dtype=np.int64)
    ys, xs = np.nonzero(mask)
    idx[ys, xs] = np.arange(ys.size)
    verts = np.stack([(xs - (w - 1) / 2) * pixel_size, ((h - 1) / 2 - ys) * pixel_size,
                      height[ys, xs]], axis=-1)
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    faces = []
    for tri in ((a, c, b), (b, c, d)):  # counter-clockwise seen from +z (image y is down)
        t = np.stack([x.ravel() for x in tri], axis=-1)
        faces.append(t[np.all(t >= 0, axis=1)])
    return trimesh.Trimesh(vertices=verts, faces=np.concatenate(faces), process=False)


def write_estimate(folder, estimate: Estimate) -> Path:
    """Write the files of an estimate folder into ``folder`` (which exists):
    ``estimate.exr``, ``estimate.json`` and, with a height field, ``surface.ply``."""
    from .conventions import normals_to_angles

    folder = Path(folder)
    normals = np.asarray(estimate.normals, dtype=np.float64)
    valid = np.asarray(estimate.valid, dtype=bool)
    zenith, azimuth = normals_to_angles(normals)
    nan = np.float32(np.nan)
    channels = {
        "normal.X": np.where(valid, normals[..., 0], nan),
        "normal.Y": np.where(valid, normals[..., 1], nan),
        "normal.Z": np.where(valid, normals[..., 2], nan),
        "zenith": np.where(valid, zenith, nan),
        "azimuth": np.where(valid, azimuth, nan),
        "thickness": np.where(valid, estimate.thickness_nm, nan),
        "valid": valid.astype(np.float32),
    }
    write_exr(folder / "estimate.exr", channels)
    write_json(folder / "estimate.json", estimate.json())
    if estimate.height is not None and valid.sum() >= 4:
        height = np.nan_to_num(np.asarray(estimate.height, dtype=np.float64))
        height_to_mesh(height, valid, estimate.pixel_size).export(folder / "surface.ply")
    return folder


def read_estimate(path) -> Estimate:
    """Read an estimate folder. One-line errors name the file and the channel."""
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"{root}: estimate folder not found")
    exr = root / "estimate.exr"
    ch = read_exr(exr)
    shape = None
    for name in ESTIMATE_CHANNELS:
        if name not in ch:
            raise UserError(f"{exr}: missing channel '{name}'")
        if shape is None:
            shape = ch[name].shape
        elif ch[name].shape != shape:
            raise UserError(f"{exr}: channel '{name}' has shape {ch[name].shape}, expected {shape}")
    info = read_json(root / "estimate.json")
    if not isinstance(info, dict):
        raise UserError(f"{root / 'estimate.json'}: expected a JSON object")
    info = dict(info)
    normals = np.stack([ch["normal.X"], ch["normal.Y"], ch["normal.Z"]], axis=-1)
    return Estimate(normals=normals, thickness_nm=ch["thickness"], valid=ch["valid"] > 0.5,
                    film_ior=info.pop("film_ior", None), substrate_ior=info.pop("substrate_ior", None),
                    info=info)


# -- evaluation folders -------------------------------------------------------------------------

def write_evaluation_files(folder, metrics: dict, info: dict, rerendered_polarized_rgb: dict, rerendered_spectral_s,
                           error_maps: dict, mask) -> Path:
    """Write the files of an evaluation folder into ``folder`` (which exists): ``metrics.json``,
    ``evaluation.json``, ``rerendered.exr`` (the re-rendered captures: ``pol000.R`` …,
    ``spectral_s.band000`` …) and ``errors.exr`` (error maps, NaN stored as 0, and ``mask``)."""
    folder = Path(folder)
    write_json(folder / "metrics.json", metrics)
    write_json(folder / "evaluation.json", info)
    write_exr(folder / "rerendered.exr", {**polarized_rgb_channels(rerendered_polarized_rgb),
                                          **band_channels(np.asarray(rerendered_spectral_s), "spectral_s.")})
    write_exr(folder / "errors.exr", {**{k: np.nan_to_num(v, nan=0.0) for k, v in error_maps.items()},
                                      "mask": np.asarray(mask).astype(np.float32)})
    return folder


def read_metrics(folder) -> dict:
    """``metrics.json`` of an evaluation folder."""
    metrics = read_json(Path(folder) / "metrics.json", missing="not a thinfilm evaluation folder")
    if not isinstance(metrics, dict):
        raise UserError(f"{Path(folder) / 'metrics.json'}: expected a JSON object")
    return metrics
