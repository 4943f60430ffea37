"""`mop predict --context` (mop.incontext): the simulation after a context record is exactly the by-hand
concatenation, a context that does not fit is one line, and on its own class a shipped class model with
context is not worse than without."""

import dataclasses

import numpy as np
import pytest

from mop.cli import main
from mop.errors import MopError
from mop.identify.cubic import fit_narx, simulate_narx
from mop.identify.select import fit
from mop.incontext import (
    _read,
    _with_orders,
    context_limit,
    context_orders,
    fitted_to_context,
    reading_line,
    reading_orders,
    readings,
    simulate_with_context,
)
from mop.predictors import make_predictor
from mop.record import Record
from mop.records import simulate_all
from mop.runs import load_config, load_predictor
from mop.systems import generator, make_family

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def lti():
    """pretrained:lti-siso (context C = 500) and 24 records of its own class, 1300 steps each."""
    traj = make_family(load_config("pretrained:lti-siso").system).generate(24, 1299, generator=generator(3))
    records = [
        Record(y=traj.y[b].double().numpy(), u=traj.u[b].double().numpy(), name=f"r{b}") for b in range(24)
    ]
    return load_predictor("pretrained:lti-siso"), records


def test_the_context_is_the_by_hand_concatenation_exactly(lti):
    """choose=False: the last C - n steps of the context then the test, simulated from there."""
    model, records = lti
    context, test = records[0][:800], records[0][800:]
    init = 50
    assert context_limit(model) == 500
    done = simulate_with_context(model, test, init, [context], choose=False)
    tail = context[800 - 450 :]
    joined = Record(y=np.concatenate([tail.y, test.y]), u=np.concatenate([tail.u, test.u]))
    by_hand = simulate_all(model, [joined.pair], 450 + init)[0]
    assert done.context_steps == 450
    np.testing.assert_array_equal(done.simulation, by_hand)


