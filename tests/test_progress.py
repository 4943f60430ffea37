"""mop.progress: plain, bounded progress lines when the output is not a terminal."""

import io

from mop.progress import LogProgress, progress


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_log_lines_are_bounded_and_carry_the_facts():
    out = io.StringIO()
    bar = progress(total=100_000, desc="train", interval=0.05, file=out)
    assert isinstance(bar, LogProgress)
    for step in range(100_000):
        bar.update(1)
        if step % 1000 == 0:
            bar.set_postfix(loss=f"{1 / (step + 1):.4g}")
    bar.close()
    bar.close()  # a second close prints nothing more
    lines = out.getvalue().splitlines()
    assert 1 <= len(lines) <= 100  # a fast loop: a handful of timed lines plus the final one
    assert "\r" not in out.getvalue()
    last = lines[-1]
    assert last.startswith("train: step 100000/100000 (100%)")
    assert "steps/s" in last and "took" in last and "loss=" in last


def test_eta_while_running():
    bar = LogProgress(total=10, desc="x", file=io.StringIO())
    bar.update(5)
    bar.start -= 5.0  # five steps in five seconds
    assert "1.0 steps/s" in bar.line() and "ETA 5s" in bar.line()


def test_tty_gets_tqdm_and_disable_prints_nothing():
    from tqdm import tqdm

    bar = progress(total=3, desc="t", file=FakeTTY())
    assert isinstance(bar, tqdm)
    bar.update(3)
    bar.set_postfix(loss="1")
    bar.close()
    out = io.StringIO()
    quiet = progress(total=3, file=out, disable=True)
    quiet.update(3)
    quiet.close()
    assert out.getvalue() == ""
