"""Text, TOML and JSON files, and mask images: readers whose every failure is one line.

Each reader stops with a :class:`~thinfilm.core.errors.UserError` that names the file: missing,
a folder, unreadable, not UTF-8, not valid TOML or JSON (with the line), and, for
:func:`read_json` with ``finite``, a NaN or infinite number (with the field).
:func:`write_json` writes sorted keys and a trailing newline, byte-for-byte reproducible.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .errors import UserError
from .exr import read_exr

__all__ = ["read_text_file", "read_toml", "parse_json_text", "read_json", "write_json", "read_mask_file"]


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
