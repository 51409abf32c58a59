"""Output checks and atomic writes (claravid.infra.files)."""

import os
import stat

import pytest

from claravid.infra.cli import UsageError
from claravid.infra.files import (
    atomic_save,
    atomic_write_text,
    check_output_dir,
    check_output_file,
)


def test_check_output_file(tmp_path):
    with pytest.raises(UsageError, match="is a folder"):
        check_output_file(tmp_path)
    blocker = tmp_path / "afile"
    blocker.write_text("x")
    with pytest.raises(UsageError, match="is a file, not a folder"):
        check_output_file(blocker / "sub" / "out.json")
    with pytest.raises(UsageError, match="--overwrite"):
        check_output_file(blocker, overwrite=False)
    assert check_output_file(tmp_path / "new" / "out.json") == tmp_path / "new" / "out.json"
    assert not (tmp_path / "new").exists()  # checking creates nothing
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(UsageError, match="not writable"):
            check_output_file(locked / "out.json")


def test_check_output_dir_refuses_a_foreign_folder(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "precious.txt").write_text("data")
    with pytest.raises(UsageError, match="not written by this tool"):
        check_output_dir(theirs, marker="report.json")
    assert check_output_dir(theirs, marker="report.json", overwrite=True) == theirs
    ours = tmp_path / "ours"
    ours.mkdir()
    (ours / "report.json").write_text("{}")
    assert check_output_dir(ours, marker="report.json") == ours
    (tmp_path / "empty").mkdir()
    assert check_output_dir(tmp_path / "empty", marker="report.json")
    with pytest.raises(UsageError, match="is a file"):
        check_output_dir(theirs / "precious.txt", marker="report.json")


def test_atomic_save_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = atomic_write_text(tmp_path / "r.json", "old")

    def broken(tmp):
        tmp.write_text("half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        atomic_save(target, broken)
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]  # no temp left behind


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_atomic_writes_respect_the_umask(umask, mode, tmp_path):
    from claravid.models import build_model, save_checkpoint

    old = os.umask(umask)
    try:
        text = atomic_write_text(tmp_path / "report.json", "{}")
        model = build_model("dinov2_vits14", 2, backbone_kwargs={"embed_dim": 8, "depth": 4,
                            "num_heads": 1}, layers=[0, 1, 2, 3], features=4,
                            out_channels=[4, 4, 4, 4])  # fmt: skip
        ckpt = save_checkpoint(model, tmp_path / "m.pt")
    finally:
        os.umask(old)
    # What open(path, "w") gives: 0666 minus the umask, as stat shows it.
    assert stat.S_IMODE(text.stat().st_mode) == mode
    assert stat.S_IMODE(ckpt.stat().st_mode) == mode
