"""Output folders and files: never destroy anything, never leave anything half written.

The rule (``README.md``, *Outputs never destroy anything*)
----------------------------------------------------------
A command replaces an existing ``--out`` folder only if

1. this tool made it: it holds the marker file :data:`MARKER` (``.thinfilm-output``, a small
   JSON: ``format``, ``tool``, ``version``, ``command`` and ``entries``, the list of every
   file and folder the command wrote), written by the same command (``generate`` replaces
   a dataset, never an estimate or a benchmark);
2. it holds nothing else: every file and folder in it is one of the marker's ``entries``
   (a note, a ``.git/`` or a ``src/`` added by a person makes it theirs);
3. it is none of the command's inputs, lies inside none of them and contains none of them
   (``--out`` equal to the dataset, ``--out DATASET/sub``, ``--out ..`` of the dataset, the
   folder of the thickness bitmap a spec names). Paths are compared after resolving
   symbolic links.

Otherwise the command stops with one line (:class:`~thinfilm.core.errors.UserError`, exit
code 2) before any work, and nothing is touched. ``render`` writes files, not a folder: it
refuses to replace an existing file unless asked to (``--overwrite``), and never replaces
one of its inputs.

How an output is written
------------------------
:func:`atomic_output_dir` takes a lock, checks the rule, and yields a new temporary folder
beside ``--out`` (``.NAME.tmp-PID@HOST-XXXXXXXX``). The command does its work and writes its
files there. When the block ends without an error the marker is written, the folder gets
the permissions of the user's umask (not ``mkdtemp``'s 0700), the rule is checked once more,
and the folder is swapped into place in one step (``renameat2(RENAME_EXCHANGE)`` where the
file system has it; else two renames with SIGINT/SIGTERM held back in between); the old
output is then deleted. On any error, on Ctrl-C and on SIGTERM (:mod:`thinfilm.core.signals`
turns it into an exception) the temporary folder is removed, and so are the parent folders
the call created, so a failed command leaves the file system as it found it.

- **Lock.** ``.NAME.lock`` beside ``--out``, held with ``flock`` from before the work until
  the output is in place (and removed then). A second writer to the same ``--out`` stops at
  once with one line naming the first one's process id: two writers can never both
  succeed. A lock left by a killed process is released by the kernel and simply reused.
- **Stale temporaries.** A process killed with SIGKILL cannot clean up. The next output
  written into the same parent folder removes temporaries left there by processes that no
  longer exist: only names of this module's pattern, only of this host, only when the
  recorded process id is not running. (An old output that a killed process had moved aside
  while swapping is moved back if nothing took its place.)
- **Errors.** A full disk, a read-only or missing parent and similar file-system failures
  become one line naming ``--out``.

API for commands
----------------
``check_output_dir(out, command=..., inputs=...)``
    The rule, without touching anything; returns the resolved path. Call it first to fail
    before expensive work (:func:`atomic_output_dir` calls it again).
``with atomic_output_dir(out, command=..., inputs=...) as tmp:``
    Write a whole folder (``generate``, ``reconstruct``, ``evaluate``, ``benchmark``, a sweep
    writing ``DIR/0000/``, ``DIR/0001/`` … into ``tmp``, an importer). Nested calls inside
    ``tmp`` are fine (benchmark's per-dataset folders): each gets its own marker.
``with open_output_dir(out, command=..., inputs=...) as folder:``
    Work *in place* in an output folder that grows over several runs (``benchmark
    --resume``): created with its marker if missing or empty, else it must be ours by the
    rule. The lock is held while the block runs. ``folder.has("tasks/0003")`` says whether a
    part was completed; ``with folder.atomic_child("tasks/0003") as tmp:`` writes one part
    atomically (replacing an earlier copy of it); ``folder.write_text("results.json", text)``
    replaces one file atomically. The marker's ``entries`` are updated before each part is
    renamed into place, so an interrupted run never leaves a part the next run would
    mistake for someone else's files.
``staging_path(part)`` and ``folder.adopt("tasks/0003", staged)``
    A part written by another process (a Dask worker) at ``staging_path`` is moved into place
    by the process that holds the folder.
``with atomic_output_files([stem.exr, stem.png], overwrite=..., inputs=...) as tmp_paths:``
    Files rather than a folder (``render``): ``tmp_paths[path]`` is where to write each;
    all are renamed into place together at the end.

``command`` is the subcommand's name (``"generate"``); ``inputs`` every file or folder the
command reads (missing ones are fine). Errors name the option ``--out``.

Examples
--------
>>> import tempfile, pathlib
>>> base = pathlib.Path(tempfile.mkdtemp())
>>> with atomic_output_dir(base / "result", command="example") as tmp:
...     _ = (tmp / "numbers.txt").write_text("1 2 3")
>>> sorted(p.name for p in (base / "result").iterdir())
['.thinfilm-output', 'numbers.txt']
>>> read_marker(base / "result")["entries"]
['numbers.txt']
>>> (base / "result" / "notes.md").write_text("mine")
4
>>> try:
...     check_output_dir(base / "result", command="example")
... except UserError as e:
...     print(str(e).split(": ", 1)[1])
holds 'notes.md', which thinfilm did not write; refusing to replace it (choose another output folder, or move your files away)
>>> import shutil; shutil.rmtree(base)
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
import socket
import sys
from pathlib import Path

from . import signals
from .errors import UserError

__all__ = [
    "MARKER",
    "MARKER_FORMAT",
    "check_output_dir",
    "atomic_output_dir",
    "open_output_dir",
    "OutputFolder",
    "check_output_files",
    "atomic_output_files",
    "output_lock",
    "read_marker",
    "clean_stale_temporaries",
    "host_tag",
    "exchange_paths",
]

#: The file that marks a folder as an output of this tool.
MARKER = ".thinfilm-output"
MARKER_FORMAT = "thinfilm-output/1"

_TEMP_RE = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old|stage)-(?P<pid>\d+)@(?P<host>[A-Za-z0-9-]{1,32})-"
                      r"(?P<rand>[A-Za-z0-9_]{8})(?P<ext>\.[A-Za-z0-9]{1,8})?$")


# -- small helpers ------------------------------------------------------------------------------

def host_tag() -> str:
    """This machine's name as it appears in the names of temporaries (``...-PID@HOST-...``):
    letters, digits and '-', at most 32 characters."""
    host = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname() or "")[:32]
    return host or "host"


def _temp_name(name: str, kind: str = "tmp", ext: str = "") -> str:
    """``.NAME.tmp-PID@HOST-XXXXXXXX[.ext]``: the pattern :func:`clean_stale_temporaries` knows."""
    rand = secrets.token_hex(4)
    return f".{name}.{kind}-{os.getpid()}@{host_tag()}-{rand}{ext}"


def _umask() -> int:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _resolve(path) -> Path:
    try:
        return Path(os.path.abspath(os.path.expanduser(os.fspath(path)))).resolve()
    except (RuntimeError, OSError) as e:  # a loop of symbolic links
        raise UserError(f"cannot resolve the path ({e})", argument="out", value=path) from None


def _reason(e: OSError) -> str:
    return e.strerror or str(e) or type(e).__name__


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: it exists, it is someone else's
        return True
    return True


def _tree(root: Path) -> set:
    """Every file and folder below ``root`` as relative POSIX paths, folders with a trailing
    ``/``; symbolic links are listed, never followed. The marker itself is left out."""
    out = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        rel = Path(dirpath).relative_to(root)
        for d in dirnames:
            out.add((rel / d).as_posix() + "/")
        for f in filenames:
            out.add((rel / f).as_posix())
    out.discard(MARKER)
    return out


def _is_stale_temporary(path: Path) -> bool:
    m = _TEMP_RE.match(path.name)
    return bool(m) and m["host"] == host_tag() and not _pid_alive(int(m["pid"]))


def _in_stale_temporary(root: Path, rel: str) -> bool:
    """Whether ``rel`` (below ``root``) is, or lies inside, a stale temporary."""
    path = root
    for part in Path(rel).parts:
        path = path / part
        if _is_stale_temporary(path):
            return True
    return False


def _overlap(out: Path, inputs) -> str | None:
    for item in inputs or ():
        if item is None:
            continue
        raw = Path(os.fspath(item))
        inp = _resolve(raw)
        if inp == out:
            return f"is the input {raw}; refusing to write an output over an input"
        if inp.is_relative_to(out):
            return f"contains the input {raw}; refusing to replace it"
        if out.is_relative_to(inp):
            return f"lies inside the input {raw}; refusing to write into an input"
    return None


def _dir_mode() -> int:
    return 0o777 & ~_umask()


def _file_mode() -> int:
    return 0o666 & ~_umask()


def _rmtree(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _make_parents(folder: Path, created: list) -> None:
    """Create ``folder`` and its missing parents, appending each one made to ``created``
    (outermost first) as soon as it exists, so that an interrupt midway loses no record."""
    missing = []
    p = folder
    while not p.exists():
        if p.is_symlink():
            raise OSError(errno.ENOENT, "a symbolic link points nowhere", str(p))
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    for d in reversed(missing):
        with signals.blocked():
            try:
                d.mkdir()
            except FileExistsError:
                continue
            created.append(d)


def _remove_created(created) -> None:
    for d in reversed(created):
        with contextlib.suppress(OSError):
            d.rmdir()


def _about_output(e: OSError, *places) -> bool:
    """Whether an OSError raised while writing an output is the output's fault (a full disk,
    a file inside the temporary folder) rather than an input's."""
    if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG):
        return True
    for name in (e.filename, getattr(e, "filename2", None)):
        if name is None:
            continue
        try:
            p = _resolve(name)
        except (OSError, ValueError):
            continue
        if any(p == q or p.is_relative_to(q) for q in places):
            return True
    return False


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux ``renameat2(RENAME_EXCHANGE)``); False where the
    system or file system cannot."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _swap_into_place(new: Path, target: Path) -> None:
    """Put folder ``new`` at ``target`` (replacing what is there) and delete the old one.
    Signals are held back meanwhile."""
    with signals.blocked():
        if not target.exists():
            os.rename(new, target)
            return
        if not any(target.iterdir()):
            try:
                os.rename(new, target)  # over an empty folder, in one step (POSIX)
                return
            except OSError:
                pass
        if exchange_paths(new, target):
            _rmtree(new)  # it now holds the old output
            return
        old = target.with_name(_temp_name(target.name, "old"))
        os.rename(target, old)
        try:
            os.rename(new, target)
        except OSError:
            os.rename(old, target)
            raise
        _rmtree(old)


