"""A run stopped before its last step says so where it is used (mop.load warns with the step it reached),
and training it again says that it resumes, and from which step."""

import warnings

import pytest

import mop
import mop.train.loop as loop
from mop.errors import MopWarning
from mop.train import train
from tests.test_train import tiny_config


class Stop(Exception):
    pass


def test_an_interrupted_run_warns_when_loaded_and_says_it_resumes(tmp_path, monkeypatch, one_thread):
    config = tiny_config(steps=8, checkpoint_every=2)
    saved = loop.save_training_state
    calls = []

    def stop_after_two(*args, **kwargs):  # the process dies right after its second checkpoint (step 4)
        saved(*args, **kwargs)
        calls.append(1)
        if len(calls) == 2:
            raise Stop

    monkeypatch.setattr(loop, "save_training_state", stop_after_two)
    with pytest.raises(Stop):
        train(config, tmp_path / "run", progress=False)
    monkeypatch.setattr(loop, "save_training_state", saved)
    with pytest.warns(MopWarning, match="unfinished: trained to step 4 of 8"):
        mop.load(tmp_path / "run")
    lines = []
    train(config, tmp_path / "run", progress=False, announce=lines.append)
    assert "resuming at step 4 of 8" in lines[0]
    with warnings.catch_warnings():
        warnings.simplefilter("error", MopWarning)  # finished: no warning
        mop.load(tmp_path / "run")
