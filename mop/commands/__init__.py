"""Subcommands of `mop`: each module provides add_arguments(parser) and run(args) -> int."""

from __future__ import annotations

import argparse


class OverridesAnywhere(argparse.ArgumentParser):
    """A parser whose `overrides` (key=value words) may also come after the options.

    argparse reads a nargs="*" positional in one chunk, so `mop train --out D a=1` would leave `a=1` over.
    """

    def parse_known_args(self, args=None, namespace=None):
        namespace, extras = super().parse_known_args(args, namespace)
        late = [a for a in extras if "=" in a and not a.startswith("-")]
        namespace.overrides = [*(namespace.overrides or []), *late]
        return namespace, [a for a in extras if a not in late]
