"""The live berthing aid (``harborsight live``): frames measured as they come, alarms, and
the state served to a dashboard and to other programs."""
