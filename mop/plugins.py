"""Plugins: Python files outside the package that register entries (a system family, a predictor) on import.

    import_plugin(Path("examples/dead_time.py"))   # registers "dead-time"
    plugin_file(FAMILIES.get("dead-time"))          # -> that file's path (None for a built-in entry)

An experiment file names its plugins (mop.experiments.files); a run trained on a plugin's family records the
file in its run directory (PLUGINS_FILE, mop.train.rundir), so that loading the run later (mop.runs: `mop
predict`, `mop.load`) imports it again before reading config.json.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

from mop.errors import MopError

PLUGINS_FILE = "plugins.json"  # in a run directory: the plugin files its config.json needs, absolute paths
MODULE_PREFIX = "mop_plugin_"


def import_plugin(path: Path) -> None:
    """Import a Python file by path (its registrations run); importing the same file twice is a no-op.

    Any error the file raises while importing (a SyntaxError, a missing module, its own exception) is a
    one-line MopError naming the file, the line and the error.
    """
    if not path.is_file():
        raise MopError(f"plugin {path} does not exist; plugins are paths relative to the experiment file")
    name = f"{MODULE_PREFIX}{path.stem}_{abs(hash(str(path.resolve())))}"
    if name in sys.modules:
        return
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except MopError as err:
        del sys.modules[name]
        raise MopError(f"plugin {path}: {err}") from None
    except Exception as err:  # the plugin's own code: report it in one line, whatever it raised
        del sys.modules[name]
        raise MopError(f"plugin {path} failed to import: {_plugin_error(err, path)}") from None


def _plugin_error(err: Exception, path: Path) -> str:
    """`SyntaxError at line 3: invalid syntax`, `ModuleNotFoundError: No module named 'x' (line 1)`."""
    if isinstance(err, SyntaxError):
        return f"SyntaxError at line {err.lineno}: {err.msg}"
    line = ""
    tb = err.__traceback__
    while tb is not None:
        if Path(tb.tb_frame.f_code.co_filename).resolve() == path.resolve():
            line = f" (line {tb.tb_lineno})"
        tb = tb.tb_next
    first = (str(err).splitlines() or [""])[0]
    return f"{type(err).__name__}: {first}{line}"


def plugin_file(entry: object) -> Path | None:
    """The file of the plugin that defined `entry` (a class or function), None where the package did."""
    module = sys.modules.get(getattr(entry, "__module__", "") or "")
    if module is None or not module.__name__.startswith(MODULE_PREFIX) or not module.__file__:
        return None
    return Path(module.__file__).resolve()
