"""Which sources there are, and each one's settings section: the built-in sources' names and
packages, and the sources registered at run time (plug-ins named in ``PLUGINS_ENV``, a test's toy
source). The registry of sources (``pipeline/sources.py``) keeps the registered ones here, so that
the run's settings (``pipeline.settings``) know every section without importing the registry.
Built-in sources are imported on first use, so listing names and settings costs no heavy import.
"""

from __future__ import annotations

import importlib
import os
from typing import Any, Protocol

# Modules defining a plug-in's ``SOURCE``, comma-separated, registered on the first use.
PLUGINS_ENV = "TAPVID3D_SOURCES"
# name -> the package of a built-in source. Sources are listed in this order (tapnet's evaluation
# order, in which its overall score sums the sources' means), then plug-ins.
BUILT_IN = {
    "drivetrack": "pipeline.drivetrack",
    "adt": "pipeline.adt",
    "pstudio": "pipeline.pstudio",
}


class Registered(Protocol):
    """What this module reads of a registered source (a ``pipeline.sources.Source``)."""

    @property
    def name(self) -> str: ...

    @property
    def settings(self) -> type | None: ...


_registered: dict[str, Any] = {}
_plugins_loaded = False


def register(source: Registered) -> None:
    """Add (or replace) a source at run time."""
    _registered[source.name] = source


def unregister(name: str) -> None:
    _registered.pop(name, None)


def registered(name: str) -> Any | None:
    """The source registered as ``name`` at run time, None when there is none."""
    _load_plugins()
    return _registered.get(name)


def _load_plugins() -> None:
    """Register the sources of the modules ``PLUGINS_ENV`` names (once per process)."""
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for module in filter(None, (part.strip() for part in os.environ.get(PLUGINS_ENV, "").split(","))):
        register(importlib.import_module(module).SOURCE)


def names() -> tuple[str, ...]:
    """Every source's name: the built-in ones in ``BUILT_IN``'s order, then plug-ins in the order
    they were registered."""
    _load_plugins()
    return (*BUILT_IN, *(name for name in _registered if name not in BUILT_IN))


def settings_of(name: str) -> type | None:
    """The settings section class of source ``name`` (None for a source without settings), read for
    a built-in source from its light ``settings`` module."""
    source = registered(name)
    if source is not None:
        return source.settings
    return importlib.import_module(f"{BUILT_IN[name]}.settings").SETTINGS


def title_of(name: str) -> str:
    """The title of source ``name``'s section on the settings page: a built-in source's settings
    module's ``TITLE``, a plug-in's settings section's first docstring line."""
    source = registered(name)
    if source is not None:
        return (source.settings.__doc__ or name).strip().splitlines()[0].rstrip(".")
    return importlib.import_module(f"{BUILT_IN[name]}.settings").TITLE
