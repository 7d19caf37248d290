"""Segmentation: class map, networks (torch), ONNX export and ONNX Runtime inference.

Only :mod:`harborsight.perception.classes` and :mod:`harborsight.perception.onnx_segmenter`
are on the deployed path (numpy + ONNX Runtime); the rest needs the ``train`` extra (torch).
"""
