"""Placeholder until its owner lands it."""

import argparse

from mop.errors import MopError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    pass


def run(args: argparse.Namespace) -> int:
    raise MopError("not implemented yet")
