"""Deployed inference: an exported model in ONNX Runtime (numpy + OpenCV, no torch)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES, NUM_CLASSES
from harborsight.perception.confidence import SolidConfidence, class_probabilities
from harborsight.perception.flips import flip_views

#: :func:`cpu_int8_dot_product` of a CPU whose fused uint8 x int8 sums saturate
SATURATING_CPU = "avx2 without vnni"


@functools.cache
def cpu_int8_dot_product() -> str:
    """How this CPU sums ONNX Runtime's fused uint8 x int8 products, from its CPU flags:
    ``vnni`` (32-bit sums, exact), ``avx2 without vnni`` (pairs of products in 16-bit
    saturating sums), or ``unknown`` (not x86, or no flags to read). The flags come from
    ``/proc/cpuinfo`` on Linux and from py-cpuinfo elsewhere (Windows, macOS), which knows
    AVX-512 VNNI but not AVX-VNNI: such a CPU counts as saturating there, which costs speed,
    not labels."""
    flags = _linux_cpu_flags()
    if flags is None:
        try:
            import cpuinfo

            flags = [f.replace("avx512vnni", "avx512_vnni")
                     for f in cpuinfo.get_cpu_info().get("flags", [])]
        except Exception:  # py-cpuinfo probes the CPU in several ways; any may fail
            return "unknown"
    if "avx512_vnni" in flags or "avx_vnni" in flags:
        return "vnni"
    return SATURATING_CPU if "avx2" in flags else "unknown"


def _linux_cpu_flags() -> list[str] | None:
    """The ``flags`` of the first CPU in ``/proc/cpuinfo``; None where there is none."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    return next((line.split(":", 1)[1].split() for line in text.splitlines()
                 if line.startswith("flags")), None)


#: operators that compute in integers whatever the session's options: a QOperator graph
#: (ONNX Runtime's other quantisation format) cannot be run "as written" in float
INTEGER_OPERATORS = frozenset({"QLinearConv", "QLinearMatMul", "ConvInteger", "MatMulInteger",
                               "DynamicQuantizeMatMul", "MatMulIntegerToFloat"})


#: :func:`int8_arithmetic` of fused kernels given the weights as uint8 on a saturating CPU
UINT8_WEIGHTS = f"fused, uint8 weights ({SATURATING_CPU})"


def _referenced_names(graph) -> set[str]:
    """Every name ``graph`` reads or exposes: node inputs (subgraphs of ``If``, ``Loop`` and
    ``Scan`` included), graph inputs and graph outputs."""
    names = {v.name for v in graph.input} | {v.name for v in graph.output}
    for node in graph.node:
        names.update(node.input)
        for attribute in node.attribute:
            for subgraph in [attribute.g, *attribute.graphs]:
                if subgraph.node or subgraph.input or subgraph.output:
                    names |= _referenced_names(subgraph)
    return names


def _int8_weight_dequantizers(graph) -> list:
    """The ``DequantizeLinear`` nodes of ``graph`` that read an int8 initialiser (weights)
    whose scale, and zero point where given, are initialisers too; weights that are also
    graph inputs or outputs are left out (a caller may override those, so they are not
    constants)."""
    from onnx import TensorProto

    exposed = {v.name for v in graph.input} | {v.name for v in graph.output}
    constants = {t.name for t in graph.initializer} - exposed
    int8 = {t.name for t in graph.initializer if t.data_type == TensorProto.INT8} - exposed
    return [n for n in graph.node if n.op_type == "DequantizeLinear" and n.input[0] in int8
            and n.input[1] in constants
            and (len(n.input) < 3 or not n.input[2] or n.input[2] in constants)]


