"""Output folders and files: never destroy anything, never leave anything half written.

The rule (``docs/design.md``, *Outputs never destroy anything*)
---------------------------------------------------------------
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
   symbolic links;
4. it is not itself a symbolic link: an output is never written through one (a link that
   points nowhere included), nor is a folder created where a dangling link leads.

Otherwise the command stops with one line (:class:`~thinfilm.core.errors.UserError`, exit
code 2) before any work, and nothing is touched. ``render`` writes files, not a folder: it
refuses to replace an existing file unless asked to (``--overwrite``), never replaces
one of its inputs, and never a symbolic link or anything but a regular file.

Only what this tool made is ever opened for writing, followed, truncated or removed: a file,
link or folder of someone else's at a path this module uses (the lock, a name like a
temporary's) stops the command with one line, and stays as it was.

How an output is written
------------------------
:func:`atomic_output_dir` takes a lock, checks the rule, and creates a new temporary folder
beside ``--out`` (``.NAME.tmp-PID@HOST-XXXXXXXX``, holding the record :data:`TEMP_MARKER`),
and yields a folder ``NAME`` inside it. The command does its work and writes its files
there. When the block ends without an error the marker is written, the folder gets the
permissions of the user's umask (not 0700), the rule is checked once more, and the folder is
swapped into place in one step (``renameat2(RENAME_EXCHANGE)`` where the file system has it;
else two renames with the signals held back in between); the old output is then deleted,
all or nothing: every file of it is first moved into the temporary folder, and if one cannot
be (an immutable file, a folder one may not write), every move is undone, the old output
stays as it was, the new one is moved beside it (``NAME.new``) and the command stops with
one line that says where it is. On any error, on Ctrl-C and on SIGTERM, SIGHUP or SIGQUIT
(:mod:`thinfilm.core.signals` turns them into exceptions) the temporary folder is removed,
and so are the parent folders the call created, so a failed command leaves the file system
as it found it.

- **Lock.** ``.NAME.lock`` beside ``--out``, created new (``O_EXCL``, never through a link)
  holding ``thinfilm-lock/1 PID HOST`` and held with ``flock`` from before the work until
  the output is in place (and removed then). A second writer to the same ``--out`` stops at
  once with one line naming the first one's process id: two writers can never both
  succeed. A lock file of ours left by a killed process (its process gone from this host)
  is taken over; anything else at that path is refused, never opened for writing. Lock
  files of ours that killed processes left elsewhere (beside a part being staged) are not
  taken for someone else's files, and the stale-temporary clean-up removes them when their
  process is gone from this host and nobody holds them.
- **Stale temporaries.** A process killed with SIGKILL cannot clean up. The next output
  written into the same parent folder removes the temporary folders left there by processes
  that no longer exist: only folders of this module's name pattern that hold its record,
  only of this host, only when the recorded process is not running. A folder or file merely
  named like one is never touched. (An old output that a killed process had moved aside
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
``staged = folder.staging_path("tasks/0003")`` and ``folder.adopt("tasks/0003", staged)``
    A part written by another process (a Dask worker) at ``staged`` is moved into place by
    the process that holds the folder, as soon as it is done. The part's parent folders are
    listed in the marker before anything is written there, so that a run killed meanwhile
    leaves nothing the next run would take for someone else's files; what was staged but
    not adopted when the run ends (a signal) is removed by ``folder.discard_staged()`` (which
    :func:`open_output_dir` calls on exit), and after SIGKILL by the next run, as a stale
    temporary. (``staging_path(part)``, the module function, names one without any of this.)
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
import stat
import sys
from pathlib import Path

from . import signals
from .errors import UserError

__all__ = [
    "MARKER",
    "MARKER_FORMAT",
    "TEMP_MARKER",
    "check_output_dir",
    "atomic_output_dir",
    "open_output_dir",
    "OutputFolder",
    "check_output_files",
    "atomic_output_files",
    "output_lock",
    "read_marker",
    "clean_stale_temporaries",
]

#: The file that marks a folder as an output of this tool.
MARKER = ".thinfilm-output"
MARKER_FORMAT = "thinfilm-output/1"
#: The file inside each temporary folder that records the process that made it.
TEMP_MARKER = ".thinfilm-temporary"
TEMP_FORMAT = "thinfilm-temporary/1"
#: The first word of a lock file's content (then the process id and the host).
LOCK_FORMAT = "thinfilm-lock/1"

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)

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


def _lexical(path, what: str = "out") -> Path:
    """``path`` made absolute with the links of its parent folders resolved, but not a link at
    its own name: the path a command writes at. A parent that is a link pointing nowhere
    is refused (it would be followed to create folders somewhere else)."""
    raw = Path(os.path.abspath(os.path.expanduser(os.fspath(path))))
    if raw.parent == raw:
        return raw
    up = raw.parent
    while not os.path.lexists(up) and up.parent != up:
        up = up.parent
    if os.path.islink(up) and not os.path.exists(up):
        raise UserError(f"'{up}' is a symbolic link that points nowhere; refusing to follow it",
                        argument=what, value=path)
    try:
        return raw.parent.resolve() / raw.name
    except (RuntimeError, OSError) as e:  # a loop of symbolic links
        raise UserError(f"cannot resolve the path ({e})", argument=what, value=path) from None


def _refuse_link(path: Path, what: str = "out") -> None:
    """Stop when ``path`` itself is a symbolic link: an output is never written through one."""
    if os.path.islink(path):
        if not os.path.exists(path):
            raise UserError(f"is a symbolic link that points nowhere; refusing to follow it", argument=what,
                            value=path)
        raise UserError(f"is a symbolic link (to {os.readlink(path)}); refusing to write through it (give "
                        f"the path it points to, or another one)", argument=what, value=path)


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


def _new_file(path, data: bytes, mode: int = 0o600) -> None:
    """Create file ``path`` (it must not exist, and a link there is never followed) holding ``data``."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC, mode)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    finally:
        os.close(fd)


