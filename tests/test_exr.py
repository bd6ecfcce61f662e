"""EXR files (thinfilm.core.exr): reading and writing from several threads at once with the
process's file descriptors untouched, and one classified error per call for each way a file
can be wrong."""

import errno
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from thinfilm.core.errors import UserError
from thinfilm.core.exr import EXR_ERROR_REASONS, ExrError, ExrWriteError, read_exr, write_exr


def _channels(seed, shape=(37, 23), names=("a", "b.R", "b.G")):
    """Smooth values in steps of 1/256, which ZIP compresses (no chunk is stored as it is)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    return {n: (np.round(256 * np.sin(0.1 * x + 0.2 * y + i + rng.random())) / 256).astype(np.float32)
            for i, n in enumerate(names)}


def _descriptors():
    """The files behind descriptors 1 and 2 (device, inode)."""
    return tuple((os.fstat(fd).st_dev, os.fstat(fd).st_ino) for fd in (1, 2))


def _openexr_file(path, channels, compression="ZIP_COMPRESSION", **header):
    """A file written by OpenEXR itself (another program's file)."""
    import OpenEXR

    head = {"compression": getattr(OpenEXR, compression), "type": OpenEXR.scanlineimage, **header}
    with OpenEXR.File(head, dict(channels)) as f:  # the binding turns the values into Channels
        f.write(str(path))


def test_threads_read_and_write_at_once_and_the_descriptors_stay(tmp_path, capfd):
    shared = _channels(0)
    write_exr(tmp_path / "shared.exr", shared)
    serial = {}
    for k in range(16):  # the bytes each file must have, written one at a time
        write_exr(tmp_path / f"serial{k}.exr", _channels(k + 1))
        serial[k] = (tmp_path / f"serial{k}.exr").read_bytes()
    capfd.readouterr()
    before = _descriptors()
    changed = []
    stop = threading.Event()

    def watch():  # the descriptors, sampled all the while the workers run
        while not stop.is_set():
            if _descriptors() != before:
                changed.append(_descriptors())

    def work(k):
        write_exr(tmp_path / f"t{k}.exr", _channels(k + 1))
        mine = read_exr(tmp_path / f"t{k}.exr")
        theirs = read_exr(tmp_path / "shared.exr")
        with pytest.raises(ExrError):  # errors too, while the others read and write
            read_exr(tmp_path / "nowhere.exr")
        return k, mine, theirs

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        with ThreadPoolExecutor(8) as pool:
            results = list(pool.map(work, [k for _ in range(4) for k in range(16)]))
    finally:
        stop.set()
        watcher.join()
    assert not changed and _descriptors() == before
    for k, mine, theirs in results:
        want = _channels(k + 1)
        assert sorted(mine) == sorted(want) and all(np.array_equal(mine[n], want[n]) for n in want)
        assert all(np.array_equal(theirs[n], shared[n]) for n in shared)
    for k in range(16):
        assert (tmp_path / f"t{k}.exr").read_bytes() == serial[k]
    assert capfd.readouterr() == ("", "")


def test_files_of_other_programs_read_as_written(tmp_path, capfd):
    """The structure check accepts what OpenEXR writes: every compression it has for float
    scanlines, half floats, decreasing line order, and a tiled file."""
    import OpenEXR

    data = _channels(5, (70, 41))
    cases = {c: {} for c in ("NO_COMPRESSION", "RLE_COMPRESSION", "ZIPS_COMPRESSION", "ZIP_COMPRESSION",
                             "PIZ_COMPRESSION", "PXR24_COMPRESSION", "B44_COMPRESSION", "DWAA_COMPRESSION")}
    cases["ZIP_COMPRESSION"] = {"lineOrder": OpenEXR.DECREASING_Y}
    for compression, header in cases.items():
        path = tmp_path / f"{compression}.exr"
        _openexr_file(path, data, compression, **header)
        with OpenEXR.File(str(path), separate_channels=True) as f:
            want = {k: np.asarray(v.pixels, dtype=np.float32) for k, v in f.channels().items()}
        got = read_exr(path)
        assert sorted(got) == sorted(want), compression
        assert all(np.array_equal(got[k], want[k]) for k in want), compression
    half = {k: v.astype(np.float16) for k, v in data.items()}
    _openexr_file(tmp_path / "half.exr", half)
    got = read_exr(tmp_path / "half.exr")
    assert all(got[k].dtype == np.float32 and np.array_equal(got[k], half[k].astype(np.float32)) for k in half)
    tiled = tmp_path / "tiled.exr"
    tiles = OpenEXR.TileDescription()
    tiles.xSize = tiles.ySize = 16
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles},
                      dict(data)) as f:
        f.write(str(tiled))
    got = read_exr(tiled)
    assert all(np.array_equal(got[k], data[k]) for k in data)
    assert capfd.readouterr() == ("", "")


def _one_line(e, path, reason):
    assert isinstance(e, UserError) and e.reason == reason and reason in EXR_ERROR_REASONS
    text = str(e)
    assert text.startswith(f"{path}: ") and "\n" not in text
    return text


def _refused(path, reason, capfd, **kw):
    capfd.readouterr()
    with pytest.raises(ExrError) as info:
        read_exr(path, **kw)
    assert capfd.readouterr() == ("", ""), "OpenEXR printed about the file"
    return _one_line(info.value, path, reason)


