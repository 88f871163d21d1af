"""Access to the sample-world generators, which live with the tests in ``tests/fixtures``."""

from __future__ import annotations

import importlib
import pathlib
import sys


def load_fixture_module(name: str):
    """Import ``tests.fixtures.<name>`` from the checkout this package sits in."""
    root = pathlib.Path(__file__).resolve().parent.parent
    if not (root / "tests" / "fixtures" / f"{name}.py").exists():
        raise FileNotFoundError(
            f"the sample world generator tests/fixtures/{name}.py is not beside this package "
            f"({root}); run from a checkout of the repository, or pass --input"
        )
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return importlib.import_module(f"tests.fixtures.{name}")
