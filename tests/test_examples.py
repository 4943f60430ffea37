"""The workbench from outside: examples/pendulum.py registers a family that mop/ never names, and
examples/pendulum.toml, an experiment file, trains MOP and runs the EKF / UKF / PF on it through the same
code as the quadrotor."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from mop import cli
from mop.experiments.files import import_plugin

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module")
def pendulum():
    import_plugin(EXAMPLES / "pendulum.py")
    from mop.systems import FAMILIES

    return FAMILIES.get("pendulum")


def test_autograd_jacobian_matches_finite_differences(pendulum):
    """The example gives no Jacobian: StateSpace differentiates f, checked against central differences."""
    from mop.config import SystemConfig
    from mop.systems import generator

    family = pendulum(SystemConfig(family="pendulum"), torch.float64)
    model = family.state_space(family.sample(4, generator=generator(0)))
    x, u = torch.randn(4, 2, dtype=torch.float64), torch.rand(4, 1, dtype=torch.float64)
    J = model.transition_jacobian(x, u, 0)  # (4, 2, 2)
    f = lambda z: model.f(z[:, None], u[:, None], 0)[:, 0]  # noqa: E731
    h = 1e-6
    for j in range(2):
        e = torch.zeros(2, dtype=torch.float64)
        e[j] = h
        np.testing.assert_allclose(J[:, :, j], (f(x + e) - f(x - e)) / (2 * h), atol=1e-8)


def test_pendulum_experiment_file_end_to_end(tmp_path, tiny_smoke):
    out = tmp_path / "pendulum"
    argv = ["reproduce", str(EXAMPLES / "pendulum.toml"), "--preset", "smoke", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    data = json.loads((out / "eval.json").read_text())
    assert data["experiment"] == "pendulum" and data["num_systems"] == 6
    assert {"mop", "ekf", "ukf", "pf", "rls", "last"} <= set(data["predictors"])
    assert [c["claim"] for c in data["claims"]][0].startswith("MOP is within 25% of the EKF")
    assert (out / "pendulum_error.png").exists() and "| ekf |" in (out / "report.md").read_text()
    ekf = data["predictors"]["ekf"]["window_error"]
    assert all(np.isfinite(v) for v in ekf.values())
