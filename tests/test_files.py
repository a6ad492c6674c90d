"""codec.files' safe writer: devices, FIFOs and links are respected, permissions kept,
errors name the user's path, and no temporary file is ever left behind."""

from __future__ import annotations

import errno
import os
import stat
import threading

import numpy as np
import pytest

import codec
from codec import files
from codec.files import WriteError, atomic_open, atomic_write

IMAGE = np.arange(400, dtype=np.uint8).reshape(20, 20)


def device(tmp_path, name: str, minor: int) -> str:
    """A private copy of /dev/null (minor 3) or /dev/full (minor 7) where we may make
    one (root), so that a broken writer cannot damage the real one; else the real one
    (which an unprivileged broken writer cannot replace either, and fails on)."""
    path = tmp_path / name
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    except PermissionError:
        return f"/dev/{name}"
    return str(path)


def test_a_character_device_is_written_through_not_replaced(tmp_path):
    null = device(tmp_path, "null", 3)
    codec.write(null, IMAGE)
    assert stat.S_ISCHR(os.stat(null).st_mode)
    assert sorted(os.listdir(tmp_path)) == (["null"] if null.startswith(str(tmp_path)) else [])


def test_a_full_device_is_an_error_naming_it(tmp_path):
    full = device(tmp_path, "full", 7)
    with pytest.raises(WriteError, match=f"cannot write {full}: No space left on device") as err:
        codec.write(full, IMAGE)
    assert isinstance(err.value, codec.ATMError) and isinstance(err.value, OSError)
    assert err.value.errno == errno.ENOSPC
    assert stat.S_ISCHR(os.stat(full).st_mode)


def test_a_fifo_is_written_through(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    atomic_write(fifo, b"through the pipe")
    reader.join(10)
    assert got == [b"through the pipe"]
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


def test_a_symlink_keeps_pointing_at_its_replaced_target(tmp_path):
    (tmp_path / "real").mkdir()
    target = tmp_path / "real" / "x.atm"
    target.write_bytes(b"old")
    link = tmp_path / "link.atm"
    link.symlink_to(target)
    codec.write(link, IMAGE)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_bytes() == codec.encode(IMAGE)
    # a dangling link gets its target made
    dangling = tmp_path / "dangling.atm"
    dangling.symlink_to(tmp_path / "real" / "new.atm")
    atomic_write(dangling, b"new")
    assert dangling.is_symlink() and (tmp_path / "real" / "new.atm").read_bytes() == b"new"
    assert sorted(os.listdir(tmp_path / "real")) == ["new.atm", "x.atm"]


def test_a_replaced_file_keeps_its_permissions_and_a_new_one_follows_the_umask(tmp_path):
    kept = tmp_path / "kept.atm"
    kept.write_bytes(b"old")
    os.chmod(kept, 0o640)
    codec.write(kept, IMAGE)
    assert stat.S_IMODE(os.stat(kept).st_mode) == 0o640
    umask = os.umask(0o027)
    try:
        atomic_write(tmp_path / "new.bin", b"x")
    finally:
        os.umask(umask)
    assert stat.S_IMODE(os.stat(tmp_path / "new.bin").st_mode) == 0o640


@pytest.mark.parametrize("unnamed", [files.UNNAMED, None], ids=["O_TMPFILE", "named"])
def test_errors_name_the_users_path_and_leave_nothing(tmp_path, monkeypatch, unnamed):
    monkeypatch.setattr(files, "UNNAMED", unnamed)
    missing = tmp_path / "missing" / "x.atm"
    with pytest.raises(WriteError, match=f"cannot write {missing}: the folder {missing.parent} does not exist"):
        codec.write(missing, IMAGE)
    with pytest.raises(WriteError, match="output file name is empty"):
        atomic_write("", b"x")
    with pytest.raises(WriteError, match="cannot end with /"):
        atomic_write(f"{tmp_path}/", b"x")
    with pytest.raises(WriteError, match="it is a directory"):
        atomic_write(tmp_path, b"x")
    (tmp_path / "x.atm").write_bytes(b"precious")
    with pytest.raises(RuntimeError):
        with atomic_open(tmp_path / "x.atm") as f:
            f.write(b"partial")
            raise RuntimeError("the encoder failed")
    assert (tmp_path / "x.atm").read_bytes() == b"precious"
    assert sorted(os.listdir(tmp_path)) == ["x.atm"]


@pytest.mark.skipif(files.UNNAMED is None, reason="no O_TMPFILE here")
def test_an_unfinished_output_has_no_name_at_all(tmp_path):
    """What SIGKILL leaves is what exists during the write: with O_TMPFILE, nothing."""
    with atomic_open(tmp_path / "x.atm") as f:
        f.write(b"data" * 1000)
        assert os.listdir(tmp_path) == []
    assert (tmp_path / "x.atm").read_bytes() == b"data" * 1000


def test_where_the_unnamed_file_cannot_be_named_it_is_copied(tmp_path, monkeypatch):
    def refuse(fd, dst):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(files, "_link", refuse)
    (tmp_path / "x.atm").write_bytes(b"old")
    os.chmod(tmp_path / "x.atm", 0o600)
    atomic_write(tmp_path / "x.atm", b"new" * 500_000)
    assert (tmp_path / "x.atm").read_bytes() == b"new" * 500_000
    assert stat.S_IMODE(os.stat(tmp_path / "x.atm").st_mode) == 0o600
    assert os.listdir(tmp_path) == ["x.atm"]


def test_write_refuses_an_image_name_unless_forced(tmp_path):
    with pytest.raises(codec.OptionError, match=r"image extension \.png.*name ending in \.atm"):
        codec.write(tmp_path / "x.png", IMAGE)
    assert os.listdir(tmp_path) == []
    codec.write(tmp_path / "x.PNG", IMAGE, force=True)
    codec.write(tmp_path / "x.bin", IMAGE)  # not an image name: nothing to mistake
    assert (tmp_path / "x.PNG").read_bytes() == codec.encode(IMAGE)