def _read_own_file(path, limit: int = 4096) -> bytes | None:
    """The first bytes of regular file ``path``, read without following a link there; None
    when it is missing, a link or anything but a regular file."""
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _CLOEXEC | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        return os.read(fd, limit)
    except OSError:
        return None
    finally:
        os.close(fd)


def _temp_record(pid: int | None = None, host: str | None = None) -> bytes:
    return (json.dumps({"format": TEMP_FORMAT, "pid": int(pid or os.getpid()), "host": host or host_tag()},
                       sort_keys=True) + "\n").encode("ascii")


def _make_temporary(parent: Path, name: str, kind: str = "tmp") -> Path:
    """Create a new temporary folder ``.NAME.KIND-PID@HOST-XXXXXXXX`` in ``parent``, holding
    the file :data:`TEMP_MARKER` that records this process: what makes it ours to remove
    later. Signals are held back meanwhile, so it never exists without its record; one that
    arrived meanwhile is raised as the block ends, before the caller holds the folder, so the
    folder is removed here then."""
    path = parent / _temp_name(name, kind)
    made = False
    try:
        with signals.blocked():
            os.mkdir(path, 0o700)
            made = True
            _new_file(path / TEMP_MARKER, _temp_record())
    except BaseException:
        if made:
            shutil.rmtree(path, ignore_errors=True)
        raise
    return path


def _temporary_owner(path: Path):
    """``(pid, host)`` that the record of temporary folder ``path`` names, or None when
    ``path`` is not a folder (a link is not) holding a valid record that agrees with its name."""
    m = _TEMP_RE.match(path.name)
    if not m:
        return None
    try:
        if not stat.S_ISDIR(os.lstat(path).st_mode):
            return None
    except OSError:
        return None
    data = _read_own_file(path / TEMP_MARKER)
    try:
        rec = json.loads(data.decode("ascii")) if data else None
    except (UnicodeDecodeError, ValueError):
        return None
    if (not isinstance(rec, dict) or rec.get("format") != TEMP_FORMAT or not isinstance(rec.get("pid"), int)
            or rec.get("pid") <= 0 or rec.get("host") != m["host"] or rec["pid"] != int(m["pid"])):
        return None
    return rec["pid"], rec["host"]


def _is_stale_temporary(path: Path) -> bool:
    """A folder of this module's pattern that holds our record, of this host, whose process
    is gone. Anything else named like one (a person's folder, a file) is not ours."""
    owner = _temporary_owner(path)
    return owner is not None and owner[1] == host_tag() and not _pid_alive(owner[0])