def test_cli_context_equals_the_api_and_the_concatenation(tmp_path, lti, capsys):
    model, records = lti
    context, test = records[1][:800], records[1][800:]
    for name, r in (("ctx", context), ("test", test)):
        rows = "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(r.y[:, 0], r.u[:, 0], strict=True))
        (tmp_path / f"{name}.csv").write_text("y0,u0\n" + rows + "\n")
    out = tmp_path / "p.npz"
    argv = ["predict", "pretrained:lti-siso", str(tmp_path / "test.csv"), "--simulate", "50"]
    assert main([*argv, "--context", str(tmp_path / "ctx.csv"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "context" in printed and "read" in printed
    tables = [np.loadtxt(tmp_path / f"{n}.csv", delimiter=",", skiprows=1) for n in ("ctx", "test")]
    ctx, tst = (Record(y=a[:, :1], u=a[:, 1:]) for a in tables)
    expected = simulate_with_context(model, tst, 50, [ctx]).simulation
    np.testing.assert_array_equal(np.load(out)["ysim"][0], expected.astype(np.float32))


def test_on_its_own_class_the_context_is_not_worse_than_none(lti):
    """24 systems of lti-siso: context = the first 800 steps, test = the last 500, n = 50. Measured: mean RMSE
    0.00082 with the context (chosen on all 24) against 0.0101 without, 12x lower; asserted: at most half
    (the tolerance leaves room for other seeds and platforms) and never more than 2% worse on any system."""
    model, records = lti
    with_ctx, without = [], []
    for r in records:
        context, test = r[:800], r[800:]
        y = test.y[50:]
        done = simulate_with_context(model, test, 50, [context])
        alone = simulate_all(model, [test.pair], 50)[0]
        with_ctx.append(np.sqrt(np.mean((y - done.simulation) ** 2)))
        without.append(np.sqrt(np.mean((y - alone) ** 2)))
    assert np.mean(with_ctx) <= 0.5 * np.mean(without)
    assert all(a <= 1.02 * b for a, b in zip(with_ctx, without, strict=True))


def test_a_context_that_does_not_fit_is_one_line(tmp_path, capsys):
    test = Record(y=np.zeros((100, 1)), u=np.zeros((100, 1)), sampling_time=0.1)
    with pytest.raises(MopError, match="2 outputs"):
        simulate_with_context(
            load_predictor("pretrained:lti-siso"),
            test,
            10,
            [Record(y=np.zeros((50, 2)), u=np.zeros((50, 1)))],
        )
    with pytest.raises(MopError, match="sampled every"):
        simulate_with_context(
            None, test, 10, [Record(y=np.zeros((50, 1)), u=np.zeros((50, 1)), sampling_time=0.2)]
        )
    (tmp_path / "t.csv").write_text("y0,u0\n" + "\n".join("0,0" for _ in range(60)) + "\n")
    (tmp_path / "c.csv").write_text("y0,y1,u0\n" + "\n".join("0,0,0" for _ in range(60)) + "\n")
    argv = ["predict", "pretrained:lti-siso", str(tmp_path / "t.csv"), "--out", str(tmp_path / "p.npz")]
    assert main([*argv, "--simulate", "10", "--context", str(tmp_path / "c.csv")]) != 0
    err = capsys.readouterr().err.strip()
    assert "--context record" in err and len(err.splitlines()) == 1
    assert main([*argv, "--context", str(tmp_path / "c.csv")]) != 0
    assert "give --simulate" in capsys.readouterr().err
    assert not (tmp_path / "p.npz").exists()


def long_records(noise_std: float):
    """8 lti-siso systems, 3000 steps each: a context of 2400 (almost 5 times the model's C = 500) and a
    test of the last 600."""
    family = make_family(dataclasses.replace(load_config("pretrained:lti-siso").system, noise_std=noise_std))
    traj = family.generate(8, 2999, generator=generator(3))
    records = [Record(y=traj.y[b].double().numpy(), u=traj.u[b].double().numpy()) for b in range(8)]
    return [(r[:2400], r[2400:]) for r in records]


def test_fit_reading_at_gain_zero_is_the_least_squares_arx_of_the_whole_context(lti):
    """Gain 0 leaves the fitted feature alone: the ARX(15, 15) with an intercept fitted by least squares on
    all 2400 steps of a noisy context (std 0.1; mop.identify.cubic's numpy regressors, in the context's mean
    / std units),
    simulated from the test's first 20 outputs. Measured: within 0.0055 (the feature's prior P_0 = 1e-3 I
    lets the init window's 5 pairs nudge the fit); asserted 0.02 of the outputs' std, which a fit on the
    context's last 500 steps alone exceeds (0.074)."""
    model, _ = lti
    for context, test in long_records(0.1)[:4]:
        sim = simulate_all(fitted_to_context(model, [context], 0.0), [test.pair], 20)[0]
        my, sy, mu, su = context.y.mean(0), context.y.std(0), context.u.mean(0), context.u.std(0)
        theta = fit_narx([((context.y - my) / sy, (context.u - mu) / su)], 15, 15, 0)
        ref = simulate_narx(theta, (test.y - my) / sy, (test.u - mu) / su, 15, 15, 0, 20) * sy + my
        np.testing.assert_allclose(sim, ref, atol=0.02 * float(test.y.std()))


@pytest.mark.parametrize("noise_std", [0.0, 0.1])
def test_a_context_longer_than_the_model_is_read_whole(lti, noise_std):
    """8 systems, a context of 2400 steps: the chosen reading is the one with the lowest held-out score (its
    orders, if it names any, read again on the whole context), its simulation is exactly that reading's,
    and on average it simulates the test no worse than the last window alone (noise-free, measured: RMSE
    0.000107 against 0.000120, the ARX exact either way); with measurement noise (std 0.1) every system
    reads the context as the feature's fit, below the window (measured 0.1004 against 0.1060, both over the
    noise floor of about 0.1)."""
    model, _ = lti
    chosen, window = [], []
    for context, test in long_records(noise_std):
        done = simulate_with_context(model, test, 50, [context])
        best = min(done.held_out, key=done.held_out.get)
        assert done.reading == _with_orders(best, context_orders(model, [context]))
        y = test.y[50:]
        chosen.append(np.sqrt(np.mean((done.simulation - y) ** 2)))
        by_window = simulate_with_context(model, test, 50, [context], choose=False).simulation
        window.append(np.sqrt(np.mean((by_window - y) ** 2)))
        if done.reading.startswith("fit"):
            gain = float(done.reading.rpartition(" ")[2])
            orders = reading_orders(done.reading)
            again = fitted_to_context(model, [context], gain, orders=orders)
            again = simulate_all(again, [test.pair], 50)[0]
            np.testing.assert_array_equal(done.simulation, again)
            assert done.context_steps == 2400
        elif noise_std > 0:
            raise AssertionError(f"a noisy record read as {done.reading!r}")
    assert np.mean(chosen) <= np.mean(window)


def test_the_fit_reading_serves_class_models_only(lti):
    """A class model's fit readings are two whole models: its fitted feature alone (gain 0) and the model as
    trained (gain 1), at its own orders and at the context's."""
    model, _ = lti
    assert [r for r in readings(model) if r.startswith("fit")] == ["fit gain 0", "fit gain 1"]
    assert readings(model, (3, 2))[-2:] == ["fit ARX(3, 2) gain 0", "fit ARX(3, 2) gain 1"]
    assert readings(make_predictor("arx")) == ["none", "window"]


def test_a_reading_that_diverges_on_the_test_gives_way_to_the_next_best(lti, monkeypatch):
    """The held-out end chooses a reading before the test is simulated; where that reading's simulation of
    the test leaves every measured range (here made to, by scaling it 1e6), the next best by held-out
    score simulates the test, and the line says which diverged."""
    import mop.incontext as incontext

    model, records = lti
    context, test = records[2][:800], records[2][800:]
    plain = simulate_with_context(model, test, 50, [context])
    real = incontext._read

    def wild(predictor, record, init, ctx, reading, fitted=None):
        sim, steps = real(predictor, record, init, ctx, reading, fitted)
        return (sim * 1e6 if record is test and reading == plain.reading else sim), steps

    monkeypatch.setattr(incontext, "_read", wild)
    done = simulate_with_context(model, test, 50, [context])
    ranked = sorted(done.held_out, key=done.held_out.get)
    assert done.diverged == (plain.reading,) and done.reading == ranked[1]
    assert plain.reading in reading_line(done) and "strayed" in reading_line(done)
    np.testing.assert_array_equal(done.simulation, real(model, test, 50, [context], ranked[1])[0])


@pytest.mark.parametrize("beyond", [0.5, 1.5])
def test_a_reading_that_strays_beyond_the_measured_outputs_gives_way(lti, monkeypatch, beyond):
    """The chosen reading's simulation of the test replaced by a constant `beyond` x STRAY_FACTOR ranges
    above every output measured before it (finite, far inside DIVERGENCE_FACTOR): at 1.5 it gives way to
    the next best by held-out score, at 0.5 it is kept."""
    import mop.incontext as incontext

    model, records = lti
    context, test = records[2][:800], records[2][800:]
    plain = simulate_with_context(model, test, 50, [context])
    seen = np.concatenate([context.y, test.y[:50]])
    top = seen.max() + beyond * incontext.STRAY_FACTOR * (seen.max() - seen.min())
    real = incontext._read

    def high(predictor, record, init, ctx, reading, fitted=None):
        sim, steps = real(predictor, record, init, ctx, reading, fitted)
        return (np.full_like(sim, top) if record is test and reading == plain.reading else sim), steps

    monkeypatch.setattr(incontext, "_read", high)
    done = simulate_with_context(model, test, 50, [context])
    ranked = sorted(done.held_out, key=lambda r: (done.held_out[r], list(done.held_out).index(r)))
    assert ranked[0] == plain.reading
    if beyond > 1:
        assert done.diverged == (plain.reading,) and done.reading == ranked[1]
    else:
        assert done.diverged == () and done.reading == plain.reading
        np.testing.assert_array_equal(done.simulation, np.full_like(done.simulation, top))


def test_a_single_output_model_reads_each_output_of_a_record_on_its_own(lti):
    """Two lti-siso records' outputs side by side with the first one's inputs make a two-output record;
    pretrained:lti-siso simulates it with its context channel by channel, exactly as it simulates each
    one-output record (that output, those inputs) with its own context, and the line names each channel's
    reading."""
    model, records = lti
    u = records[3].u
    two = Record(y=np.concatenate([records[3].y, records[4].y], axis=1), u=u, name="two")
    context, test = two[:800], two[800:]
    done = simulate_with_context(model, test, 50, [context])
    for i in range(2):
        one = Record(y=two.y[:, i : i + 1], u=u)
        alone = simulate_with_context(model, one[800:], 50, [one[:800]])
        np.testing.assert_array_equal(done.simulation[:, i : i + 1], alone.simulation)
        assert f"y{i}: {alone.reading}" in done.reading
    assert "each output on its own" in reading_line(done)
    assert done.shipped == () and "reads every output together" not in reading_line(done)  # none for m = 2


def test_a_long_context_reads_the_longer_arx_it_supports_when_that_simulates_its_end_better(lti):
    """A plant with an input delay of 18 steps, which the class model's ARX(15, 15) feature cannot hold:
    with 6000 steps of context the readings include the feature refitted as ARX(20, 20) (the records
    recipe's long orders, mop.identify.long_arx), one of them is chosen, it is exactly that fitted model's
    simulation, and it simulates the test at least 3 times better than the model's own orders fitted alike
    (measured: 0.072 against 1.37, the outputs' std 1.38; noise std 0.05)."""
    from tests.test_long_arx import delayed_plant

    model, _ = lti
    y, u = delayed_plant(7000, delay=18, seed=1)
    context, test = Record(y=y[:6000], u=u[:6000]), Record(y=y[6000:], u=u[6000:])
    done = simulate_with_context(model, test, 50, [context])
    assert done.reading.startswith("fit ARX(20, 20) gain ") and "ARX(20, 20)" in reading_line(done)
    gain = float(done.reading.rpartition(" ")[2])
    again = simulate_all(fitted_to_context(model, [context], gain, orders=(20, 20)), [test.pair], 50)[0]
    np.testing.assert_array_equal(done.simulation, again)
    own = simulate_all(fitted_to_context(model, [context], 0.0), [test.pair], 50)[0]
    rmse = lambda sim: float(np.sqrt(np.mean((sim - test.y[50:]) ** 2)))  # noqa: E731
    assert 3 * rmse(done.simulation) < rmse(own)


def test_a_three_output_class_model_reads_what_each_output_alone_misses():
    """Six noise-free plants of up to 24 states with one input and three outputs (mop.systems.lti_mimo), 1500
    steps of context: pretrained:lti-mimo, whose feature regresses each output on every output's lags,
    simulates the test no worse than pretrained:lti-siso reading one output at a time on every plant (1%
    tolerance, and 1e-4 of the outputs' std where both are exact: on plant 5 both read the context with the
    orders `mop fit arx` picks, 1.3e-5 against 7.5e-6) and below half of it on average; one output of a
    plant of more than 15 states needs more lags than lti-siso's ARX(15, 15) holds, the three together do
    not (measured: mean RMSE 0.0000114 against 0.000237)."""
    from mop.config import SystemConfig

    family = make_family(SystemConfig(family="lti-mimo", max_order=24))
    traj = family.generate(6, 1999, generator=generator(11))
    mimo, siso = load_predictor("pretrained:lti-mimo"), load_predictor("pretrained:lti-siso")
    three, alone = [], []
    for b in range(6):
        record = Record(y=traj.y[b].double().numpy(), u=traj.u[b].double().numpy())
        context, test = record[:1500], record[1500:]
        for model, scores in ((mimo, three), (siso, alone)):
            done = simulate_with_context(model, test, 50, [context])
            scores.append(float(np.sqrt(np.mean((done.simulation - test.y[50:]) ** 2))))
        exact = 1e-4 * float(test.y.std())
        assert three[-1] <= 1.01 * alone[-1] + exact, (b, three[-1], alone[-1])
        # read one output at a time, the line names the shipped model that reads all three
        assert "pretrained:lti-mimo reads every output together" in reading_line(done)
    assert np.mean(three) < 0.5 * np.mean(alone)


def test_a_long_reading_stays_at_the_fit_over_the_whole_context():
    """A reading of longer orders than the model's ("fit ARX(P, P)") keeps the feature at its least-squares
    fit on the context (model.rls_fixed): at gain 0 it is the numpy simulation of the ARX(20, 20) with an
    intercept fitted on all 3000 steps of a noisy three-output context (mop.identify.cubic's regressors, in
    the context's mean / std units), from the test's first 50 outputs. Measured: within 3e-5 of the outputs'
    std (the two least squares' ridges differ); adapting from P_0 = I over those 50 outputs, as the model's
    own orders do, moved the 81 coefficients an output enough to leave it by 0.03 - 0.04."""
    from mop.config import SystemConfig

    family = make_family(SystemConfig(family="lti-mimo", noise_std=0.1))
    traj = family.generate(2, 3599, generator=generator(4))
    model = load_predictor("pretrained:lti-mimo")
    for b in range(2):
        y, u = traj.y[b].double().numpy(), traj.u[b].double().numpy()
        context, test = Record(y=y[:3000], u=u[:3000]), Record(y=y[3000:], u=u[3000:])
        sim = simulate_all(fitted_to_context(model, [context], 0.0, orders=(20, 20)), [test.pair], 50)[0]
        my, sy, mu, su = context.y.mean(0), context.y.std(0), context.u.mean(0), context.u.std(0)
        theta = fit_narx([((context.y - my) / sy, (context.u - mu) / su)], 20, 20, 0)
        ref = simulate_narx(theta, (test.y - my) / sy, (test.u - mu) / su, 20, 20, 0, 50) * sy + my
        np.testing.assert_allclose(sim, ref, atol=0.001 * float(test.y.std()))


def test_the_fitted_feature_simulates_beyond_the_tests_first_outputs_as_the_arx_does(lti):
    """A test whose first 50 outputs sit near one level, then an input step that moves the plant across the
    range the context has shown: the fit reading at gain 0 is the least-squares ARX(2, 2) of the context
    simulated (numpy, mop.identify.cubic) to 1e-3 of the outputs' std. Held within the test's first outputs'
    range alone (before model.rls_fill_range), the feature stopped at a fraction of the step (a cascaded
    tanks' record: held at 7.3 V while the level rose to 10 V)."""
    model, _ = lti
    rng = np.random.default_rng(5)
    a1, a2, b1, b2 = 1.5, -0.6, 0.3, 0.2  # y_t = a1 y_{t-1} + a2 y_{t-2} + b1 u_{t-1} + b2 u_{t-2} + 1 + e_t

    def plant(u):
        y = np.zeros(len(u))
        for t in range(2, len(u)):
            y[t] = a1 * y[t - 1] + a2 * y[t - 2] + b1 * u[t - 1] + b2 * u[t - 2] + 1 + 0.01 * rng.normal()
        return y[:, None]

    u_ctx = np.repeat(rng.uniform(-2, 2, 60), 20)[:, None]  # steps across the range
    u_test = np.concatenate([np.full(200, -1.5), np.full(400, 1.8)])[:, None]
    u_test = u_test + 0.05 * rng.normal(size=(600, 1))
    context, test = Record(y=plant(u_ctx[:, 0]), u=u_ctx), Record(y=plant(u_test[:, 0]), u=u_test)
    sim = simulate_all(fitted_to_context(model, [context], 0.0, orders=(2, 2)), [test.pair], 50)[0]
    my, sy, mu, su = context.y.mean(0), context.y.std(0), context.u.mean(0), context.u.std(0)
    theta = fit_narx([((context.y - my) / sy, (context.u - mu) / su)], 2, 2, 0)
    ref = simulate_narx(theta, (test.y - my) / sy, (test.u - mu) / su, 2, 2, 0, 50) * sy + my
    assert np.ptp(test.y[200:]) > 5 * np.ptp(test.y[:50])  # the step leaves the first outputs' range
    np.testing.assert_allclose(sim, ref, atol=1e-3 * float(test.y.std()))


def test_a_short_context_is_read_with_the_orders_mop_fit_arx_picks(lti):
    """A 600-step context of an ARX(2, 2) plant, too short for a longer ARX than lti-siso's own ARX(15, 15):
    context_orders are the orders `mop fit arx` picks on it, and the fit reading at gain 0 with them
    simulates the test as the ARX `mop fit arx` fits (mop.identify.arx: numpy's lstsq, its own simulation)
    to 1e-5 of the outputs' std (measured 2e-7; with the class models' ridge of 1e-6 times the pairs, 1e-4).
    The chosen reading's orders are those read on the whole context (the held-out check read the context
    before its end as ARX(2, 2))."""
    model, _ = lti
    rng = np.random.default_rng(11)

    def plant(u):
        y = np.zeros(len(u))
        for t in range(2, len(u)):
            e = 0.02 * rng.normal()
            y[t] = 1.2 * y[t - 1] - 0.5 * y[t - 2] + 0.8 * u[t - 1] + 0.3 * u[t - 2] + 0.5 + e
        return y[:, None]

    u = rng.normal(size=1000)
    record = Record(y=plant(u), u=u[:, None])
    context, test = record[:600], record[600:]
    orders = context_orders(model, [context])
    arx = fit("arx", [context.pair])
    assert orders == (arx.orders["p"], arx.orders["q"]) != (15, 15)
    sim = simulate_all(fitted_to_context(model, [context], 0.0, orders=orders), [test.pair], 50)[0]
    np.testing.assert_allclose(sim, simulate_all(arx, [test.pair], 50)[0], atol=1e-5 * float(test.y.std()))
    done = simulate_with_context(model, test, 50, [context])  # chosen on the held-out end: ARX(2, 2) gain 1
    assert reading_orders(done.reading) == orders  # read on the whole context: ARX(5, 1)
    assert "fit ARX(2, 2) gain 1" in done.held_out


def test_a_records_start_without_a_feature_reads_the_test_in_the_contexts_units():
    """pretrained:cascaded-tanks-lru (the records recipe's deep LRU, pretrained with each window in its
    estimation record's units) gets the "units" reading, which no feature-reading model gets; read that way
    its simulation is equivariant as a model of the plant's units must be: the context and the test both
    in other units (y -> a y + b, u -> c u + d) give a ysim + b (to float32's 1e-5); read in the test's raw
    units (the "none" reading) they do not."""
    start = load_predictor("pretrained:cascaded-tanks-lru")
    assert readings(start) == ["none", "window", "units"]
    assert "units" not in readings(load_predictor("pretrained:cascaded-tanks-records"))
    traj = make_family(load_config("pretrained:cascaded-tanks-lru").system).generate(
        2, 599, generator=generator(4)
    )
    pair = [(traj.y[b].double().numpy(), traj.u[b].double().numpy()) for b in range(2)]
    a, b, c, d = 3.0, -2.0, 0.5, 1.0

    def record(y, u, name, scaled):
        return Record(y=a * y + b, u=c * u + d, name=name) if scaled else Record(y=y, u=u, name=name)

    sims = {}
    for scaled in (False, True):
        context, test = record(*pair[0], "est", scaled), record(*pair[1], "test", scaled)
        sims[scaled] = {
            reading: _read(start, test, 5, [context], reading)[0] for reading in ("units", "none")
        }
    np.testing.assert_allclose(sims[True]["units"], a * sims[False]["units"] + b, rtol=1e-5, atol=1e-5)
    assert np.abs(sims[True]["none"] - (a * sims[False]["none"] + b)).max() > 1e-3
