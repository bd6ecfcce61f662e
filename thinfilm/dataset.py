"""Dataset and estimate folders: EXR channel I/O, validation, atomic writes.

Format ``thinfilm-dataset/1`` (see ``DESIGN.md``): ``scene.toml``, ``meta.json``,
``ground_truth.exr``, ``polarized_rgb.exr``, ``spectral_s.exr``, ``stokes_spectral.exr``,
``preview.png``. Every image is float32, all of one height and width, row 0 at the top.

Readers stop with a :class:`~thinfilm.errors.UserError` that names the file and the
channel when a channel is missing, shapes disagree, captures hold NaN, or the
``format`` is unknown.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = [
    "FORMAT",
    "Dataset",
    "read_exr",
    "write_exr",
    "read_dataset",
    "atomic_output_dir",
    "check_output_dir",
    "read_json",
    "write_json",
    "pol_layer",
    "band_channel",
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


def write_exr(path, channels: dict) -> None:
    """Write 2-D float32 channels (name → H×W array) to an EXR file (ZIP, deterministic)."""
    import OpenEXR

    shapes = {np.shape(v) for v in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"{path}: channels must be 2-D arrays of one shape, got {shapes}")
    data = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in sorted(channels.items())}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, data) as f:
        f.write(str(path))


def read_exr(path) -> dict:
    """Read every channel of an EXR file as float32 H×W arrays."""
    import OpenEXR

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            return {k: np.asarray(v.pixels, dtype=np.float32) for k, v in f.channels().items()}
    except UserError:
        raise
    except Exception as e:  # OpenEXR raises plain exceptions for damaged files
        raise UserError(f"{path}: not a readable EXR file ({e})") from None


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
    """

    path: Path
    meta: dict
    ground_truth: dict = field(default_factory=dict)
    polarized_rgb: dict = field(default_factory=dict)
    spectral_s: np.ndarray | None = None
    stokes: dict = field(default_factory=dict)

    @property
    def wavelengths_nm(self) -> np.ndarray:
        return np.asarray(self.meta.get("wavelengths_nm", []), dtype=np.float64)

    @property
    def polarizer_angles_deg(self) -> list:
        return sorted(self.polarized_rgb)

    @property
    def mask(self) -> np.ndarray | None:
        return self.ground_truth.get("mask")

    @property
    def shape(self) -> tuple:
        for img in (self.spectral_s, *self.polarized_rgb.values(), self.ground_truth.get("mask")):
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
    meta = read_json(meta_path, missing="not a thinfilm dataset folder")
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
    return ds


#: Files that mark a folder as one of ours (dataset, estimate, evaluation, benchmark):
#: only such folders, or empty ones, are replaced by a new output.
OUTPUT_MARKERS = ("meta.json", "estimate.json", "metrics.json", "results.json")


def check_output_dir(out, markers=OUTPUT_MARKERS) -> Path:
    """Check that ``out`` can receive a new output folder, before any work is done.

    ``out`` may not exist yet, may be an empty folder, or may be an earlier output of ours
    (it holds one of ``markers``), which will be replaced. Anything else (a file, a folder of
    someone's files) is refused with a :class:`UserError`, so no user data is ever deleted.

    Returns the absolute path.
    """
    out = Path(out).expanduser().resolve()
    if out.parent == out:
        raise UserError(f"--out {out}: cannot write an output folder at the file-system root")
    if out.exists():
        if not out.is_dir():
            raise UserError(f"--out {out}: exists and is not a folder")
        if any(out.iterdir()) and not any((out / m).is_file() for m in markers):
            raise UserError(f"--out {out}: folder exists, is not empty and is not a thinfilm "
                            f"output; refusing to replace it")
    return out


@contextlib.contextmanager
def atomic_output_dir(out, markers=OUTPUT_MARKERS):
    """Yield a temporary folder beside ``out``; on success rename it to ``out``.

    On any error the temporary folder is removed, so no half-written output is left. An
    existing ``out`` is replaced only after the new one is complete, and only if it is empty
    or an earlier output of ours (:func:`check_output_dir`). File-system errors become a
    :class:`UserError` naming ``--out``.
    """
    out = check_output_dir(out, markers)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    except OSError as e:
        raise UserError(f"--out {out}: cannot create the folder ({e.strerror})") from None
    try:
        yield tmp
        check_output_dir(out, markers)  # still safe to replace after the work
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            out.rename(old)
        try:
            tmp.rename(out)
        except OSError:
            if old is not None:
                old.rename(out)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as e:
        shutil.rmtree(tmp, ignore_errors=True)
        raise UserError(f"--out {out}: cannot write the output ({e.strerror or e})") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def read_json(path, missing=None):
    """Parse a JSON file; a missing or malformed file is a one-line :class:`UserError`
    (``missing`` adds a hint to the not-found message)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found" + (f" ({missing})" if missing else ""))
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except UnicodeDecodeError:
        raise UserError(f"{path}: not a text file") from None


def write_json(path, data) -> None:
    """JSON with sorted keys and a trailing newline (byte-for-byte reproducible)."""
    Path(path).write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