# -- markers ----------------------------------------------------------------------------------------

def read_marker(folder) -> dict | None:
    """The marker of an output folder (a dict with ``command`` and ``entries``), or None
    when the folder has no valid one."""
    path = Path(folder) / MARKER
    try:
        if path.is_symlink() or not path.is_file():
            return None
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if (not isinstance(data, dict) or data.get("format") != MARKER_FORMAT
            or not isinstance(data.get("entries"), list)
            or not all(isinstance(e, str) for e in data["entries"])):
        return None
    return data


def _write_marker(folder: Path, command, entries) -> None:
    """Write the marker atomically (a temporary file renamed over it). Deterministic: the
    same output gives the same bytes."""
    from thinfilm import __version__

    data = {"format": MARKER_FORMAT, "tool": "thinfilm", "version": __version__,
            "command": command, "entries": sorted(entries)}
    tmp = folder / _temp_name(MARKER)
    tmp.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    os.chmod(tmp, _file_mode())
    os.replace(tmp, folder / MARKER)


# -- the rule -------------------------------------------------------------------------------------

def _cmd(command) -> str:
    return f"'thinfilm {command}'" if command else "another thinfilm command"


def _check_ours(out: Path, command, what: str = "out") -> None:
    """``out`` exists and is a folder: refuse unless empty or ours by the rule."""
    entries = [p for p in out.iterdir() if not _is_stale_temporary(p)]
    if not entries:
        return
    marker = read_marker(out)
    if marker is None:
        raise UserError(f"folder exists, is not empty and is not a thinfilm output; "
                        f"refusing to replace it (it has no {MARKER} marker)", argument=what, value=out)
    if marker.get("command") != command:
        raise UserError(f"holds the output of {_cmd(marker.get('command'))}, not of "
                        f"{_cmd(command)}; refusing to replace it", argument=what, value=out)
    known = set(marker["entries"])
    foreign = sorted(e for e in _tree(out) if e not in known and not _in_stale_temporary(out, e))
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise UserError(f"holds '{foreign[0].rstrip('/')}'{more}, which thinfilm did not "
                        f"write; refusing to replace it (choose another output folder, or move your files "
                        f"away)", argument=what, value=out)


