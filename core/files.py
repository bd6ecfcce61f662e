"""Text, TOML and JSON files, and mask images: readers whose every failure is one line.

Each reader stops with a :class:`~thinfilm.core.errors.UserError` that names the file: missing,
a folder, not a regular file (a named pipe, a device, a socket: refused unread, so no read
blocks), a name or path too long, unreadable, larger than its limit (:data:`MAX_TEXT_BYTES` for
text), not UTF-8, not valid TOML or JSON (with the line; nested too deeply), and, for
:func:`read_json` with ``finite``, a NaN or infinite number (with the field). Every reader of a
user's file goes through :func:`open_regular`. A leading UTF-8 byte-order mark is dropped.
:func:`write_json` writes sorted keys and a trailing newline, byte-for-byte reproducible.
"""

from __future__ import annotations

import errno
import json
import math
import os
import stat
from pathlib import Path

import numpy as np

from .errors import UserError

__all__ = ["read_text_file", "read_bytes_file", "open_regular", "path_error", "show_path", "read_toml",
           "parse_toml_text", "parse_json_text", "special_file_kind", "check_regular_file", "read_json", "write_json", "MAX_TEXT_BYTES"]


#: the largest text file (a scene spec, a CSV table, a JSON file) a reader takes, in bytes
MAX_TEXT_BYTES = 64 * 2**20

_KINDS = {stat.S_IFIFO: "a named pipe", stat.S_IFCHR: "a character device", stat.S_IFBLK: "a block device",
          stat.S_IFSOCK: "a socket"}


def show_path(path, limit: int = 120) -> str:
    """``path`` as messages show it: whole when short, else its start and end around ``…``."""
    text = str(path)
    return text if len(text) <= limit else f"{text[:50]}…{text[-(limit - 51):]}"


def path_error(path, what: str, e: OSError) -> UserError:
    """The one-line :class:`UserError` for an ``OSError`` met on the user's ``path``: not
    found, a folder, a name or path too long (``ENAMETOOLONG``), or the system's reason."""
    shown = show_path(path)
    if isinstance(e, FileNotFoundError):
        return UserError(f"{shown}: {what} not found")
    if isinstance(e, IsADirectoryError):
        return UserError(f"{shown}: is a folder, expected a {what}")
    if e.errno == errno.ENAMETOOLONG:
        if len(os.fsencode(str(path))) >= 4096:
            return UserError(f"{shown}: path too long ({len(os.fsencode(str(path)))} bytes; the system takes "
                             f"at most 4095)")
        return UserError(f"{shown}: file name too long (the system takes at most 255 bytes for each name "
                         f"between slashes)")
    return UserError(f"{shown}: cannot read the {what} ({e.strerror or e})")


def special_file_kind(mode) -> str | None:
    """What a file of ``st_mode`` is when it is neither a regular file nor a folder ("a named
    pipe", "a character device" …), else None."""
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    return _KINDS.get(stat.S_IFMT(mode), "not a file")


def _refuse_special(path, mode, what):
    if stat.S_ISDIR(mode):
        raise UserError(f"{show_path(path)}: is a folder, expected a {what}")
    if not stat.S_ISREG(mode):
        kind = _KINDS.get(stat.S_IFMT(mode), "not a file")
        raise UserError(f"{show_path(path)}: not a regular file ({kind}), expected a {what}")


def open_regular(path, what: str = "file", max_bytes: int | None = None):
    """Open a user's file for reading (binary). Anything but a regular file (a folder, a named
    pipe, a device, a socket) is refused without being read, so that no read blocks or runs
    forever; ``max_bytes``: a larger file is refused before any byte is read. Every refusal is
    a one-line :class:`UserError` naming the file (``what``: what it should be)."""
    path = Path(path)
    try:
        _refuse_special(path, os.stat(path).st_mode, what)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise path_error(path, what, e) from None
    try:
        st = os.fstat(fd)
        _refuse_special(path, st.st_mode, what)  # replaced between the two looks
        if max_bytes is not None and st.st_size > max_bytes:
            raise UserError(f"{show_path(path)}: the {what} is {st.st_size} bytes, at most {max_bytes} are read")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_regular_file(path, what: str = "file") -> None:
    """Refuse, in one line naming it, a ``path`` that is missing or not a regular file (as
    :func:`open_regular`, which it opens and closes)."""
    open_regular(path, what).close()


