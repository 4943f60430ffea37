"""The plan line's time estimate (issue #66, B): the median of several timed trial steps after untimed
warm-up steps, so one slow step (other work on the machine, a first call's allocations) does not multiply the
estimate. The step times are a fake timer's, so the test does not depend on this machine's speed."""

import pytest
import torch

import mop.train.estimate as estimate
from mop.models import build_model
from mop.train import resolve_config
from tests.test_train import tiny_config

pytestmark = pytest.mark.usefixtures("one_thread")


class FakeTimer:
    """time.perf_counter for the estimate: the k-th timed step lasts durations[k] seconds."""

    def __init__(self, durations: list[float]) -> None:
        self.durations, self.now, self.reads = list(durations), 0.0, 0

    def perf_counter(self) -> float:
        if self.reads % 2 == 1:  # the end of a step: it lasted its duration
            self.now += self.durations[(self.reads // 2) % len(self.durations)]
        self.reads += 1
        return self.now


@pytest.mark.parametrize(
    ("durations", "expected"),
    [
        ([5.0, 0.02, 0.02, 0.02, 0.02], 0.02),  # one slow step among fast ones
        ([0.02, 0.02, 0.9, 0.02, 0.02, 0.03], 0.02),
        ([0.5], 0.5),
    ],
)
def test_the_estimate_is_the_median_of_several_steps_after_warm_up(monkeypatch, durations, expected):
    timer = FakeTimer(durations)
    monkeypatch.setattr(estimate, "time", timer)
    config = resolve_config(tiny_config())
    seconds = estimate.step_seconds(config, build_model(config.model), torch.device("cpu"))
    assert seconds == pytest.approx(expected)
    timed = timer.reads // 2
    assert estimate.MIN_TRIAL_STEPS <= timed <= estimate.TRIAL_STEPS
    before_last = sum(durations[i % len(durations)] for i in range(timed - 1))
    assert timed == estimate.MIN_TRIAL_STEPS or before_last < estimate.TRIAL_SECONDS


def test_the_plan_line_says_how_it_was_timed():
    config = resolve_config(tiny_config())
    line = estimate.plan_line(config, build_model(config.model), torch.device("cpu"))
    assert f"the median of up to {estimate.TRIAL_STEPS} trial steps after {estimate.WARMUP_STEPS}" in line
