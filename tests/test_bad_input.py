import subprocess
import sys

import numpy as np
import pytest

from mop.cli import main


def _run_fails(argv, capsys, out, word):
    assert main(argv) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and word in err, err
    assert not out.exists() and not list(out.parent.glob(f".{out.name}*"))


CASES = {
    "nan": ("d.npz", lambda p: np.savez(p, y=np.full((1, 5, 2), np.nan)), "NaN"),
    "inf": ("d.npz", lambda p: np.savez(p, y=np.full((1, 5, 2), -np.inf)), "Inf"),
    "huge": ("d.npz", lambda p: np.savez(p, y=np.full((1, 5, 2), 1e30)), "values up to"),
    "columns": ("d.npz", lambda p: np.savez(p, y=np.zeros((1, 5, 3))), "output_dim"),
    "empty": ("d.csv", lambda p: p.write_text(""), "empty"),
    "one_row": ("d.csv", lambda p: p.write_text("trajectory,t,y0,y1\na,0,1,2\n"), "one row"),
    "malformed": ("d.csv", lambda p: p.write_text("trajectory,t,y0,y1\na,0,1\n"), "columns"),
}


@pytest.mark.parametrize("case", CASES)
def test_bad_data(case, tiny_run, tmp_path, capsys):
    name, make, word = CASES[case]
    make(tmp_path / name)
    out = tmp_path / "p.csv"
    _run_fails(["predict", str(tiny_run), str(tmp_path / name), "--out", str(out)], capsys, out, word)


def test_failed_predict_keeps_the_previous_output(tiny_run, tmp_path, capsys):
    np.savez(tmp_path / "d.npz", y=np.full((1, 5, 2), np.nan))
    out = tmp_path / "p.csv"
    out.write_text("an earlier result\n")
    assert main(["predict", str(tiny_run), str(tmp_path / "d.npz"), "--out", str(out)]) != 0
    assert out.read_text() == "an earlier result\n" and "NaN" in capsys.readouterr().err


def test_missing_run_dir(tmp_path, capsys):
    np.savez(tmp_path / "d.npz", y=np.zeros((1, 5, 2)))
    out = tmp_path / "p.csv"
    _run_fails(
        ["predict", str(tmp_path / "nope"), str(tmp_path / "d.npz"), "--out", str(out)],
        capsys,
        out,
        "does not exist",
    )