def check_output_dir(out, *, command=None, inputs=()) -> Path:
    """Check that ``out`` may receive a new output folder, before any work; touches nothing.

    Parameters
    ----------
    out : path-like
        The ``--out`` folder: absent, an empty folder, or an earlier output of ``command``
        holding only what it wrote (see the module docstring).
    command : str, optional
        The subcommand's name, recorded in the marker; an existing output of another command
        is never replaced.
    inputs : iterable of path-like
        Files and folders the command reads; ``out`` may not be, contain, or lie inside any.

    Returns
    -------
    Path
        ``out``, absolute, symbolic links resolved.

    Raises
    ------
    UserError
        One line naming ``--out``.
    """
    out = _resolve(out)
    if out.parent == out:
        raise UserError(f"cannot write an output folder at the file-system root", argument="out", value=out)
    problem = _overlap(out, inputs)
    if problem:
        raise UserError(f"{problem}", argument="out", value=out)
    if out.exists():
        if not out.is_dir():
            raise UserError(f"exists and is not a folder", argument="out", value=out)
        try:
            _check_ours(out, command)
        except PermissionError as e:
            raise UserError(f"cannot read the existing folder ({_reason(e)})", argument="out", value=out) from None
    elif out.is_symlink():
        raise UserError(f"is a symbolic link that points nowhere", argument="out", value=out)
    return out


