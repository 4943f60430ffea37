"""The out-of-distribution warning of a trained run: inputs far outside the training inputs are flagged once,
in one line, and in-distribution inputs are not."""

import warnings

import numpy as np
import pytest
import torch

from mop.cli import main
from mop.config import SystemConfig
from mop.errors import MopWarning
from mop.runs import load_predictor
from mop.systems import generator, make_family
from mop.systems.base import Trajectories


def _mop_warnings(predictor, traj):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        predictor.predict(traj)
        predictor.predict(traj)
    return [w for w in caught if issubclass(w.category, MopWarning)]


def test_in_distribution_inputs_are_not_flagged(tiny_run):
    family = make_family(SystemConfig(family="linear", output_dim=2, state_dim=2))
    traj = family.generate(50, 40, generator=generator(5))  # longer than the context, same systems
    assert _mop_warnings(load_predictor(tiny_run), traj) == []


def test_a_random_walk_is_flagged_once(tiny_run):
    y = torch.randn(2, 501, 2, generator=torch.Generator().manual_seed(0)).cumsum(1)
    caught = _mop_warnings(load_predictor(tiny_run), Trajectories(y=y))
    assert len(caught) == 1 and "far outside what" in str(caught[0].message)


def test_the_training_statistics_are_those_of_the_validation_inputs(tiny_run):
    import json

    stats = json.loads((tiny_run / "inputs.json").read_text())
    assert len(stats["mean"]) == len(stats["std"]) == 2 and all(s > 0 for s in stats["std"])


@pytest.mark.usefixtures("one_thread")
def test_predict_prints_the_warning_in_one_line(tiny_run, tmp_path, capsys):
    y = np.random.default_rng(0).normal(size=(1, 301, 2)).cumsum(1) * 5
    np.savez(tmp_path / "walk.npz", y=y)
    assert main(["predict", str(tiny_run), str(tmp_path / "walk.npz"), "--out", str(tmp_path / "p.npz")]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("mop: warning: the data lie far outside") and len(err.splitlines()) == 1, err
