"""Experiment-file mistakes are blamed where they were written: a typo under [train] on [train] (not on a
condition), a command-line override on itself, and the file's name stays outside the quoted key."""

import numpy as np

from mop import cli
from mop.config import DataConfig, RunConfig, apply_overrides
from mop.recipe.records import order_line


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("mop: error: ") and "\n" not in err, err
    return err


def _experiment(tmp_path, train: str, condition: str = "horizon = 20") -> str:
    np.savez(tmp_path / "val.npz", y=np.random.default_rng(0).normal(size=(2, 30, 1)))
    path = tmp_path / "exp.toml"
    path.write_text(
        'name = "x"\ntitle = "t"\npredictors = ["rls", "last"]\nreference = "last"\n'
        f'[train]\n{train}\n[[conditions]]\nname = "val"\ndata = "val.npz"\n{condition}\n'
    )
    return str(path)


def test_experiment_file_mistakes_are_blamed_where_they_were_written(tmp_path, capsys):
    argv = ["--preset", "smoke", "--out", str(tmp_path / "o"), "--quiet"]
    assert cli.main(["reproduce", _experiment(tmp_path, '"train.stepz" = 3'), *argv]) == 2
    err = _one_line_error(capsys)
    assert "[train]: unknown config key 'train.stepz'" in err and "condition" not in err
    assert cli.main(["reproduce", _experiment(tmp_path, "", "horizn = 20"), *argv]) == 2
    err = _one_line_error(capsys)
    assert f"{tmp_path / 'exp.toml'}: unknown config key 'conditions[0].horizn'" in err  # file outside quotes
    assert cli.main(["reproduce", _experiment(tmp_path, ""), *argv, "train.foo=1"]) == 2
    assert "key=value overrides: unknown config key 'train.foo'" in _one_line_error(capsys)


def test_the_order_line_names_the_rule_that_chose_the_orders():
    """mop fit arx, the records recipe and a fine-tune choose ARX orders on different parts of a record; the
    line says which rule chose them."""
    config = apply_overrides(RunConfig(), ["model.rls_order=3", "model.arx_order=2", "model.rls_prior=fit"])
    config = RunConfig(model=config.model, train=config.train, data=DataConfig(path="est.csv"))
    recipe = order_line(config, [])
    assert recipe.startswith("orders: ARX(3, 2)") and "training part only" in recipe
    assert "on the whole record, as `mop fit arx est.csv` does" in order_line(config, [], init="pretrained:x")
    assert "overrides name them" in order_line(config, ["model.arx_order=2"])
    assert order_line(RunConfig(), []) is None  # no recorded data: no orders to choose