# -- the lock -------------------------------------------------------------------------------------

@contextlib.contextmanager
def output_lock(out, what: str = "out"):
    """Hold the exclusive lock of output ``out`` (``.NAME.lock`` beside it; its parent must
    exist). A second holder gets a :class:`UserError` at once; the lock file is removed
    when released."""
    out = Path(out)
    fd = None
    try:
        with signals.blocked():  # no interrupt between taking the lock and owning it here
            fd = _acquire(out, what)
        yield out.parent / f".{out.name}.lock"
    finally:
        if fd is not None:
            with signals.blocked():
                with contextlib.suppress(OSError):
                    os.unlink(out.parent / f".{out.name}.lock")
                os.close(fd)


def _acquire(out: Path, what: str) -> int:
    import fcntl

    lock = out.parent / f".{out.name}.lock"
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as e:
            raise UserError(f"cannot create the folder ({_reason(e)})", argument=what, value=out) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            owner = ""
            with contextlib.suppress(OSError, ValueError, IndexError):
                owner = os.pread(fd, 64, 0).decode("ascii", "replace").split()[0]
            os.close(fd)
            if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                who = f" (process {owner})" if owner else ""
                raise UserError(f"another thinfilm command{who} is writing it; wait for it "
                                f"to finish or choose another output folder", argument=what, value=out) from None
            raise UserError(f"cannot lock the output ({_reason(e)})", argument=what, value=out) from None
        # The file may have been removed by the previous holder after we opened it: then
        # our lock is on a dead inode; start again.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError:
                pass
            return fd
        os.close(fd)


