"""Labelled datasets from common annotation tools (``harborsight dataset import``).

COCO instances JSON, LabelMe JSON, CVAT for images 1.1 XML and YOLO segmentation labels are
read into frames of shapes (:mod:`.importers` and one module per format), their class names
mapped onto harborsight's classes (:mod:`.classmap`: ``--map boat=ship``), painted into
class masks (:mod:`.annotations`: coordinates, rasterisation and drawing order) and written as
a dataset folder that training and evaluation read (:mod:`.layout`). YOLO boxes are not
masks: :func:`read_yolo_boxes` returns them (:class:`Box`, :class:`ImageBoxes`) for a step
that makes masks from boxes. The library needs no CLI; ``harborsight.cli.dataset`` is a thin
shell over it.
"""

from harborsight.datasets.annotations import Issue
from harborsight.datasets.classmap import parse_class_map, read_class_names
from harborsight.datasets.importers import FORMATS, read_annotations
from harborsight.datasets.layout import ImportOptions, ImportResult, import_dataset, plan_import, run_import
from harborsight.datasets.yolo import Box, ImageBoxes, read_yolo_boxes

__all__ = ["FORMATS", "Box", "ImageBoxes", "ImportOptions", "ImportResult", "Issue", "import_dataset",
           "parse_class_map", "plan_import", "read_annotations", "read_class_names", "read_yolo_boxes",
           "run_import"]