def weights_as_uint8(model) -> int:
    """Rewrite, in place, every int8 weight read by a ``DequantizeLinear``
    (:func:`_int8_weight_dequantizers`) as uint8: ``w' = w + 128`` with zero point
    ``z' = z + 128``, so ``(w' - z')·s = (w - z)·s`` and the real weights are exactly the
    same. The int8 originals go only where nothing else reads them. Returns how many nodes
    changed.

    Why: ONNX Runtime fuses a QDQ convolution with int8 weights into its uint8 x int8
    kernel, which on x86 without VNNI multiplies with ``vpmaddubsw`` and adds each pair of
    products in a saturating 16-bit register (two products of 255 x 127 give 32,767, not
    64,770). With uint8 weights it takes its uint8 x uint8 kernel instead, which widens to
    16 bits before multiplying and sums in 32 bits: no saturation, at some speed
    (docs/results.md, "uint8 weights on CPUs without VNNI")."""
    from onnx import numpy_helper

    graph = model.graph
    values = {t.name: t for t in graph.initializer}
    taken = _referenced_names(graph) | set(values) | {o for n in graph.node for o in n.output}
    converted: dict[str, str] = {}

    def as_uint8(name: str | None, like: np.ndarray) -> str:
        """The name of a uint8 copy (+128) of initialiser ``name`` (0 when absent)."""
        key = name or f"zero_point_like_{like.shape}"
        if key not in converted:
            signed = (numpy_helper.to_array(values[name]) if name
                      else np.zeros(like.shape, np.int8))
            shifted = (signed.astype(np.int16) + 128).astype(np.uint8)
            new_name, k = f"{key}_as_uint8", 1
            while new_name in taken:
                new_name, k = f"{key}_as_uint8_{k}", k + 1
            taken.add(new_name)
            graph.initializer.append(numpy_helper.from_array(shifted, new_name))
            converted[key] = new_name
        return converted[key]

    nodes = _int8_weight_dequantizers(graph)
    for node in nodes:
        scale = numpy_helper.to_array(values[node.input[1]])
        zero_point = node.input[2] if len(node.input) > 2 and node.input[2] else None
        node.input[0] = as_uint8(node.input[0], scale)
        if len(node.input) > 2:
            node.input[2] = as_uint8(zero_point, scale)
        else:
            node.input.append(as_uint8(None, scale))
    still_read = _referenced_names(graph)
    for name in converted:
        if name in values and name not in still_read:
            graph.initializer.remove(values[name])
    return len(nodes)


def int8_arithmetic(path: str | Path, reference_arithmetic: bool) -> str | None:
    """How :class:`OnnxSegmenter` computes the convolutions of the model at ``path``: None
    for a float model; for a QDQ int8 model ``reference`` (the graph as written: dequantise,
    float convolution, quantise), ``fused (<this CPU's kind>)``, or on a CPU whose uint8 x
    int8 sums saturate :data:`UINT8_WEIGHTS` (:func:`weights_as_uint8`); ``integer operators
    (<kind>)`` for a graph with integer operators, whatever the options; ``unknown`` when
    the graph cannot be read."""
    import onnx

    try:
        graph = onnx.load(str(path), load_external_data=False).graph
    except Exception:  # protobuf raises several types; this is a report only
        return "unknown"
    return _int8_arithmetic(graph, reference_arithmetic)


def _int8_arithmetic(graph, reference_arithmetic: bool) -> str | None:
    operators = {node.op_type for node in graph.node}
    if operators & INTEGER_OPERATORS:
        return f"integer operators ({cpu_int8_dot_product()})"
    if "QuantizeLinear" not in operators:
        return None
    if reference_arithmetic:
        return "reference"
    if cpu_int8_dot_product() == SATURATING_CPU and _int8_weight_dequantizers(graph):
        return UINT8_WEIGHTS
    return f"fused ({cpu_int8_dot_product()})"


