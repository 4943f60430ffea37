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
    [("model.bogus=1", "unknown"), ("model.width=-4", "positive"), ("model.num_heads=4", "divide")],
)
def test_bad_train_config(override, word, tmp_path, capsys):
    out = tmp_path / "run"
    extra = ["model.width=30"] if "heads" in override else []
    assert main(["train", "--out", str(out), *extra, override]) != 0
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and word in err.splitlines()[-1], err
    assert not (out / "model.safetensors").exists()
