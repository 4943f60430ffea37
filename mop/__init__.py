"""mop: meta-learned output prediction of dynamical systems."""

__version__ = "0.1.0"


def load(run_dir, device="cpu"):
    """Load a trained predictor from a run directory or a shipped one, `pretrained:NAME` (see mop.runs;
    `mop pretrained` lists the shipped models)."""
    from mop.runs import load_predictor

    return load_predictor(run_dir, device=device)