def test_a_truncated_file_is_refused_at_every_length(tmp_path, capfd):
    good = tmp_path / "good.exr"
    write_exr(good, _channels(1, (50, 20)))
    data = good.read_bytes()
    header_end = data.index(b"scanlineimage") + len(b"scanlineimage") + 1
    cut = tmp_path / "cut.exr"
    messages = set()
    for n in range(len(data)):
        cut.write_bytes(data[:n])
        messages.add(_refused(cut, "truncated", capfd).split(" (", 1)[1])
    assert "truncated: the file is empty)" in messages
    assert "truncated: the header is cut off)" in messages
    assert "truncated: the table of chunk offsets is cut off)" in messages
    assert any(m.startswith("truncated: chunk") for m in messages)
    assert header_end < len(data) and all(m.startswith("truncated: ") for m in messages)
    assert all(np.array_equal(read_exr(good)[k], v) for k, v in _channels(1, (50, 20)).items())


@pytest.mark.parametrize("content", [b"", b"P", b"hello, not an image\n" * 20, b"\x89PNG\r\n\x1a\n" + bytes(64),
                                     b"v/1"])
def test_a_file_that_is_not_an_exr_is_refused(tmp_path, capfd, content):
    path = tmp_path / "x.exr"
    path.write_bytes(content)
    reason = "truncated" if b"\x76\x2f\x31\x01".startswith(content) else "not-exr"
    text = _refused(path, reason, capfd)
    assert "not a readable EXR file" in text


def test_a_damaged_file_is_refused(tmp_path, capfd):
    good = tmp_path / "good.exr"
    write_exr(good, _channels(2, (64, 32)))
    data = bytearray(good.read_bytes())
    bad = tmp_path / "bad.exr"
    # a byte inside the compressed data of a chunk, near the end of the file
    data[-40] ^= 0x5A
    bad.write_bytes(bytes(data))
    assert "damaged" in _refused(bad, "damaged", capfd)
    # every single bit flipped in the header and chunk table, and a sample of the rest
    data = good.read_bytes()
    rng = np.random.default_rng(0)
    places = list(range(400)) + sorted(rng.choice(np.arange(400, len(data)), 200, replace=False).tolist())
    for i in places:
        for bit in (0, 3, 7):
            flipped = bytearray(data)
            flipped[i] ^= 1 << bit
            bad.write_bytes(bytes(flipped))
            capfd.readouterr()
            try:
                read_exr(bad)
            except ExrError as e:
                _one_line(e, bad, e.reason)
                assert e.reason in ("not-exr", "truncated", "damaged"), (i, bit, str(e))
            assert capfd.readouterr() == ("", ""), (i, bit)


def test_a_missing_channel_is_named(tmp_path, capfd):
    path = tmp_path / "x.exr"
    write_exr(path, _channels(3))
    got = read_exr(path, ["b.G", "a"])
    assert list(got) == ["b.G", "a"]
    text = _refused(path, "missing-channel", capfd, channels=["a", "valid"])
    assert text == f"{path}: missing channel 'valid'"


def test_missing_files_and_folders_are_refused(tmp_path, capfd):
    assert _refused(tmp_path / "none.exr", "not-found", capfd) == f"{tmp_path / 'none.exr'}: file not found"
    (tmp_path / "dir.exr").mkdir()
    assert "is a folder" in _refused(tmp_path / "dir.exr", "folder", capfd)


def test_a_write_the_file_system_refuses_is_one_line_and_an_os_error(tmp_path, capfd):
    capfd.readouterr()
    for path, code in ((tmp_path / "no" / "such" / "x.exr", errno.ENOENT), (tmp_path, errno.EISDIR)):
        with pytest.raises(ExrWriteError) as info:
            write_exr(path, _channels(4))
        e = info.value
        assert isinstance(e, OSError) and e.errno == code and e.filename == str(path)
        text = _one_line(e, path, "unwritable")
        assert text == f"{path}: cannot write the EXR file ({os.strerror(code)})"
    assert capfd.readouterr() == ("", "")
    assert not (tmp_path / "no").exists()


def test_openexrs_pool_follows_the_thread_budget_and_an_explicit_size(tmp_path):
    import OpenEXR

    from thinfilm.core.exr import MAX_EXR_THREADS, set_exr_threads
    from thinfilm.core.threads import cores, set_thread_budget

    def pool_after_a_write():
        write_exr(tmp_path / "x.exr", _channels(6))
        return OpenEXR.global_thread_count()

    full = min(cores(), MAX_EXR_THREADS)
    try:
        set_thread_budget(1)
        assert pool_after_a_write() == 0  # one thread: no pool
        set_thread_budget(None)
        assert pool_after_a_write() == (full if full > 1 else 0)
        set_exr_threads(3)
        set_thread_budget(1)
        assert pool_after_a_write() == 3  # an explicit size stays until set_exr_threads(None)
        set_exr_threads(None)
        assert pool_after_a_write() == 0
    finally:
        set_exr_threads(None)
        set_thread_budget(None)
    assert pool_after_a_write() == (full if full > 1 else 0)


def test_errors_survive_pickling(tmp_path):
    """Errors cross processes (Dask workers) whole."""
    import pickle

    with pytest.raises(ExrError) as read_error:
        read_exr(tmp_path / "none.exr")
    with pytest.raises(ExrWriteError) as write_error:
        write_exr(tmp_path / "no" / "x.exr", _channels(7))
    for e in (read_error.value, write_error.value):
        back = pickle.loads(pickle.dumps(e))
        assert type(back) is type(e) and str(back) == str(e) and back.reason == e.reason and back.path == e.path
    back = pickle.loads(pickle.dumps(write_error.value))
    assert (back.errno, back.strerror, back.filename) == (errno.ENOENT, os.strerror(errno.ENOENT),
                                                          str(tmp_path / "no" / "x.exr"))
