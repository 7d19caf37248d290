"""Whole flights: frame sources (folders, videos), per-section trends over time, the run."""

from harborsight.flight.runner import RunOptions, RunSummary, run_flight
from harborsight.flight.sources import FlightFrame, FolderSource, VideoSource
from harborsight.flight.timeline import ClearanceTimeline

__all__ = ["ClearanceTimeline", "FlightFrame", "FolderSource", "RunOptions", "RunSummary",
           "VideoSource", "run_flight"]