# -- stale temporaries ---------------------------------------------------------------------------

def clean_stale_temporaries(parent) -> list:
    """Remove what killed processes left in folder ``parent``: temporaries of this module's
    name pattern, of this host, whose process id is not running. An old output moved aside
    by such a process is moved back when nothing took its place. Returns the paths
    removed or restored."""
    parent = Path(parent)
    done = []
    try:
        children = list(parent.iterdir())
    except OSError:
        return done
    for p in children:
        m = _TEMP_RE.match(p.name)
        if not m or m["host"] != host_tag() or _pid_alive(int(m["pid"])):
            continue
        if p.is_symlink() or not (p.is_dir() or p.is_file()):
            continue
        if m["kind"] == "old":
            target = parent / m["name"]
            if not target.exists() and not target.is_symlink():
                with contextlib.suppress(OSError):
                    os.rename(p, target)
                    done.append(target)
                    continue
        _rmtree(p)
        if not p.exists():
            done.append(p)
    return done


# -- whole folders --------------------------------------------------------------------------------

@contextlib.contextmanager
def _locked(out, command, inputs, created):
    """Create the missing parents of ``out`` (recorded in ``created``), hold the lock of
    ``out``, clear stale temporaries beside it and check ``out`` again under the lock."""
    try:
        _make_parents(out.parent, created)
    except OSError as e:
        raise UserError(f"cannot create the folder ({_reason(e)})", argument="out", value=out) from None
    with output_lock(out):
        clean_stale_temporaries(out.parent)
        check_output_dir(out, command=command, inputs=inputs)
        yield


@contextlib.contextmanager
def atomic_output_dir(out, *, command=None, inputs=()):
    """Yield a new temporary folder beside ``out``; when the block succeeds, mark it, give it
    normal permissions and swap it into place at ``out`` (see the module docstring).

    The lock of ``out`` is held for the whole block, so a second writer to ``out`` stops at
    once. On any error, interrupt or termination, the temporary folder, the lock and the
    parent folders this call created are removed. File-system failures while writing
    (full disk, permissions) become a :class:`UserError` naming ``--out``.

    Parameters are those of :func:`check_output_dir`.
    """
    out = check_output_dir(out, command=command, inputs=inputs)
    created = []
    try:
        with _locked(out, command, inputs, created):
            tmp = out.parent / _temp_name(out.name)
            try:
                try:
                    tmp.mkdir(mode=0o700)
                except OSError as e:
                    raise UserError(f"cannot create the folder ({_reason(e)})", argument="out", value=out) from None
                yield tmp
                _write_marker(tmp, command, _tree(tmp))
                os.chmod(tmp, _dir_mode())
                check_output_dir(out, command=command, inputs=inputs)  # nothing changed meanwhile
                _swap_into_place(tmp, out)
            except OSError as e:
                _rmtree(tmp)
                if _about_output(e, tmp, out):
                    raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=out) from None
                raise
            except BaseException:
                _rmtree(tmp)
                raise
    except BaseException:
        _remove_created(created)
        raise