_LOCK_RE = re.compile(r"^\..+\.lock$")


def _lock_owner(path: Path):
    """``(pid, host)`` that lock file ``path`` (``.NAME.lock``, a regular file, not a link)
    names in our format, or None when it is anything else."""
    if not _LOCK_RE.match(path.name):
        return None
    return _parse_lock(_read_own_file(path, 256))


def _is_stale_lock(path: Path) -> bool:
    """A lock file of ours (``.NAME.lock`` holding ``thinfilm-lock/1 PID HOST``) of this host
    whose process is gone: what a killed command left."""
    owner = _lock_owner(path)
    return owner is not None and owner[1] == host_tag() and not _pid_alive(owner[0])


def _remove_stale_lock(path: Path) -> bool:
    """Remove lock file ``path`` when it is stale (:func:`_is_stale_lock`) and nobody holds
    it (``flock``): never a file that is not ours, nor one being taken over meanwhile."""
    import fcntl

    if not _is_stale_lock(path):
        return False
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _CLOEXEC | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return False
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False  # someone holds it: not stale after all
        owner = _parse_lock(os.pread(fd, 256, 0))
        if owner is None or owner[1] != host_tag() or _pid_alive(owner[0]):
            return False
        with signals.blocked():
            if os.path.samestat(st, os.lstat(path)):
                os.unlink(path)
                return True
    except OSError:
        pass
    finally:
        os.close(fd)
    return False


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
    places = [q for q in places if q is not None]
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


