"""The class map shared by labels, networks and reports."""

from __future__ import annotations

WATER, SHIP, OBSTACLE, IGNORE = 0, 1, 2, 255

#: Class names in network output order.
CLASS_NAMES = ("water", "ship", "obstacle")
NUM_CLASSES = len(CLASS_NAMES)

#: BGR colours for drawing masks.
CLASS_COLOURS_BGR = {WATER: (140, 90, 30), SHIP: (60, 60, 220), OBSTACLE: (60, 200, 230),
                     IGNORE: (0, 0, 0)}

#: Input normalisation (RGB, ImageNet statistics), applied inside every exported model.
RGB_MEAN = (0.485, 0.456, 0.406)
RGB_STD = (0.229, 0.224, 0.225)
