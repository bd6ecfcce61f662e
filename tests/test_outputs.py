"""The output-folder API (thinfilm.core.outputs): the replacement rule, the marker, the lock,
stale temporaries, outputs written in place part by part, and output files."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from thinfilm.core import outputs
from thinfilm.core.errors import UserError
from thinfilm.core.outputs import (MARKER, TEMP_MARKER, atomic_output_dir, atomic_output_files, check_output_dir,
                                   check_output_files, clean_stale_temporaries, open_output_dir, output_lock,
                                   read_marker)


def _write(folder, files):
    for name, text in files.items():
        p = Path(folder) / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def _names(folder):
    return sorted(p.name for p in Path(folder).iterdir())


def _dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_marker_lists_what_was_written_and_is_deterministic(tmp_path):
    for name in ("a", "b"):
        with atomic_output_dir(tmp_path / name, command="generate") as tmp:
            _write(tmp, {"meta.json": "{}", "sub/x.exr": "x"})
    assert read_marker(tmp_path / "a")["entries"] == ["meta.json", "sub/", "sub/x.exr"]
    assert read_marker(tmp_path / "a")["command"] == "generate"
    assert (tmp_path / "a" / MARKER).read_bytes() == (tmp_path / "b" / MARKER).read_bytes()


def test_replaces_its_own_output_and_nothing_else(tmp_path):
    out = tmp_path / "out"
    with atomic_output_dir(out, command="reconstruct") as tmp:
        _write(tmp, {"estimate.json": "1", "deep/er/file": "1"})
    with atomic_output_dir(out, command="reconstruct") as tmp:
        _write(tmp, {"estimate.json": "2"})
    assert (out / "estimate.json").read_text() == "2" and not (out / "deep").exists()
    # another command's output, a file a person added anywhere in it, an unmarked folder
    with pytest.raises(UserError, match="holds the output of 'thinfilm reconstruct', not of 'thinfilm evaluate'"):
        check_output_dir(out, command="evaluate")
    _write(out, {"deep/notes.txt": "mine"})
    with pytest.raises(UserError, match="holds 'deep' and 1 more, which thinfilm did not write"):
        check_output_dir(out, command="reconstruct")
    (out / MARKER).write_text("not json")
    with pytest.raises(UserError, match="not a thinfilm output"):
        check_output_dir(out, command="reconstruct")
    assert (out / "deep" / "notes.txt").read_text() == "mine"


@pytest.mark.parametrize("out, message", [
    ("data", "is the input"), ("data/sub", "lies inside the input"), (".", "contains the input"),
    ("link", "is the input"), ("link/x", "lies inside the input"), ("spec-folder", "contains the input"),
])
def test_never_writes_over_into_or_around_an_input(tmp_path, monkeypatch, out, message):
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, {"data/meta.json": "{}", "spec-folder/s.toml": ""})
    os.symlink(tmp_path / "data", tmp_path / "link")
    with pytest.raises(UserError, match=message):
        with atomic_output_dir(out, command="x", inputs=["data", "spec-folder/s.toml"]):
            pass


def test_a_failure_leaves_the_file_system_as_it_was(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_output_dir(tmp_path / "new" / "deeper" / "out", command="x") as tmp:
            _write(tmp, {"half.exr": "x"})
            raise RuntimeError("interrupted")
    assert _names(tmp_path) == []


def test_permissions_follow_the_umask(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic_output_dir(tmp_path / "out", command="x") as tmp:
            _write(tmp, {"f": "x"})
    finally:
        os.umask(old)
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o750
    assert (tmp_path / "out" / MARKER).stat().st_mode & 0o777 == 0o640


def test_swap_without_renameat2_falls_back_to_two_renames(tmp_path, monkeypatch):
    with atomic_output_dir(tmp_path / "out", command="x") as tmp:
        _write(tmp, {"f": "1"})
    monkeypatch.setattr(outputs, "exchange_paths", lambda a, b: False)
    with atomic_output_dir(tmp_path / "out", command="x") as tmp:
        _write(tmp, {"f": "2"})
    assert (tmp_path / "out" / "f").read_text() == "2" and _names(tmp_path) == ["out"]


def test_the_lock_admits_one_writer_and_is_removed_after(tmp_path):
    out = tmp_path / "out"
    with output_lock(out):
        assert (tmp_path / ".out.lock").read_text().split() == ["thinfilm-lock/1", str(os.getpid()), outputs.host_tag()]
        with pytest.raises(UserError, match=f"another thinfilm command \\(process {os.getpid()}\\)"):
            with atomic_output_dir(out, command="x"):
                pass
    assert _names(tmp_path) == []
    with atomic_output_dir(out, command="x"):
        pass


def _record(folder, pid, host):
    """The record a temporary folder of ours holds (TEMP_MARKER)."""
    _write(folder, {TEMP_MARKER: json.dumps({"format": "thinfilm-temporary/1", "pid": pid, "host": host})})


def test_stale_temporaries_only_ours_only_dead(tmp_path):
    host, dead = outputs.host_tag(), _dead_pid()
    stale = tmp_path / f".out.tmp-{dead}@{host}-abcd1234"
    alive = tmp_path / f".out.tmp-{os.getpid()}@{host}-abcd1234"
    other_host = tmp_path / f".out.tmp-{dead}@elsewhere-abcd1234"
    for p, pid, h in ((stale, dead, host), (alive, os.getpid(), host), (other_host, dead, "elsewhere")):
        _write(p, {"x.exr": "x"})
        _record(p, pid, h)
    # named like ours but without our record, or with a record of another process: not ours
    unmarked = tmp_path / f".out.tmp-{dead}@{host}-abcd5678"
    mismatched = tmp_path / f".out.tmp-{dead}@{host}-abcd9999"
    _write(unmarked, {"thesis.tex": "mine"})
    _write(mismatched, {"x": "x"})
    _record(mismatched, dead + 1, host)
    not_ours = tmp_path / ".out.tmp-xyz"
    _write(not_ours, {"x.exr": "x"})
    stale_file = tmp_path / f".img.exr.tmp-{dead}@{host}-abcd1234.exr"
    stale_file.write_text("a file cannot hold our record")
    link = tmp_path / f".lnk.tmp-{dead}@{host}-abcd1234"
    os.symlink(stale, link)
    removed = clean_stale_temporaries(tmp_path)
    assert removed == [stale]
    assert _names(tmp_path) == sorted(p.name for p in (alive, other_host, not_ours, unmarked, mismatched,
                                                      stale_file, link))
    assert (unmarked / "thesis.tex").read_text() == "mine"


def test_stale_locks_only_ours_only_dead_only_unheld(tmp_path):
    host, dead = outputs.host_tag(), _dead_pid()
    out = tmp_path / "out"
    with atomic_output_dir(out, command="example") as tmp:
        _write(tmp, {"a.txt": "1"})
    stale = out / ".part.lock"
    stale.write_text(f"thinfilm-lock/1 {dead} {host}\n")
    check_output_dir(out, command="example")  # a killed command's lock is not someone else's file
    live = out / ".live.lock"
    live.write_text(f"thinfilm-lock/1 {os.getpid()} {host}\n")
    elsewhere = out / ".far.lock"
    elsewhere.write_text(f"thinfilm-lock/1 {dead} elsewhere\n")
    mine = out / ".notes.lock"
    mine.write_text("my own notes")
    # a live process's lock, another host's, a person's file of that name: not stale
    with pytest.raises(UserError, match=r"holds '\.far\.lock' and 2 more"):
        check_output_dir(out, command="example")
    assert clean_stale_temporaries(out) == [stale]
    assert _names(out) == sorted([MARKER, "a.txt", live.name, elsewhere.name, mine.name])


def test_parts_staged_for_another_process_are_listed_adopted_or_removed(tmp_path):
    out = tmp_path / "out"
    with open_output_dir(out, command="example") as folder:
        a, b = folder.staging_path("tasks/c1/a"), folder.staging_path("tasks/c1/b")
        # the folders that hold them are the output's before anything is written there
        assert {"tasks/", "tasks/c1/"} <= set(read_marker(out)["entries"]) and (out / "tasks" / "c1").is_dir()
        for staged in (a, b):
            with atomic_output_dir(staged, command="part") as tmp:
                _write(tmp, {"r.txt": staged.name})
        folder.adopt("tasks/c1/a", a)
    # b was written but not adopted (an interrupted run): removed, and a holds no record
    assert _names(out / "tasks" / "c1") == ["a"] and _names(out / "tasks" / "c1" / "a") == [MARKER, "r.txt"]
    assert f"tasks/c1/a/{TEMP_MARKER}" not in read_marker(out)["entries"]
    check_output_dir(out, command="example")


def test_an_old_output_moved_aside_by_a_killed_swap_is_moved_back(tmp_path):
    holder = tmp_path / f".out.tmp-{_dead_pid()}@{outputs.host_tag()}-abcd1234"
    with atomic_output_dir(holder / "out.old", command="x") as tmp:
        _write(tmp, {"meta.json": "{}"})
    _record(holder, int(holder.name.split("-")[1].split("@")[0]), outputs.host_tag())
    clean_stale_temporaries(tmp_path)
    assert _names(tmp_path) == ["out"] and (tmp_path / "out" / "meta.json").is_file()


def test_nested_outputs_inside_a_temporary_folder(tmp_path):
    with atomic_output_dir(tmp_path / "bench", command="benchmark") as tmp:
        with atomic_output_dir(tmp / "datasets" / "hemisphere", command="generate") as inner:
            _write(inner, {"meta.json": "{}"})
        _write(tmp, {"results.json": "{}"})
    assert read_marker(tmp_path / "bench" / "datasets" / "hemisphere")["command"] == "generate"
    assert "datasets/hemisphere/.thinfilm-output" in read_marker(tmp_path / "bench")["entries"]
    with atomic_output_dir(tmp_path / "bench", command="benchmark") as tmp:  # replaceable as a whole
        pass


def test_an_output_written_in_place_part_by_part_resumes(tmp_path):
    out = tmp_path / "bench"
    with open_output_dir(out, command="benchmark") as folder:
        with folder.atomic_child("tasks/0000") as tmp:
            _write(tmp, {"metrics.json": "{}"})
        with pytest.raises(RuntimeError):
            with folder.atomic_child("tasks/0001") as tmp:
                _write(tmp, {"metrics.json": "half"})
                raise RuntimeError("killed")
    assert _names(out / "tasks") == ["0000"]
    with open_output_dir(out, command="benchmark") as folder:
        assert folder.has("tasks/0000") and not folder.has("tasks/0001")
        with folder.atomic_child("tasks/0001") as tmp:
            _write(tmp, {"metrics.json": "{}"})
        with folder.atomic_child("tasks/0000") as tmp:  # redo one part: replaced whole
            _write(tmp, {"metrics.json": "[]"})
        folder.write_text("results.json", json.dumps({"n": 2}))
    assert (out / "tasks" / "0000" / "metrics.json").read_text() == "[]"
    assert set(read_marker(out)["entries"]) == {"tasks/", "tasks/0000/", "tasks/0000/metrics.json", "tasks/0001/",
                                                "tasks/0001/metrics.json", "results.json"}
    check_output_dir(out, command="benchmark")  # all of it is ours: replaceable by a fresh run
    _write(out, {"tasks/0001/mine.txt": "x"})  # a person's file in it: no longer ours to write in
    with pytest.raises(UserError, match="holds 'tasks/0001/mine.txt'"):
        with open_output_dir(out, command="benchmark"):
            pass
    assert (out / "tasks/0001/mine.txt").read_text() == "x"
    with pytest.raises(UserError, match="not a thinfilm output"):
        with open_output_dir(tmp_path, command="benchmark"):
            pass


def test_a_fresh_in_place_output_that_fails_at_once_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with open_output_dir(tmp_path / "a" / "bench", command="benchmark"):
            raise RuntimeError("bad input")
    assert _names(tmp_path) == []


def test_output_files_overwrite_only_when_asked_and_never_an_input(tmp_path):
    exr, png = tmp_path / "img.exr", tmp_path / "img.png"
    with atomic_output_files([exr, png]) as tmp:
        for t in tmp.values():
            t.write_text("1")
    with pytest.raises(UserError, match="file exists; pass --overwrite"):
        check_output_files([exr, png])
    with atomic_output_files([exr, png], overwrite=True) as tmp:
        for t in tmp.values():
            t.write_text("2")
    assert exr.read_text() == "2" and _names(tmp_path) == ["img.exr", "img.png"]
    with pytest.raises(UserError, match="is the input"):
        check_output_files([png], overwrite=True, inputs=[png])
    with pytest.raises(RuntimeError):
        with atomic_output_files([tmp_path / "x.exr"]) as tmp:
            raise RuntimeError("render failed")
    assert _names(tmp_path) == ["img.exr", "img.png"]


@pytest.mark.parametrize("exchange", [True, False])
def test_an_old_output_that_cannot_be_removed_whole_stays_and_the_new_one_is_kept_beside(tmp_path, monkeypatch,
                                                                                       exchange):
    out = tmp_path / "out"
    with atomic_output_dir(out, command="x") as tmp:
        _write(tmp, {"a/b/keep.txt": "old", "top.txt": "old"})
    before = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    if not exchange:
        monkeypatch.setattr(outputs, "exchange_paths", lambda a, b: False)
    move = outputs.move_entry

    def immutable(src, dst):
        if os.path.basename(src) == "keep.txt":
            raise PermissionError(1, "Operation not permitted", src)
        move(src, dst)

    monkeypatch.setattr(outputs, "move_entry", immutable)
    with pytest.raises(UserError, match="cannot remove the old output .*'a/b/keep.txt'.*kept as it was, and the "
                                        "new output is at .*out.new"):
        with atomic_output_dir(out, command="x") as tmp:
            _write(tmp, {"top.txt": "new"})
    assert {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert (tmp_path / "out.new" / "top.txt").read_text() == "new"
    assert _names(tmp_path) == ["out", "out.new"]


def test_output_files_are_never_written_through_a_link(tmp_path):
    (tmp_path / "thesis.txt").write_text("mine")
    os.symlink(tmp_path / "thesis.txt", tmp_path / "img.exr")
    with pytest.raises(UserError, match="is a symbolic link"):
        with atomic_output_files([tmp_path / "img.exr"], overwrite=True) as tmp:
            pass
    assert (tmp_path / "thesis.txt").read_text() == "mine"