def _rename_noreplace(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst`` only if nothing is at ``dst`` (``renameat2(RENAME_NOREPLACE)``
    where the system has it)."""
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            fn = ctypes.CDLL(None, use_errno=True).renameat2
        except (OSError, AttributeError):
            fn = None
        if fn is not None:
            fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
            fn.restype = ctypes.c_int
            if fn(-100, os.fsencode(src), -100, os.fsencode(dst), 1) == 0:
                return
            err = ctypes.get_errno()
            if err not in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
                raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
    os.rename(src, dst)


class _OldKept(OSError):
    """The old folder could not be removed whole; it was put back as it was."""

    def __init__(self, error: OSError, root: Path):
        super().__init__(error.errno, error.strerror or str(error), error.filename)
        self.error, self.root = error, root

    def where(self) -> str:
        name = self.error.filename
        if name is None:
            return ""
        try:
            return Path(os.fspath(name)).relative_to(self.root).as_posix()
        except ValueError:
            return ""


def move_entry(src, dst) -> None:
    """One step of removing an old folder: move ``src`` into the folder being emptied."""
    os.rename(src, dst)


def _raise(error):
    raise error


def _dismantle(root: Path, trash: Path) -> None:
    """Delete folder tree ``root`` (a real folder, not a link), all or nothing: first every file
    and folder in it is moved, deepest first, into the new folder ``trash`` (a move fails exactly
    where a deletion would: an immutable file, a folder one may not write); if one fails, every
    move is undone, so ``root`` is as it was, and :class:`_OldKept` is raised. Then ``trash``,
    which holds only what could be moved, is deleted."""
    os.mkdir(trash, 0o700)
    moved = []
    try:
        for dirpath, dirnames, filenames in os.walk(root, topdown=False, onerror=_raise):
            for name in filenames + dirnames:
                src = os.path.join(dirpath, name)
                dst = os.path.join(trash, str(len(moved)))
                move_entry(src, dst)
                moved.append((src, dst))
    except OSError as e:
        for src, dst in reversed(moved):
            with contextlib.suppress(OSError):
                os.rename(dst, src)
        with contextlib.suppress(OSError):
            os.rmdir(trash)
        raise _OldKept(e, root) from None
    shutil.rmtree(trash, ignore_errors=True)
    with contextlib.suppress(OSError):
        os.rmdir(root)


def _replace(new: Path, target: Path, holder: Path) -> None:
    """Put folder ``new`` at ``target`` and delete what was there, all or nothing. ``holder``
    is a temporary folder of ours beside ``target`` (:func:`_make_temporary`) where the old
    folder is taken apart. When the old folder cannot be removed whole it is put back at
    ``target`` as it was, ``new`` is back at its own path, and :class:`_OldKept` is raised.
    Signals are held back meanwhile."""
    with signals.blocked():
        if not os.path.lexists(target):
            os.rename(new, target)
            return
        if not any(target.iterdir()):
            try:
                os.rename(new, target)  # over an empty folder, in one step (POSIX)
                return
            except OSError:
                pass
        if exchange_paths(new, target):
            old = new  # it now holds the old folder
        else:
            old = holder / f"{target.name}.old"  # moved back by the stale clean-up if we die now
            os.rename(target, old)
            try:
                os.rename(new, target)
            except OSError:
                os.rename(old, target)
                raise
        try:
            _dismantle(old, holder / f"{target.name}.removed")
        except _OldKept:
            if old == new:
                exchange_paths(new, target)
            else:
                os.rename(target, new)
                os.rename(old, target)
            raise


def _park(new: Path, out: Path, holder: Path) -> Path:
    """Move a finished output that could not take the place of ``out`` to a free name beside
    it (``NAME.new``, ``NAME.new-2`` …); where that fails it stays in ``holder``, whose record
    is dropped so that no clean-up removes it. Returns where it is."""
    for i in range(1, 100):
        dest = out.with_name(f"{out.name}.new" + (f"-{i}" if i > 1 else ""))
        if os.path.lexists(dest):
            continue
        try:
            _rename_noreplace(new, dest)
            return dest
        except FileExistsError:
            continue
        except OSError:
            break
    with contextlib.suppress(OSError):
        os.unlink(holder / TEMP_MARKER)
    return new


def _kept_message(e: _OldKept, what: str, kept: Path | None) -> str:
    where = e.where()
    text = f"cannot remove the {what} ({_reason(e.error)}{f': {where!r}' if where else ''}); it is kept as it was"
    if kept is not None:
        text += f", and the new output is at {kept}"
    return text


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
    """Write the marker atomically (a new file in a temporary folder, renamed over it). Deterministic: the
    same output gives the same bytes."""
    from thinfilm import __version__

    data = {"format": MARKER_FORMAT, "tool": "thinfilm", "version": __version__,
            "command": command, "entries": sorted(entries)}
    holder = _make_temporary(folder, MARKER)
    try:
        tmp = holder / MARKER
        _new_file(tmp, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode("utf-8"))
        os.chmod(tmp, _file_mode())
        os.replace(tmp, folder / MARKER)
    finally:
        _rmtree(holder)


# -- the rule -------------------------------------------------------------------------------------

def _cmd(command) -> str:
    return f"'thinfilm {command}'" if command else "another thinfilm command"


def _check_ours(out: Path, command, what: str = "out") -> None:
    """``out`` exists and is a folder: refuse unless empty or ours by the rule."""
    entries = [p for p in out.iterdir() if not (_is_stale_temporary(p) or _is_stale_lock(p))]
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
    foreign = sorted(e for e in _tree(out) if e not in known and not _in_stale_temporary(out, e)
                     and not _is_stale_lock(out / e))
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
        ``out``, absolute, the symbolic links of its parent folders resolved (``out`` itself
        may not be one: an output is never written through a link).

    Raises
    ------
    UserError
        One line naming ``--out``.
    """
    full = _resolve(out)
    path = _lexical(out)
    if full.parent == full or path.parent == path:
        raise UserError(f"cannot write an output folder at the file-system root", argument="out", value=full)
    problem = _overlap(full, inputs)
    if problem:
        raise UserError(f"{problem}", argument="out", value=full)
    _refuse_link(path)
    if path.exists():
        if not path.is_dir():
            raise UserError(f"exists and is not a folder", argument="out", value=path)
        try:
            _check_ours(path, command)
        except PermissionError as e:
            raise UserError(f"cannot read the existing folder ({_reason(e)})", argument="out", value=path) from None
    return path


# -- the lock -------------------------------------------------------------------------------------

def _lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}.lock"


