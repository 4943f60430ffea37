"""The training progress display, in one place (today a tqdm bar; a no-op when disabled)."""

from __future__ import annotations


class _NoProgress:
    def update(self, n: int = 1) -> None:
        pass

    def set_postfix(self, **values) -> None:
        pass

    def close(self) -> None:
        pass


def make_progress(total: int, initial: int, desc: str, enabled: bool = True):
    """A bar with update(n), set_postfix(**values) and close(), starting at `initial` of `total` steps."""
    if not enabled:
        return _NoProgress()
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, dynamic_ncols=True)
