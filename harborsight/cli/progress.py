"""The commands' progress display, now :mod:`harborsight.progress` (training uses it too)."""

from harborsight.progress import PLAIN_EVERY_S, ProgressReport, plain_line, progress_report

__all__ = ["PLAIN_EVERY_S", "ProgressReport", "plain_line", "progress_report"]