@contextlib.contextmanager
def output_lock(out, what: str = "out"):
    """Hold the exclusive lock of output ``out`` (``.NAME.lock`` beside it; its parent must
    exist). A second holder gets a :class:`UserError` at once; the lock file is removed
    when released.

    The lock file is created new (never through a link, never over a file already there) and
    holds ``thinfilm-lock/1 PID HOST``; the holder keeps it ``flock``-ed. A lock file of ours
    whose process is gone from this host (killed) is taken over; anything else at that path
    (a person's file, a link, a folder) is left alone and the command stops with one line."""
    out = Path(out)
    lock = _lock_path(out)
    fd = None
    try:
        with signals.blocked():  # no interrupt between taking the lock and owning it here
            fd = _acquire(out, lock, what)
        yield lock
    finally:
        if fd is not None:
            with signals.blocked():
                with contextlib.suppress(OSError):
                    if os.path.samestat(os.fstat(fd), os.lstat(lock)):
                        os.unlink(lock)
                os.close(fd)


def _parse_lock(data: bytes | None):
    """``(pid, host)`` of a lock file's content, or None when it is not one of ours."""
    try:
        parts = data.decode("ascii").split() if data else []
    except UnicodeDecodeError:
        return None
    if (len(parts) == 3 and parts[0] == LOCK_FORMAT and parts[1].isdigit() and int(parts[1]) > 0
            and re.fullmatch(r"[A-Za-z0-9-]{1,32}", parts[2])):
        return int(parts[1]), parts[2]
    return None


def _kind(mode: int) -> str:
    if stat.S_ISLNK(mode):
        return "symbolic link"
    if stat.S_ISDIR(mode):
        return "folder"
    if stat.S_ISREG(mode):
        return "file"
    return "special file"


