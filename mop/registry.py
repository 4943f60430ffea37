"""Named registries: families, predictors, experiments and models each register themselves here.

    FAMILIES = Registry("system family")

    @FAMILIES.register("pendulum")
    class Pendulum: ...

    FAMILIES.get("pendulum")      # the class; MopError naming the known entries for an unknown name
    FAMILIES.default()            # the one entry registered with default=True (metadata, not a name)

A registry is filled by importing the modules that define its entries. `loader` (called once, on first
lookup) imports the built-in modules, so `import mop` stays light, and then every installed package's entry
points of the group `mop.<kind>` (e.g. a package declaring `[project.entry-points."mop.families"]
pendulum = "my_pkg.pendulum"` is imported on first lookup). A name registered twice is refused, which catches
two plug-ins choosing the same name.

A registry made with `keys` (its metadata's names and what each means) refuses any other key, both when an
entry registers and when a reader asks for one: a typo (`needs_sytem=True`, `meta(name).get("lerned")`)
is a one-line MopError listing the accepted keys, not a silent None.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

from mop.errors import MopError

T = TypeVar("T")


def check_key(where: str, key: str, keys: Mapping[str, str] | None) -> None:
    """MopError unless `key` is one of `keys` (None: any key)."""
    if keys is not None and key not in keys:
        raise MopError(f"{where} has no metadata key {key!r}; accepted keys: {', '.join(keys)}")


class Meta(Mapping[str, Any]):
    """One entry's metadata, read like a dict; a key outside the registry's `keys` is a MopError."""

    def __init__(self, where: str, values: dict[str, Any], keys: Mapping[str, str] | None) -> None:
        self._where, self._values, self._keys = where, values, keys

    def __getitem__(self, key: str) -> Any:
        check_key(self._where, key, self._keys)
        return self._values[key]

    def get(self, key: str, default: Any = None) -> Any:
        check_key(self._where, key, self._keys)
        return self._values.get(key, default)

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)


class Registry(Generic[T]):
    """name -> entry, with optional metadata per entry (e.g. what a predictor needs).

    keys: {metadata key: what it means} (None: any key, unchecked)."""

    def __init__(
        self,
        kind: str,
        loader: Callable[[], None] | None = None,
        group: str = "",
        keys: Mapping[str, str] | None = None,
    ) -> None:
        self.kind, self.group, self.keys = kind, group, keys
        self._entries: dict[str, T] = {}
        self._meta: dict[str, dict[str, Any]] = {}
        self._loader, self._loaded = loader, loader is None and not group

    def register(self, name: str, **meta: Any) -> Callable[[T], T]:
        """Decorator: register the decorated object under `name` (MopError if the name is taken)."""

        def decorate(entry: T) -> T:
            self.add(name, entry, **meta)
            return entry

        return decorate

    def add(self, name: str, entry: T, **meta: Any) -> None:
        for key in meta:
            check_key(f"{self.kind} {name!r}", key, self.keys)
        if name in self._entries and self._entries[name] is not entry:
            raise MopError(f"{self.kind} {name!r} is already registered; choose another name")
        self._entries[name], self._meta[name] = entry, meta

    def _load(self) -> None:
        if not self._loaded:
            self._loaded = True
            if self._loader is not None:
                self._loader()
            if self.group:
                from importlib.metadata import entry_points

                for entry in entry_points(group=self.group):
                    try:
                        entry.load()  # importing the module registers its entries
                    except MopError:
                        raise
                    except Exception as err:  # a broken plug-in package: one line, naming it
                        first = (str(err).splitlines() or [""])[0]
                        raise MopError(
                            f"plug-in {entry.value!r} (entry point {self.group}: {entry.name}) failed to "
                            f"import: {type(err).__name__}: {first}; fix or uninstall that package"
                        ) from None

    def get(self, name: str) -> T:
        self._load()
        if name not in self._entries:
            raise MopError(f"unknown {self.kind} {name!r}; choose one of {', '.join(self.names())}")
        return self._entries[name]

    def meta(self, name: str) -> Meta:
        """The metadata `name` registered with (MopError for an unknown name or on reading an unknown key)."""
        self.get(name)
        return Meta(f"{self.kind} {name!r}", self._meta[name], self.keys)

    def names(self) -> list[str]:
        self._load()
        return list(self._entries)

    def flagged(self, key: str) -> list[str]:
        """The names whose metadata sets `key` true, in registration order (e.g. the figures an experiment
        draws when it names none)."""
        check_key(f"a {self.kind}", key, self.keys)
        return [name for name in self.names() if self._meta[name].get(key)]

    def default(self, key: str = "default") -> str:
        """The one entry registered with `key`=True (e.g. the family a SystemConfig() without a family is),
        so that no other module has to name it; MopError when no entry or several are."""
        found = self.flagged(key)
        if len(found) != 1:
            which = f"{', '.join(repr(n) for n in found)} are" if found else "none is"
            raise MopError(f"one {self.kind} must be registered with {key}=True; {which}")
        return found[0]

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())
