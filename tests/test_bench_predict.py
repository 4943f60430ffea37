"""`mop bench predict`: each mode's RMSE is that of its predictions of the seeded records; one-line errors."""

import json

import pytest
import torch

from mop.cli import main
from mop.runs import load_config, load_predictor
from mop.systems import generator, make_family


def test_bench_predict_reports_each_modes_rmse(tiny_run, capsys, one_thread):
    argv = ["bench", "predict", "--model", str(tiny_run), "--records", "3", "--steps", "25"]
    assert main([*argv, "--sliding-records", "2", "--seed", "4", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    traj = make_family(load_config(tiny_run).system).generate(3, 25, generator=generator(4))
    C = r["context"]
    assert C == 10 and r["sliding"]["records"] == 2 and r["window"]["records"] == 3
    for mode, records in (("window", 3), ("stream", 3), ("sliding", 2)):
        part = traj.select(slice(0, records))
        yhat = load_predictor(tiny_run, mode=mode).predict(part)
        rmse = float((yhat[:, C + 1 :] - part.y[:, C + 1 :]).double().pow(2).mean().sqrt())
        assert r[mode]["rmse_beyond"] == pytest.approx(rmse, rel=1e-6), mode
        assert r[mode]["seconds"] > 0
    assert r["stream"]["rmse_beyond"] != pytest.approx(r["window"]["rmse_beyond"], rel=1e-3)
    ratio = r["window_on_sliding_records"]["rmse_beyond"] / r["sliding"]["rmse_beyond"]
    assert r["window_over_sliding_rmse_beyond"] == pytest.approx(ratio)
    assert torch.get_num_threads() == r["torch_threads"]


@pytest.mark.parametrize(("flag", "value"), [("--records", "0"), ("--sliding-records", "200")])
def test_bench_predict_bad_flags_one_line(flag, value, capsys):
    assert main(["bench", "predict", flag, value]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sliding-records" in err[0]