def _acquire(out: Path, lock: Path, what: str) -> int:
    import fcntl
    import time

    def foreign(kind):
        return UserError(f"'{lock.name}' beside it is a {kind} that thinfilm did not make, at the path "
                         f"where it keeps the lock of this output; refusing to touch it (move it away, or "
                         f"choose another output folder)", argument=what, value=out)

    def busy(owner=None):
        who = f" (process {owner[0]}{'' if owner[1] == host_tag() else ' on ' + owner[1]})" if owner else ""
        return UserError(f"another thinfilm command{who} is writing it; wait for it to finish or choose "
                         f"another output folder", argument=what, value=out)

    empty_since = None
    for _ in range(10000):
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_EXCL | _NOFOLLOW | _CLOEXEC, 0o666)
        except FileExistsError:
            fd = None
        except OSError as e:
            raise UserError(f"cannot create the folder ({_reason(e)})", argument=what, value=out) from None
        if fd is not None:  # new, ours: lock it before saying whose it is
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                os.write(fd, f"{LOCK_FORMAT} {os.getpid()} {host_tag()}\n".encode("ascii"))
            except OSError as e:
                with contextlib.suppress(OSError):
                    os.unlink(lock)
                os.close(fd)
                raise UserError(f"cannot write the lock file ({_reason(e)})", argument=what, value=out) from None
            return fd
        # Something is there: read it without following a link, never write it.
        try:
            st = os.lstat(lock)
        except FileNotFoundError:
            continue
        except OSError as e:
            raise UserError(f"cannot read the lock file ({_reason(e)})", argument=what, value=out) from None
        if not stat.S_ISREG(st.st_mode):
            raise foreign(_kind(st.st_mode))
        try:
            rfd = os.open(lock, os.O_RDONLY | _NOFOLLOW | _CLOEXEC | getattr(os, "O_NONBLOCK", 0))
        except FileNotFoundError:
            continue
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise foreign("symbolic link") from None
            raise UserError(f"cannot read the lock file ({_reason(e)})", argument=what, value=out) from None
        try:
            fst = os.fstat(rfd)
            if not stat.S_ISREG(fst.st_mode):
                raise foreign(_kind(fst.st_mode))
            data = os.pread(rfd, 256, 0)
            owner = _parse_lock(data)
            try:
                fcntl.flock(rfd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise busy(owner) from None
                raise UserError(f"cannot lock the output ({_reason(e)})", argument=what, value=out) from None
            if owner is None:
                if data or fst.st_size:
                    raise foreign("file")
                # empty: another command between creating it and writing it, or not ours
                empty_since = empty_since or time.monotonic()
                if time.monotonic() - empty_since > 2.0:
                    raise foreign("file")
                time.sleep(0.01)
                continue
            if owner[1] != host_tag() or _pid_alive(owner[0]):
                raise busy(owner)
            # ours, and its process is gone (killed): take it over
            with contextlib.suppress(OSError):
                if os.path.samestat(fst, os.lstat(lock)):
                    os.unlink(lock)
        finally:
            os.close(rfd)
    raise UserError("cannot take the lock (it keeps changing)", argument=what, value=out)


# -- stale temporaries ---------------------------------------------------------------------------

def clean_stale_temporaries(parent, keep=()) -> list:
    """Remove what killed processes left in folder ``parent``: temporary folders of this
    module's name pattern that hold our record (:data:`TEMP_MARKER`), of this host, whose
    process is not running, and lock files of ours (``.NAME.lock`` holding
    ``thinfilm-lock/1 PID HOST``) of this host whose process is gone and that nobody holds. Anything else named like one (a person's folder or file) is
    never touched, nor are the paths in ``keep``. An old output that such a process had moved
    aside while swapping is moved back when nothing took its place. Returns the paths
    removed or restored."""
    parent = Path(parent)
    keep = {Path(k) for k in keep}
    done = []
    try:
        children = list(parent.iterdir())
    except OSError:
        return done
    for p in children:
        if p in keep:
            continue
        if _LOCK_RE.match(p.name) and _remove_stale_lock(p):
            done.append(p)
            continue
        if not _is_stale_temporary(p):
            continue
        name = _TEMP_RE.match(p.name)["name"]
        target, aside = parent / name, p / f"{name}.old"
        if (not os.path.lexists(target) and os.path.isdir(aside) and not os.path.islink(aside)
                and read_marker(aside) is not None):
            with contextlib.suppress(OSError):
                _rename_noreplace(aside, target)
                done.append(target)
        shutil.rmtree(p, ignore_errors=True)
        if not os.path.lexists(p):
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
            holder = None
            try:
                try:
                    holder = _make_temporary(out.parent, out.name)
                    tmp = holder / out.name
                    os.mkdir(tmp, 0o700)
                except OSError as e:
                    raise UserError(f"cannot create the folder ({_reason(e)})", argument="out", value=out) from None
                yield tmp
                _write_marker(tmp, command, _tree(tmp))
                stage = _TEMP_RE.match(out.name)
                if stage and stage["kind"] == "stage":  # a part for another process to adopt
                    _new_file(tmp / TEMP_MARKER, _temp_record(int(stage["pid"]), stage["host"]))
                os.chmod(tmp, _dir_mode())
                check_output_dir(out, command=command, inputs=inputs)  # nothing changed meanwhile
                try:
                    _replace(tmp, out, holder)
                except _OldKept as e:
                    kept = _park(tmp, out, holder)
                    if kept == tmp:  # it could not be moved: its folder is no temporary of ours any more
                        holder = None
                    raise UserError(_kept_message(e, "old output", kept), argument="out", value=out) from None
            except OSError as e:
                _rmtree_opt(holder)
                if _about_output(e, holder, out):
                    raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=out) from None
                raise
            except BaseException:
                _rmtree_opt(holder)
                raise
            _rmtree_opt(holder)
    except BaseException:
        _remove_created(created)
        raise


def _rmtree_opt(path) -> None:
    if path is not None:
        _rmtree(path)


