"""The ``harborsight`` command line: thin wrappers over the library.

``main`` holds the app and the measurement, flight, simulator, training and evaluation
commands; each newer command group lives in a module of its own that registers itself on
the app when this package is imported.
"""

from harborsight.cli.main import OWN_RIM_PX, app, console, err_console, main

__all__ = ["OWN_RIM_PX", "app", "console", "err_console", "main"]

from harborsight.cli import (
    dataset,  # noqa: F401
    segment,  # noqa: F401
)
from harborsight.cli.numbers import refuse_non_finite_numbers

refuse_non_finite_numbers(app)