class OnnxSegmenter:
    """Runs a ``harborsight`` ONNX model on BGR frames of any size.

    The graph itself normalises, pads and crops (see :mod:`harborsight.perception.model`).
    A frame of another size is resized to the model's input (area filter when shrinking,
    bilinear when enlarging), and the logits are resized back to the frame bilinearly
    (pixel centres aligned) before the labels are taken, so class edges fall between frame
    pixels instead of on the model's coarser grid.

    A frame of another aspect ratio is stretched, not letterboxed. Measured on 130 bench
    frames cut to 4:3 and enlarged to 1440x1080: stretched into the 640x360 input, 95.53 %
    mIoU; scaled by one factor and padded with the mean colour, 94.36 % (the padding
    wastes a quarter of the input's columns). Upsampling logits instead of labels: 95.53 %
    against 95.49 %.

    ``reference_arithmetic``: run the graph as written, with ONNX Runtime's graph
    optimisations off. An int8 (QDQ) model then computes each quantised convolution as
    dequantise, float convolution, quantise: the arithmetic the graph defines, with no
    integer saturation, equal on every CPU up to float rounding (a QOperator graph's integer
    operators stay integer: :func:`int8_arithmetic` says so). With the optimisations on (the
    default, about twice as fast) ONNX Runtime fuses them into integer kernels. On x86 CPUs
    without VNNI (AVX2 only) its uint8 x int8 kernel sums pairs of products in saturating
    16-bit registers, which turned the default model's boats into obstacle on a quarter of a
    marina tile's pixels; there the session is given the same weights as uint8
    (:func:`weights_as_uint8`), whose kernel does not saturate (docs/results.md, "uint8
    weights on CPUs without VNNI").
    """

    def __init__(self, path: str | Path, threads: int | None = None,
                 reference_arithmetic: bool = False) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, None, "model file not found")
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
        self.reference_arithmetic = reference_arithmetic
        if reference_arithmetic:
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        source: str | bytes = str(self.path)
        try:
            import onnx

            graph_model = onnx.load(source)
        except Exception:  # protobuf raises several types; ONNX Runtime names the fault below
            graph_model = None
        self._int8_arithmetic = ("unknown" if graph_model is None
                                 else _int8_arithmetic(graph_model.graph, reference_arithmetic))
        if self._int8_arithmetic == UINT8_WEIGHTS:
            try:
                weights_as_uint8(graph_model)
                source = graph_model.SerializeToString()
            except Exception:  # e.g. protobuf's 2 GB limit: run the file as it is
                self._int8_arithmetic = f"fused ({SATURATING_CPU})"
        try:
            self.session = ort.InferenceSession(source, options,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # ORT raises its own exception types for bad files
            raise InputError(self.path, None, f"not a loadable ONNX model: {exc}") from exc
        meta = self.session.get_modelmeta().custom_metadata_map.get("harborsight")
        self.metadata = json.loads(meta) if meta else {}
        self.sidecar: dict = {}  # the export sidecar, filled by perception.default_model
        self.input_height, self.input_width = self._check_interface()

    def int8_arithmetic(self) -> str | None:
        """:func:`int8_arithmetic` of this session."""
        return self._int8_arithmetic

    def _check_interface(self) -> tuple[int, int]:
        """Reject graphs that are not a ``harborsight export``: one uint8 input ``image``
        (N, H, W, 3) with a fixed H and W, and outputs ``logits`` and ``labels``."""
        inputs = self.session.get_inputs()
        outputs = {o.name for o in self.session.get_outputs()}
        shape = inputs[0].shape if len(inputs) == 1 else []
        if (len(inputs) != 1 or inputs[0].name != "image" or inputs[0].type != "tensor(uint8)"
                or len(shape) != 4 or shape[3] != 3
                or not all(isinstance(d, int) for d in shape[1:3])):
            found = [(i.name, i.shape, i.type) for i in inputs]
            raise InputError(self.path, "inputs", "not a harborsight segmentation model: expected "
                             f"one uint8 input 'image' of shape (N, H, W, 3), found {found}")
        missing = {"logits", "labels"} - outputs
        if missing:
            raise InputError(self.path, "outputs", "not a harborsight segmentation model: "
                             f"missing output(s) {sorted(missing)}, found {sorted(outputs)}")
        logits = next(o for o in self.session.get_outputs() if o.name == "logits")
        channels = logits.shape[1] if len(logits.shape) == 4 else None
        if isinstance(channels, int) and channels != NUM_CLASSES:
            # a class id beyond harborsight's would stop a scoring run half way
            raise InputError(self.path, "outputs", f"'logits' has {channels} classes, "
                             f"harborsight's {NUM_CLASSES} are {', '.join(CLASS_NAMES)}")
        return int(shape[1]), int(shape[2])

    def batch_logits(self, images: np.ndarray, flips: int = 1) -> np.ndarray:
        """Float logits (N, C, H, W) of a batch of images (N, H, W, 3) at the model's input
        size. ``flips`` > 1 (:data:`~harborsight.perception.flips.FLIP_VIEWS`): test-time
        flips, each copy's logits flipped back, and ``log(mean softmax)`` over the copies
        returned, so that an argmax or a softmax of the result reads the averaged
        probabilities."""
        views = flip_views(flips)
        if len(views) == 1:
            return self.session.run(["logits"], {"image": np.ascontiguousarray(images)})[0]
        mean = None
        for mirror, upside_down in views:
            axes = (2,) * mirror + (1,) * upside_down          # W and H of (N, H, W, 3)
            flipped = np.flip(images, axes) if axes else images
            logits = self.session.run(["logits"], {"image": np.ascontiguousarray(flipped)})[0]
            logits = np.flip(logits, tuple(a + 1 for a in axes)) if axes else logits  # (N, C, H, W)
            probability = class_probabilities(logits, axis=1)
            mean = probability if mean is None else mean + probability
        return np.log(mean / len(views) + 1e-12).astype(np.float32)

    def logits(self, image_bgr: np.ndarray, flips: int = 1) -> np.ndarray:
        """Float logits (C, H, W) at the model's input size (``flips``: :meth:`batch_logits`)."""
        return self.batch_logits(self.fit(image_bgr)[None], flips)[0]

    def segment(self, image_bgr: np.ndarray, flips: int = 1) -> np.ndarray:
        """uint8 class labels (H, W) at the frame's own size (``flips``: :meth:`batch_logits`)."""
        h, w = image_bgr.shape[:2]
        image = self.fit(image_bgr)[None]
        if (h, w) == (self.input_height, self.input_width) and flips == 1:
            return self.session.run(["labels"], {"image": image})[0][0]
        return self.frame_labels(self.batch_logits(image, flips)[0], w, h)

    def segment_with_confidence(self, image_bgr: np.ndarray, flips: int = 1
                                ) -> tuple[np.ndarray, SolidConfidence]:
        """The labels of :meth:`segment` and, from the same model call, the model's solid
        probability at any pixel (:class:`~harborsight.perception.confidence.SolidConfidence`).
        A frame no larger than the input (a 256x256 tile) is enlarged without stretching and
        padded, as ``segment --mode auto`` does
        (:func:`~harborsight.perception.segment_images.small_frame_logits`), so that the
        measuring pipelines see the masks ``segment`` shows."""
        from harborsight.perception.segment_images import labels_from_logits, small_frame_logits

        h, w = image_bgr.shape[:2]
        small = small_frame_logits(self, image_bgr, flips)
        if small is not None:
            return labels_from_logits(small, w, h), SolidConfidence(small, w, h)
        image = self.fit(image_bgr)[None]
        if (h, w) == (self.input_height, self.input_width) and flips == 1:
            logits, labels = self.session.run(["logits", "labels"], {"image": image})
            return labels[0], SolidConfidence(logits[0], w, h)
        logits = self.batch_logits(image, flips)[0]
        return self.frame_labels(logits, w, h), SolidConfidence(logits, w, h)

    @staticmethod
    def frame_labels(logits: np.ndarray, w: int, h: int) -> np.ndarray:
        """Labels at the frame's size ``w`` x ``h`` from logits on the model's grid."""
        # cv2.resize maps pixel centres to pixel centres: x_src = (x + 0.5)·W_m/w - 0.5
        upsampled = cv2.resize(np.ascontiguousarray(logits.transpose(1, 2, 0)), (w, h),
                               interpolation=cv2.INTER_LINEAR)
        return upsampled.reshape(h, w, -1).argmax(axis=2).astype(np.uint8)

    def fit(self, image_bgr: np.ndarray) -> np.ndarray:
        """The frame resized to the model's input."""
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected a uint8 BGR image (H, W, 3), got {image_bgr.shape} "
                             f"{image_bgr.dtype}")
        h, w = image_bgr.shape[:2]
        if (h, w) != (self.input_height, self.input_width):
            shrink = w * h > self.input_width * self.input_height
            image_bgr = cv2.resize(image_bgr, (self.input_width, self.input_height),
                                   interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        return np.ascontiguousarray(image_bgr)
