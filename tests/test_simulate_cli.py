"""`mop simulate` round trip: the .npz holds what family.generate gives for the same seed."""

import numpy as np
import torch

from mop.cli import main
from mop.config import SystemConfig
from mop.systems import generator, make_family


def test_simulate_round_trip(tmp_path):
    out = tmp_path / "lin.npz"
    args = ["simulate", "linear", "--systems", "7", "--horizon", "12", "--seed", "3", "--out", str(out)]
    assert main([*args, "state_dim=4", "output_dim=2", "noise_var_w=0.04"]) == 0
    data = np.load(out)
    assert data["y"].shape == (7, 13, 2) and data["param_A"].shape == (7, 4, 4) and "u" not in data
    cfg = SystemConfig(state_dim=4, output_dim=2, noise_var_w=0.04)
    ref = make_family(cfg, torch.float32).generate(7, 12, generator=generator(3))
    np.testing.assert_array_equal(data["y"], ref.y.numpy())
    np.testing.assert_allclose(data["param_Q"][0], 0.04 * np.eye(4), rtol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["lin.npz"]  # no temp file left behind


def test_simulate_quadrotor_has_inputs_and_params(tmp_path):
    out = tmp_path / "q.npz"
    assert main(["simulate", "quadrotor", "--systems", "3", "--horizon", "5", "--out", str(out)]) == 0
    data = np.load(out)
    assert data["u"].shape == (3, 6, 2) and data["param_mass"].shape == (3,)
    assert data["param_C"].shape == (3, 3, 6)


def test_simulate_bad_input_is_one_line_error(tmp_path, capsys):
    out = tmp_path / "x.npz"
    assert main(["simulate", "linear", "spectral_radius=1.5", "--out", str(out)]) == 2
    assert main(["simulate", "linear", "nosuchkey=1", "--out", str(out)]) == 2
    assert main(["simulate", "linear", "--systems", "0", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("mop: error:") for line in err)
    assert not out.exists()