class OutputFolder:
    """An output folder written in place, part by part (see :func:`open_output_dir`)."""

    def __init__(self, path: Path, command):
        self.path = path
        self.command = command
        marker = read_marker(path)
        self._entries = set(marker["entries"]) if marker else set()

    @property
    def entries(self) -> frozenset:
        """What the marker lists (relative paths, folders with a trailing ``/``)."""
        return frozenset(self._entries)

    def _rel(self, rel) -> str:
        p = Path(rel)
        if p.is_absolute() or not p.parts or ".." in p.parts or p.name == MARKER:
            raise ValueError(f"output part must be a relative path inside the folder, got {rel!r}")
        return p.as_posix()

    def has(self, rel) -> bool:
        """Whether part ``rel`` (a file or folder) was completed by an earlier write."""
        rel = self._rel(rel)
        target = self.path / rel
        return target.exists() and (rel in self._entries or rel + "/" in self._entries)

    def _prepare_parent(self, rel: str) -> Path:
        target = self.path / rel
        folders = {p.as_posix() + "/" for p in Path(rel).parents if p.parts}
        if not folders <= self._entries:
            self._entries |= folders
            _write_marker(self.path, self.command, self._entries)
        target.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temporaries(target.parent)
        if target.exists() or target.is_symlink():
            inside = {rel + "/"} | {f"{rel}/{e}" for e in _tree(target)} if target.is_dir() else {rel}
            foreign = sorted(e for e in inside if e not in self._entries)
            if foreign:
                raise UserError(f"holds '{foreign[0].rstrip('/')}', which thinfilm did "
                                f"not write; refusing to replace it", argument="out", value=self.path)
        return target

    @contextlib.contextmanager
    def atomic_child(self, rel):
        """Yield a temporary folder; on success it replaces part ``rel`` (a folder) in one
        step, and the marker lists its contents."""
        rel = self._rel(rel)
        try:
            target = self._prepare_parent(rel)
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        tmp = target.parent / _temp_name(target.name)
        try:
            tmp.mkdir(mode=0o700)
            yield tmp
            os.chmod(tmp, _dir_mode())
            self._entries |= {rel + "/"} | {f"{rel}/{e}" for e in _tree(tmp)}
            _write_marker(self.path, self.command, self._entries)
            _swap_into_place(tmp, target)
        except OSError as e:
            _rmtree(tmp)
            if _about_output(e, tmp, self.path):
                raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
            raise
        except BaseException:
            _rmtree(tmp)
            raise

    def adopt(self, rel, staged) -> Path:
        """Move folder ``staged`` into place as part ``rel`` in one step, the marker listing
        its contents. ``staged`` was written elsewhere, by another process (a Dask worker), at
        :func:`staging_path` of the part: until it is adopted it is a temporary folder that
        the stale-temporary cleanup removes once its process is gone."""
        rel = self._rel(rel)
        staged = Path(staged)
        try:
            target = self._prepare_parent(rel)
            os.chmod(staged, _dir_mode())
            inside = _tree(staged) | ({MARKER} if (staged / MARKER).is_file() else set())  # its own marker too
            self._entries |= {rel + "/"} | {f"{rel}/{e}" for e in inside}
            _write_marker(self.path, self.command, self._entries)
            _swap_into_place(staged, target)
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        return target

    def write_bytes(self, rel, data: bytes) -> Path:
        """Replace file ``rel`` atomically (a temporary file renamed over it)."""
        rel = self._rel(rel)
        try:
            target = self._prepare_parent(rel)
            tmp = target.parent / _temp_name(target.name)
            try:
                tmp.write_bytes(data)
                os.chmod(tmp, _file_mode())
                self._entries.add(rel)
                _write_marker(self.path, self.command, self._entries)
                os.replace(tmp, target)
            except BaseException:
                with contextlib.suppress(OSError):
                    tmp.unlink()
                raise
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        return target

    def write_text(self, rel, text: str) -> Path:
        """Replace text file ``rel`` atomically (UTF-8)."""
        return self.write_bytes(rel, text.encode("utf-8"))


def staging_path(target) -> Path:
    """A fresh temporary path beside ``target`` (nothing is created), named in this module's
    pattern: another process writes a part there (e.g. ``atomic_output_dir(staging_path(t))``)
    for :meth:`OutputFolder.adopt` to move into place; if that process dies first, the
    stale-temporary cleanup removes it."""
    target = Path(target)
    return target.parent / _temp_name(target.name, kind="stage")


