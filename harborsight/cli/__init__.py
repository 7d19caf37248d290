"""The ``harborsight`` command line: thin wrappers over the library.

``app`` holds the Typer app, its consoles and what several commands share; each command
group lives in a module of its own that registers itself on the app when imported here, in
the order ``harborsight --help`` lists them.
"""

from harborsight.cli import (  # noqa: F401  (each registers its commands)
    dataset,
    demo,
    evaluate,
    live,
    measure,
    pose_noise,
    run,
    segment,
    simulate,
    telemetry,
    training,
    vessel,
)
from harborsight.cli.app import OWN_RIM_PX, app, console, err_console, main
from harborsight.cli.numbers import refuse_non_finite_numbers

refuse_non_finite_numbers(app)

__all__ = ["OWN_RIM_PX", "app", "console", "err_console", "main"]