def read_bytes_file(path, what: str = "file", max_bytes: int | None = None, max_lines: int | None = None) -> bytes:
    """The bytes of a regular file (:func:`open_regular`), with ``max_bytes`` checked on its
    size first and on what is read, and ``max_lines`` counted while reading: a file over
    either limit is refused before it is parsed."""
    path = Path(path)
    with open_regular(path, what, max_bytes) as f:
        chunks, size, lines = [], 0, 0
        try:
            while True:
                block = f.read(1 << 20)
                if not block:
                    break
                size += len(block)
                if max_bytes is not None and size > max_bytes:
                    raise UserError(f"{show_path(path)}: the {what} is more than {max_bytes} bytes, "
                                    f"at most {max_bytes} are read")
                if max_lines is not None:
                    lines += block.count(b"\n")
                    if lines > max_lines:
                        raise UserError(f"{show_path(path)}: the {what} has more than {max_lines} lines, "
                                        f"at most {max_lines} are read")
                chunks.append(block)
        except OSError as e:
            raise path_error(path, what, e) from None
    return b"".join(chunks)


def read_text_file(path, what: str = "file", encoding: str = "utf-8", max_bytes: int | None = MAX_TEXT_BYTES,
                   max_lines: int | None = None) -> str:
    """The text of a regular file (:func:`read_bytes_file`; a leading UTF-8 byte-order mark is
    dropped); a missing, unreadable, special (pipe, device), oversized or non-UTF-8 file is a
    one-line :class:`UserError` naming it (``what`` says what the file should be)."""
    data = read_bytes_file(path, what, max_bytes, max_lines)
    try:
        text = data.decode(encoding)
    except UnicodeDecodeError:
        raise UserError(f"{show_path(path)}: the {what} is not a UTF-8 text file") from None
    return text[1:] if text.startswith("\ufeff") else text


def parse_toml_text(text: str, path) -> dict:
    """Parse the TOML text of file ``path``; invalid or too deeply nested TOML is a one-line
    :class:`UserError` naming the file."""
    import tomllib

    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{show_path(path)}: not valid TOML ({e})") from None
    except RecursionError:
        raise UserError(f"{show_path(path)}: not valid TOML (nested too deeply)") from None


def read_toml(path, what: str = "TOML file") -> dict:
    """A parsed TOML file; errors as :func:`read_text_file`, and invalid TOML, are one line."""
    return parse_toml_text(read_text_file(path, what), path)


def parse_json_text(text: str, path) -> object:
    """Parse the JSON text of file ``path``; malformed JSON is a one-line :class:`UserError`
    naming the file and line."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"{show_path(path)}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except RecursionError:
        raise UserError(f"{show_path(path)}: not valid JSON (nested too deeply)") from None


def read_json(path, missing=None, finite=False):
    """Parse a JSON file; a missing or malformed file is a one-line :class:`UserError`
    (``missing`` adds a hint to the not-found message). With ``finite``, a ``NaN`` or
    ``Infinity`` anywhere in it is refused too, naming the field."""
    path = Path(path)
    try:
        absent = stat.S_ISDIR(os.stat(path).st_mode)
    except (FileNotFoundError, NotADirectoryError):
        absent = True
    except OSError:  # a name too long, a loop of links: read_text_file names it
        absent = False
    if absent:
        raise UserError(f"{show_path(path)}: file not found" + (f" ({missing})" if missing else ""))
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