@contextlib.contextmanager
def open_output_dir(out, *, command=None, inputs=()):
    """Yield an :class:`OutputFolder` to write ``out`` in place, part by part, holding its
    lock (an output that grows over several runs, such as ``benchmark --resume``).

    ``out`` is created with its marker when missing or empty; otherwise it must be an
    output of ``command`` holding nothing else (:func:`check_output_dir`). Parts written
    before an error stay (that is the point of resuming); a half-written part never does.
    """
    out = check_output_dir(out, command=command, inputs=inputs)
    fresh = not out.exists()
    created = []
    try:
        with _locked(out, command, inputs, created):
            try:
                if not out.exists():
                    out.mkdir()
                    os.chmod(out, _dir_mode())
                for dirpath, _, _ in os.walk(out, followlinks=False):
                    clean_stale_temporaries(dirpath)
                if read_marker(out) is None:
                    _write_marker(out, command, ())
            except OSError as e:
                raise UserError(f"cannot create the folder ({_reason(e)})", argument="out", value=out) from None
            yield OutputFolder(out, command)
    except BaseException:
        if fresh and out.exists() and read_marker(out) is not None and not (
                set(p.name for p in out.iterdir()) - {MARKER}):
            _rmtree(out)  # nothing was written: leave no trace
        _remove_created(created)
        raise


# -- files ----------------------------------------------------------------------------------------

def check_output_files(paths, *, overwrite=False, inputs=(), what="out") -> list:
    """Check that files ``paths`` may be written: each absent, or an existing file and
    ``overwrite`` given; none of them an input. Returns the resolved paths."""
    out = []
    for p in paths:
        r = _resolve(p)
        problem = _overlap(r, inputs)
        if problem:
            raise UserError(f"{problem}", argument=what, value=r)
        if r.is_dir():
            raise UserError(f"is a folder, expected a file path", argument=what, value=r)
        if (r.exists() or r.is_symlink()) and not overwrite:
            raise UserError(f"file exists; pass --overwrite to replace it", argument=what, value=r)
        out.append(r)
    if len(set(out)) != len(out):
        raise UserError(f"two outputs have the same path {out}", argument=what)
    return out


@contextlib.contextmanager
def atomic_output_files(paths, *, overwrite=False, inputs=(), what="out"):
    """Yield ``{path: temporary path}`` beside each of ``paths`` (same extension, so writers
    that go by the extension work); when the block succeeds, rename them all into place.

    The lock is the first path's; the rule is :func:`check_output_files`. On any error the
    temporaries, the lock and the parent folders this call created are removed.
    """
    targets = check_output_files(paths, overwrite=overwrite, inputs=inputs, what=what)
    created = []
    try:
        try:
            for t in targets:
                _make_parents(t.parent, created)
        except OSError as e:
            raise UserError(f"cannot create the folder ({_reason(e)})", argument=what, value=targets[0]) from None
        with output_lock(targets[0], what=what):
            for parent in {t.parent for t in targets}:
                clean_stale_temporaries(parent)
            check_output_files(targets, overwrite=overwrite, inputs=inputs, what=what)
            tmps = {t: t.parent / _temp_name(t.name, ext=t.suffix) for t in targets}
            try:
                yield dict(tmps)
                for t, tmp in tmps.items():
                    if not tmp.is_file():
                        raise RuntimeError(f"atomic_output_files: {t.name} was not written")
                    os.chmod(tmp, _file_mode())
                check_output_files(targets, overwrite=overwrite, inputs=inputs, what=what)
                with signals.blocked():
                    for t, tmp in tmps.items():
                        os.replace(tmp, t)
            except OSError as e:
                for tmp in tmps.values():
                    _rmtree(tmp)
                if _about_output(e, *tmps, *targets):
                    raise UserError(f"cannot write the output ({_reason(e)})", argument=what, value=targets[0]) from None
                raise
            except BaseException:
                for tmp in tmps.values():
                    _rmtree(tmp)
                raise
    except BaseException:
        _remove_created(created)
        raise
