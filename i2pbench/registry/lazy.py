"""Classes registered by import path: `register("package.module:Class", name="x")` keeps the name and imports the
class on first use, so listing plugins, or running other stages, never imports what it needs (a learned stage's
torch). What either way of registering gives is checked to be the hook's kind of class, with the name it claims."""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Any

from ..errors import PluginError
from ..stages.components import STAGE_BASES


@dataclass(frozen=True)
class LazyComponent:
    """A component or dataset registered by import path and name, not yet imported."""

    path: str  # "package.module:Class"
    kind: str  # a stage kind, "dataset" or "corruption"
    name: str
    plugin: str

    def resolve(self) -> type:
        """Import the class and check it is what was registered: the hook's base class, and the same `name`."""
        module, _, qualname = self.path.partition(":")
        try:
            cls: Any = importlib.import_module(module)
            for attr in qualname.split("."):
                cls = getattr(cls, attr)
        except (Exception, SystemExit) as exc:  # a broken plugin fails the command that uses it, with its name
            raise PluginError(
                f"plugin {self.plugin!r} registered {self.kind} {self.name!r} as {self.path!r}, which cannot be "
                f"imported: {type(exc).__name__}: {exc}"
            ) from exc
        check_class(cls, self.kind, self.plugin)
        if cls.name != self.name:
            raise PluginError(
                f"plugin {self.plugin!r} registered {self.path} as {self.kind} {self.name!r}, "
                f"but its name is {cls.name!r}"
            )
        return cls


def check_class(cls: Any, kind: str, plugin: str) -> None:
    """`cls` subclasses the base of `kind` and has a name (a corruption: and declares what it needs)."""
    from ..corruptions.base import Corruption  # the registry loads without them
    from ..corruptions.base import check_class as check_corruption
    from ..data.base import Dataset

    base = {"dataset": Dataset, "corruption": Corruption}.get(kind) or STAGE_BASES[kind]
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise PluginError(f"plugin {plugin!r} registered {cls!r} as a {kind}, but it does not subclass {base.__name__}")
    if not cls.name:
        raise PluginError(f"plugin {plugin!r} registered {cls.__name__} without a `name`")
    if kind == "corruption":
        check_corruption(cls, plugin)


def registered_class(kind: str, plugin: str, target: Any, name: str | None = None) -> tuple[str, Any]:
    """`register(cls)` or `register("package.module:Class", name=...)` -> (name, class or LazyComponent)."""
    if not isinstance(target, str):
        check_class(target, kind, plugin)
        if name is not None and name != target.name:
            raise PluginError(
                f"plugin {plugin!r} registered {target.__name__} as {name!r}, but its name is {target.name!r}"
            )
        return target.name, target
    module, _, qualname = target.partition(":")
    if not (module and qualname and isinstance(name, str) and name):
        raise PluginError(
            f"plugin {plugin!r} registered {kind} {target!r}: a path needs the form 'package.module:Class' and a name, "
            "register('package.module:Class', name='my-name')"
        )
    return name, LazyComponent(target, kind, name, plugin)


def class_path(entry: Any) -> str:
    """`module:Class` of a class or of one registered by path, without importing it."""
    return entry.path if isinstance(entry, LazyComponent) else f"{entry.__module__}:{entry.__qualname__}"


def same_class(a: Any, b: Any) -> bool:
    """Whether two registrations are one class (registered twice, or once eagerly and once by its path)."""
    if a is b:
        return True
    return (isinstance(a, LazyComponent) or isinstance(b, LazyComponent)) and class_path(a) == class_path(b)