class OutputFolder:
    """An output folder written in place, part by part (see :func:`open_output_dir`)."""

    def __init__(self, path: Path, command):
        self.path = path
        self.command = command
        marker = read_marker(path)
        self._entries = set(marker["entries"]) if marker else set()
        self._staged = []

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

    def _prepare_parent(self, rel: str, keep=()) -> Path:
        target = self.path / rel
        folders = {p.as_posix() + "/" for p in Path(rel).parents if p.parts}
        if not folders <= self._entries:
            self._entries |= folders
            _write_marker(self.path, self.command, self._entries)
        target.parent.mkdir(parents=True, exist_ok=True)
        clean_stale_temporaries(target.parent, keep=keep)
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
        holder = None
        try:
            holder = _make_temporary(target.parent, target.name)
            tmp = holder / target.name
            os.mkdir(tmp, 0o700)
            yield tmp
            os.chmod(tmp, _dir_mode())
            self._entries |= {rel + "/"} | {f"{rel}/{e}" for e in _tree(tmp)}
            _write_marker(self.path, self.command, self._entries)
            try:
                _replace(tmp, target, holder)
            except _OldKept as e:
                raise UserError(_kept_message(e, f"old copy of '{rel}'", None), argument="out",
                                value=self.path) from None
        except OSError as e:
            _rmtree_opt(holder)
            if _about_output(e, holder, self.path):
                raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
            raise
        except BaseException:
            _rmtree_opt(holder)
            raise
        _rmtree_opt(holder)

    def staging_path(self, rel) -> Path:
        """A fresh :func:`staging_path` for part ``rel``, its parent folders made first and
        listed in the marker (so that a run killed while another process writes there leaves
        nothing the next run would take for someone else's files). Paths handed out are
        removed by :meth:`discard_staged` unless adopted."""
        rel = self._rel(rel)
        try:
            target = self._prepare_parent(rel)
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        staged = staging_path(target)
        self._staged.append(staged)
        return staged

    def discard_staged(self) -> None:
        """Remove what the staging paths of :meth:`staging_path` still hold (parts written
        but not adopted: the run was interrupted), and what the processes that wrote there
        left beside them once they are gone (their temporaries and locks). Only temporaries
        of ours are removed: of this process, or of processes gone from this host."""
        me = (os.getpid(), host_tag())
        with signals.blocked():
            for staged in self._staged:
                if os.path.lexists(staged) and (_temporary_owner(staged) == me or _is_stale_temporary(staged)):
                    _rmtree(staged)
            for parent in dict.fromkeys(s.parent for s in self._staged):
                clean_stale_temporaries(parent)
        self._staged = []

    def adopt(self, rel, staged) -> Path:
        """Move folder ``staged`` into place as part ``rel`` in one step, the marker listing
        its contents. ``staged`` was written elsewhere, by another process (a Dask worker), at
        :func:`staging_path` of the part: until it is adopted it is a temporary folder that
        the stale-temporary cleanup removes once its process is gone. Its record goes only
        after it is in place (listed meanwhile), so that it is never, even for a moment, a
        folder of no one's."""
        rel = self._rel(rel)
        staged = Path(staged)
        holder = None
        try:
            target = self._prepare_parent(rel, keep=(staged,))
            owned = _temporary_owner(staged) is not None  # its record: it becomes a part of ours now
            holder = _make_temporary(target.parent, target.name)
            os.chmod(staged, _dir_mode())
            inside = _tree(staged) | ({MARKER} if (staged / MARKER).is_file() else set())  # its own marker too
            record = f"{rel}/{TEMP_MARKER}"
            self._entries |= {rel + "/"} | {f"{rel}/{e}" for e in inside}
            _write_marker(self.path, self.command, self._entries)
            try:
                _replace(staged, target, holder)
            except _OldKept as e:
                raise UserError(_kept_message(e, f"old copy of '{rel}'", None), argument="out",
                                value=self.path) from None
            if staged in self._staged:
                self._staged.remove(staged)
            if owned:
                os.unlink(target / TEMP_MARKER)
                self._entries.discard(record)
                _write_marker(self.path, self.command, self._entries)
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        finally:
            _rmtree_opt(holder)
        return target

    def write_bytes(self, rel, data: bytes) -> Path:
        """Replace file ``rel`` atomically (a temporary file renamed over it)."""
        rel = self._rel(rel)
        try:
            target = self._prepare_parent(rel)
            holder = _make_temporary(target.parent, target.name)
            try:
                tmp = holder / target.name
                _new_file(tmp, data)
                os.chmod(tmp, _file_mode())
                self._entries.add(rel)
                _write_marker(self.path, self.command, self._entries)
                with signals.blocked():
                    os.replace(tmp, target)
            finally:
                _rmtree(holder)
        except OSError as e:
            raise UserError(f"cannot write the output ({_reason(e)})", argument="out", value=self.path) from None
        return target

    def write_text(self, rel, text: str) -> Path:
        """Replace text file ``rel`` atomically (UTF-8)."""
        return self.write_bytes(rel, text.encode("utf-8"))


