"""Training: losses, schedules and parameter groups (needs the ``train`` extra, torch)."""
