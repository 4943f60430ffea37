"""The `mop` command: a thin dispatcher. Each subcommand lives in mop/commands/<name>.py and
provides `add_arguments(parser)` and `run(args) -> int`; only the subcommand given is imported (importlib:
the one place in mop where a module is chosen at run time)."""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from importlib import metadata

from mop.errors import MopError, MopWarning, is_out_of_memory, memory_error_message, os_error_message

# name -> (module, one-line help)
COMMANDS = {
    "simulate": ("mop.commands.simulate", "simulate trajectories of a system family to an .npz file"),
    "train": ("mop.commands.train", "train a meta-output-predictor"),
    "reproduce": ("mop.commands.reproduce", "reproduce a paper figure or run an experiment file"),
    "benchmark": ("mop.commands.benchmark", "run the system-identification benchmarks' official protocol"),
    "fit": ("mop.commands.fit", "fit ARX or N4SID once on an estimation record (mop predict uses it)"),
    "predict": ("mop.commands.predict", "one- or k-step predictions of a run or baseline on your data"),
    "pretrained": ("mop.commands.pretrained", "the predictors shipped with mop: list, show, build"),
    "bench": (
        "mop.commands.bench",
        "speed and accuracy measurements of mop itself (mop bench --help lists them)",
    ),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser; only `command`'s module is imported for its arguments (the others show their help line),
    so `mop reproduce` loads what reproducing needs and nothing of, e.g., `mop bench`."""
    parser = argparse.ArgumentParser(
        prog="mop", description="mop: meta-learned output prediction of dynamical systems."
    )
    parser.add_argument("--version", action="version", version=f"mop {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        cmd = sub.add_parser(name, help=help_text, description=help_text)
        if name == command:
            importlib.import_module(module).add_arguments(cmd)
        cmd.set_defaults(_module=module)
    return parser


def _version() -> str:
    try:
        return metadata.version("mop")
    except metadata.PackageNotFoundError:  # run from a source tree that is not installed
        return "(not installed)"


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """mop's own warnings on one line (`mop: warning: ...`); other libraries' as Python prints them."""
    if issubclass(category, MopWarning):
        print(f"mop: warning: {message}", file=sys.stderr)
    else:
        _default_show(message, category, filename, lineno, file, line)


_default_show = warnings.showwarning


def _fail(message: str) -> int:
    print(f"mop: error: {message}", file=sys.stderr)
    return 2


def _command(argv: list[str]) -> str | None:
    """The subcommand named by argv: its first word that is not an option."""
    return next((word for word in argv if not word.startswith("-")), None)


def main(argv: list[str] | None = None) -> int:
    """Run one command. Every problem the user can act on ends here in one line and exit status 2:
    MopError, OSError (a full disk, no permission, a read-only file system; atomic writes leave the
    previous files whole and remove their temporaries) and running out of memory."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(_command(argv)).parse_args(argv)
    args._argv = argv  # the command line as given, for the provenance of what a command writes
    warnings.showwarning = _show_warning
    try:
        return int(importlib.import_module(args._module).run(args) or 0)
    except MopError as err:
        return _fail(str(err))
    except OSError as err:
        return _fail(os_error_message(err))
    except (MemoryError, RuntimeError) as err:
        if not is_out_of_memory(err):
            raise
        return _fail(memory_error_message(err))
    except KeyboardInterrupt:
        print("mop: interrupted", file=sys.stderr)
        return 130
    finally:
        warnings.showwarning = _default_show


if __name__ == "__main__":
    sys.exit(main())