def test_unstable_system_subprocess(tmp_path):
    out = tmp_path / "s.npz"
    r = subprocess.run(
        [sys.executable, "-m", "mop.cli", "simulate", "linear", "spectral_radius=1.2", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert r.returncode != 0 and "Traceback" not in r.stderr and "spectral" in r.stderr, r.stderr
    assert not out.exists()


@pytest.mark.parametrize("kind", ["truncated", "pickle"])
def test_bad_weights(kind, tiny_run, tmp_path, capsys):
    import pickle
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    w = run / "model.safetensors"
    if kind == "truncated":
        w.write_bytes(w.read_bytes()[:300])
    else:
        w.write_bytes(pickle.dumps({"weight": np.zeros(3)}))
    np.savez(tmp_path / "d.npz", y=np.zeros((1, 5, 2)))
    out = tmp_path / "p.csv"
    word = "safetensors" if kind == "truncated" else "pickle"
    _run_fails(["predict", str(run), str(tmp_path / "d.npz"), "--out", str(out)], capsys, out, word)


@pytest.mark.parametrize(
    "override,word",
    [
        ("model.bogus=1", "unknown"),
        ("model.width=-4", "positive"),
        ("model.num_heads=4", "divide"),
        ("train.lr=abc", "train.lr must be a number, got 'abc'"),
        ("model.width=6.5", "model.width must be an integer, got 6.5"),
        ("system.noise_var_w=[1]", "system.noise_var_w must be a number"),
    ],
)
def test_bad_train_config(override, word, tmp_path, capsys):
    out = tmp_path / "run"
    extra = ["model.width=30"] if "heads" in override else []
    assert main(["train", "--out", str(out), *extra, override]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and word in err.splitlines()[-1], err
    assert not (out / "model.safetensors").exists()


# ----------------------------------------------------------------------------- one error path for OS errors


def _one_line(capsys, *words):
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert all(w in err for w in words), err
    return err


def _no_temporaries(directory):
    return [p.name for p in directory.rglob(".*.tmp*")]


@pytest.fixture
def full_disk(monkeypatch):
    """Every atomic write fails as on a full disk (flushing the temporary raises ENOSPC)."""
    import errno
    import os

    import mop.atomic

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(mop.atomic.os, "fsync", full)


def test_full_disk_simulate(tmp_path, capsys, full_disk):
    out = tmp_path / "s.npz"
    out.write_bytes(b"previous")
    assert main(["simulate", "linear", "--systems", "3", "--horizon", "5", "--out", str(out)]) == 2
    _one_line(capsys, "no space left on the device writing", str(out))
    assert out.read_bytes() == b"previous" and not _no_temporaries(tmp_path)


def test_full_disk_predict(tiny_run, tmp_path, capsys, full_disk):
    np.savez(tmp_path / "d.npz", y=np.zeros((1, 5, 2)))
    out = tmp_path / "p.csv"
    assert main(["predict", str(tiny_run), str(tmp_path / "d.npz"), "--out", str(out)]) == 2
    _one_line(capsys, "no space left on the device writing", str(out))
    assert not out.exists() and not _no_temporaries(tmp_path)


def test_full_disk_train_keeps_the_run(tiny_run, tmp_path, capsys, monkeypatch):
    """ENOSPC inside the safetensors writer (a SafetensorError carrying the OS code) reads as the OSError."""
    import shutil

    from safetensors import SafetensorError

    import mop.checkpoint

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    (run / "done.json").unlink()
    (run / "checkpoint.safetensors").unlink()  # trains from step 0 to its first checkpoint, which fails
    before = (run / "model.safetensors").read_bytes()
    message = 'Error while serializing: IoError(Os { code: 28, kind: StorageFull, message: "No space left" })'

    def full(*args, **kwargs):
        raise SafetensorError(message)

    monkeypatch.setattr(mop.checkpoint, "save_file", full)
    cfg = str(run / "config.json")
    assert main(["train", cfg, "--out", str(run), "--no-progress"]) == 2
    _one_line(capsys, "no space left on the device writing", str(run / "checkpoint.safetensors"))
    assert (run / "model.safetensors").read_bytes() == before and not _no_temporaries(run)


@pytest.mark.parametrize(
    "code,words",
    [("EACCES", "permission denied"), ("EROFS", "read-only file system"), ("EDQUOT", "quota")],
)
def test_os_errors_name_path_and_fix(code, words, tmp_path, capsys, monkeypatch):
    import errno
    import os

    import mop.atomic

    def refuse(*args, **kwargs):
        number = getattr(errno, code)
        raise OSError(number, os.strerror(number), str(tmp_path))

    monkeypatch.setattr(mop.atomic.tempfile, "mkstemp", refuse)
    out = tmp_path / "s.npz"
    assert main(["simulate", "linear", "--systems", "2", "--horizon", "3", "--out", str(out)]) == 2
    _one_line(capsys, words, str(tmp_path))


@pytest.mark.parametrize(
    "error",
    [MemoryError(), RuntimeError("[enforce fail at alloc_cpu.cpp:117] DefaultCPUAllocator: can't allocate")],
)
def test_out_of_memory_is_one_line(error, tmp_path, capsys, monkeypatch):
    from mop.systems.base import SystemFamily

    def oom(*args, **kwargs):
        raise error

    monkeypatch.setattr(SystemFamily, "generate", oom)
    assert main(["simulate", "linear", "--systems", "2", "--out", str(tmp_path / "s.npz")]) == 2
    _one_line(capsys, "out of memory")


def test_other_runtime_errors_still_raise(tmp_path, monkeypatch):
    """A bug is not dressed up as a user error."""
    from mop.systems.base import SystemFamily

    def bug(*args, **kwargs):
        raise RuntimeError("shape mismatch")

    monkeypatch.setattr(SystemFamily, "generate", bug)
    with pytest.raises(RuntimeError, match="shape mismatch"):
        main(["simulate", "linear", "--systems", "2", "--out", str(tmp_path / "s.npz")])


@pytest.mark.parametrize(
    "content,words",
    [
        (b"\xff\xfe\x00garbage\x80", "not valid JSON: not text"),
        (b'{"model": 5', "not valid JSON"),
        (b'{"model": 5}', "model must be a table"),
        (b"[1, 2]", "must be a mapping"),
    ],
)
def test_damaged_run_config(content, words, tiny_run, tmp_path, capsys):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    (run / "config.json").write_bytes(content)
    np.savez(tmp_path / "d.npz", y=np.zeros((1, 5, 2)))
    assert main(["predict", str(run), str(tmp_path / "d.npz"), "--out", str(tmp_path / "p.csv")]) == 2
    _one_line(capsys, words, str(run / "config.json"), "damaged")
    # training into it says the same, in one line, and leaves it as it was
    assert main(["train", "--out", str(run), "train.steps=2", "--no-progress"]) == 2
    err = _one_line(capsys, str(run))
    assert "damaged" in err or "different config" in err
    assert (run / "config.json").read_bytes() == content