def _tidy_marker(out: Path, command) -> None:
    """Bring the marker of an output written in place up to date after a run that was killed:
    a part's record of a temporary left inside it (killed just after moving it into place) is
    removed, and entries of what is not there (listed just before a move that never came) are
    dropped; a folder without a marker gets an empty one."""
    marker = read_marker(out)
    if marker is None:
        _write_marker(out, command, ())
        return
    entries = set(marker["entries"])
    records = {e for e in entries if e.endswith("/" + TEMP_MARKER)}
    for e in records:
        path = out / e
        if not _in_stale_temporary(out, e) and path.is_file() and not path.is_symlink():
            path.unlink()
    kept = {e for e in entries - records if os.path.lexists(out / e.rstrip("/"))}
    if kept != entries:
        _write_marker(out, marker.get("command", command), kept)


def staging_path(target) -> Path:
    """A fresh temporary path beside ``target`` (nothing is created), named in this module's
    pattern after the calling process: another process writes a part there (e.g.
    ``atomic_output_dir(staging_path(t))``, which leaves the record of a temporary folder
    in it, naming the calling process) for :meth:`OutputFolder.adopt` to move into place;
    if the calling process dies first, the stale-temporary cleanup removes it."""
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
                _tidy_marker(out, command)
            except OSError as e:
                raise UserError(f"cannot create the folder ({_reason(e)})", argument="out", value=out) from None
            folder = OutputFolder(out, command)
            try:
                yield folder
            finally:
                folder.discard_staged()
    except BaseException:
        if fresh and out.exists() and read_marker(out) is not None and not (
                set(p.name for p in out.iterdir()) - {MARKER}):
            _rmtree(out)  # nothing was written: leave no trace
        _remove_created(created)
        raise


# -- files ----------------------------------------------------------------------------------------

def check_output_files(paths, *, overwrite=False, inputs=(), what="out") -> list:
    """Check that files ``paths`` may be written: each absent, or an existing regular file
    and ``overwrite`` given; none of them an input, and none a symbolic link (an output is
    never written through one, ``overwrite`` or not). Returns the absolute paths, the links
    of their parent folders resolved."""
    out = []
    for p in paths:
        r = _lexical(p, what)
        problem = _overlap(_resolve(p), inputs)
        if problem:
            raise UserError(f"{problem}", argument=what, value=r)
        _refuse_link(r, what)
        if r.is_dir():
            raise UserError(f"is a folder, expected a file path", argument=what, value=r)
        if os.path.lexists(r):
            if not overwrite:
                raise UserError(f"file exists; pass --overwrite to replace it", argument=what, value=r)
            if not r.is_file():
                raise UserError(f"is not a regular file; refusing to replace it", argument=what, value=r)
        out.append(r)
    if len(set(out)) != len(out):
        raise UserError(f"two outputs have the same path {out}", argument=what)
    return out


@contextlib.contextmanager
def atomic_output_files(paths, *, overwrite=False, inputs=(), what="out"):
    """Yield ``{path: temporary path}`` for each of ``paths``, the temporary one of the same
    name in a temporary folder beside it (so writers that go by the extension work); when
    the block succeeds, rename them all into place.

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
            holders = {}
            try:
                try:
                    for t in targets:
                        if t.parent not in holders:
                            holders[t.parent] = _make_temporary(t.parent, t.name)
                except OSError as e:
                    raise UserError(f"cannot create the folder ({_reason(e)})", argument=what,
                                    value=targets[0]) from None
                tmps = {t: holders[t.parent] / t.name for t in targets}
                yield dict(tmps)
                for t, tmp in tmps.items():
                    if not (tmp.is_file() and not tmp.is_symlink()):
                        raise RuntimeError(f"atomic_output_files: {t.name} was not written")
                    os.chmod(tmp, _file_mode())
                check_output_files(targets, overwrite=overwrite, inputs=inputs, what=what)
                with signals.blocked():
                    for t, tmp in tmps.items():
                        os.replace(tmp, t)  # replaces a file (never follows a link: none is there)
            except OSError as e:
                for h in holders.values():
                    _rmtree(h)
                if _about_output(e, *holders.values(), *targets):
                    raise UserError(f"cannot write the output ({_reason(e)})", argument=what, value=targets[0]) from None
                raise
            except BaseException:
                for h in holders.values():
                    _rmtree(h)
                raise
            for h in holders.values():
                _rmtree(h)
    except BaseException:
        _remove_created(created)
        raise
