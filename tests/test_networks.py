"""Shared checks over every network: shapes at odd sizes, backward, ONNX equivalence,
and parameter counts equal to the reference implementations'."""

import numpy as np
import pytest
import torch

from harborsight.perception.export import export_onnx, onnx_max_abs_difference
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import (
    NETWORKS,
    create_network,
    inference_parameter_count,
    parameter_count,
)
from harborsight.perception.onnx_segmenter import OnnxSegmenter

#: Inference-graph parameters with 19 classes (Cityscapes), as the reference implementations
#: count them (README, "Segmentation networks").
REFERENCE_PARAMS_19 = {
    "bisenetv2": 3_358_627,       # CoinCheung/BiSeNet lib/models/bisenetv2.py, aux_mode="eval"
    "fchardnet70": 4_119_257,     # PingoLH/FCHarDNet ptsemseg/models/hardnet.py
    "ddrnet23_slim": 5_695_987,   # ydhongHIT/DDRNet segmentation/DDRNet_23_slim.py, no aux head
    "ddrnet23": 20_148_947,       # ydhongHIT/DDRNet segmentation/DDRNet_23.py, no aux head
}


@pytest.fixture(params=list(NETWORKS))
def name(request) -> str:
    return request.param


def images(n: int, h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, h, w, 3), dtype=np.uint8)


def test_eval_forward_at_odd_sizes(name):
    torch.manual_seed(0)
    model = SegmentationModel(create_network(name, 3)).eval()
    with torch.no_grad():
        for h, w in ((45, 70), (97, 33)):
            logits = model(torch.from_numpy(images(1, h, w)))
            assert logits.shape == (1, 3, h, w)
            assert torch.isfinite(logits).all()


def test_train_forward_backward(name):
    torch.manual_seed(0)
    model = SegmentationModel(create_network(name, 3)).train()
    batch = torch.from_numpy(images(2, 70, 90))
    target = torch.randint(0, 3, (2, 70, 90))
    out = model(batch)
    main, aux = out if isinstance(out, tuple) else (out, [])
    assert main.shape == (2, 3, 70, 90) and all(a.shape == main.shape for a in aux)
    loss = torch.nn.functional.cross_entropy(main, target) + sum(
        torch.nn.functional.cross_entropy(a, target) for a in aux)
    loss.backward()
    network = model.network
    aux_ids = {id(p) for p in network.aux_heads.parameters()} if network.aux_heads else set()
    missing = [n for n, p in network.named_parameters() if p.grad is None and id(p) not in aux_ids]
    assert not missing, missing[:5]


def test_onnx_export_matches_torch(name, tmp_path):
    torch.manual_seed(0)
    model = SegmentationModel(create_network(name, 3, aux_heads=False)).eval()
    path = export_onnx(model, tmp_path / f"{name}.onnx", 72, 100, {"network": name})
    assert onnx_max_abs_difference(model, path, images(2, 72, 100)) <= 1e-3
    segmenter = OnnxSegmenter(path)
    assert segmenter.metadata["network"] == name
    frame = images(1, 72, 100, seed=5)[0]
    with torch.no_grad():
        expected = model(torch.from_numpy(frame[None])).argmax(1)[0].numpy()
    assert (segmenter.segment(frame) == expected).mean() > 0.999
    # another size: the frame resized to the input, the logits bilinearly back (torch's
    # interpolate with align_corners=False maps pixel centres the same way)
    big = images(1, 144, 200, seed=6)[0]
    with torch.no_grad():
        logits = torch.from_numpy(segmenter.logits(big))[None]
        expected = torch.nn.functional.interpolate(logits, size=(144, 200), mode="bilinear",
                                                   align_corners=False).argmax(1)[0].numpy()
    assert (segmenter.segment(big) == expected).mean() > 0.999


def test_parameter_counts_match_reference(name):
    network = create_network(name, 19, aux_heads=True)
    assert inference_parameter_count(network) == REFERENCE_PARAMS_19[name]
    assert parameter_count(create_network(name, 19, aux_heads=False)) == REFERENCE_PARAMS_19[name]


@pytest.mark.parametrize("graph", ["identity", "float_input"])
def test_a_foreign_onnx_model_is_refused_at_load(graph, tmp_path):
    """A loadable ONNX graph that is not a `harborsight export` names the file and what is
    wrong, instead of failing on every frame later."""
    import onnx
    from onnx import TensorProto, helper

    from harborsight.errors import InputError

    dtype = TensorProto.UINT8 if graph == "identity" else TensorProto.FLOAT
    node = helper.make_node("Identity", ["image"], ["out"])
    model = helper.make_model(helper.make_graph(
        [node], "foreign", [helper.make_tensor_value_info("image", dtype, [1, 8, 8, 3])],
        [helper.make_tensor_value_info("out", dtype, [1, 8, 8, 3])]),
        opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    path = tmp_path / "foreign.onnx"
    onnx.save(model, path)
    field = "outputs" if graph == "identity" else "inputs"
    with pytest.raises(InputError, match=rf"foreign.onnx: {field}: not a harborsight"):
        OnnxSegmenter(path)


def test_int8_keeps_the_classifier_tail_in_float(tmp_path):
    """Static int8 of the whole graph left the classifier's logits on a uint8 grid: on an
    untrained BiSeNetV2, 1.5 % of pixels tied between two classes, and ArgMax gives a tie
    to water. The backbone is int8; from the last Conv on the logits are float."""
    import onnx

    from harborsight.perception.quantization import quantize_int8

    torch.manual_seed(0)
    model = SegmentationModel(create_network("bisenetv2", 3, aux_heads=False)).eval()
    fp32 = export_onnx(model, tmp_path / "m.onnx", 64, 96, {"network": "bisenetv2"})
    int8 = quantize_int8(fp32, tmp_path / "m.int8.onnx", images(4, 64, 96, seed=1))
    nodes = list(onnx.load(str(int8)).graph.node)
    last_conv = max(i for i, n in enumerate(nodes) if n.op_type == "Conv")
    assert any(n.op_type == "QuantizeLinear" for n in nodes[:last_conv])
    assert not any(n.op_type in ("QuantizeLinear", "DequantizeLinear")
                   for n in nodes[last_conv:])
    segmenter = OnnxSegmenter(int8)
    frame = images(1, 64, 96, seed=7)[0]
    logits = np.sort(segmenter.logits(frame), axis=0)
    assert (logits[-1] == logits[-2]).mean() < 1e-3


def test_percentile_calibration_clips_the_activation_ranges(tmp_path):
    """``percentile`` sets each activation's int8 range from a high percentile of what the
    calibration images produce, ``minmax`` from the extremes: no range is wider, some are
    narrower, and the model still agrees with float on most pixels. Bad options are refused."""
    import onnx
    from onnx import numpy_helper

    from harborsight.errors import InputError
    from harborsight.perception.quantization import quantize_int8

    torch.manual_seed(0)
    model = SegmentationModel(create_network("bisenetv2", 3, aux_heads=False)).eval()
    fp32 = export_onnx(model, tmp_path / "m.onnx", 64, 96, {"network": "bisenetv2"})
    calibration = images(4, 64, 96, seed=1)

    def activation_scales(path) -> dict[str, float]:
        graph = onnx.load(str(path)).graph
        values = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
        return {n.input[0]: float(values[n.input[1]]) for n in graph.node
                if n.op_type == "QuantizeLinear" and values[n.input[1]].size == 1}

    minmax = activation_scales(quantize_int8(fp32, tmp_path / "a.onnx", calibration))
    clipped = activation_scales(quantize_int8(fp32, tmp_path / "b.onnx", calibration,
                                              "percentile", 99.0))
    shared = sorted(set(minmax) & set(clipped))
    assert len(shared) > 10
    assert all(clipped[k] <= minmax[k] * (1 + 1e-6) for k in shared)
    assert sum(clipped[k] < 0.9 * minmax[k] for k in shared) >= len(shared) // 4
    frame = images(1, 64, 96, seed=7)[0]
    agree = np.mean(OnnxSegmenter(tmp_path / "b.onnx").segment(frame)
                    == OnnxSegmenter(fp32).segment(frame))
    assert agree > 0.8
    for method, percentile, field in (("entropy", 99.9, "calibration_method"),
                                      ("percentile", 40.0, "calibration_percentile"),
                                      ("percentile", float("nan"), "calibration_percentile")):
        with pytest.raises(InputError, match=field):
            quantize_int8(fp32, tmp_path / "c.onnx", calibration, method, percentile)


def test_reference_arithmetic_runs_the_int8_graph_as_written(tmp_path):
    """With ``reference_arithmetic`` ONNX Runtime computes dequantise, float convolution,
    quantise, as the graph says, on every CPU. The default (fused) session gives the same
    logits: on x86 without VNNI, where a plain ONNX Runtime session's uint8 x int8 kernel
    saturates (class 1's logit 65,400, not 129,600), it runs the weights as uint8."""
    import onnxruntime as ort

    from harborsight.perception.onnx_segmenter import (
        SATURATING_CPU,
        UINT8_WEIGHTS,
        cpu_int8_dot_product,
    )
    from tests.int8_models import (
        EXACT_LOGITS,
        HEIGHT,
        WIDTH,
        qoperator_model,
        saturating_qdq_model,
    )

    path = saturating_qdq_model(tmp_path / "sat.onnx")
    white = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    exact = np.array(EXACT_LOGITS)[:, None, None] * np.ones((1, HEIGHT, WIDTH))
    segmenter = OnnxSegmenter(path, reference_arithmetic=True)
    logits = segmenter.logits(white)
    assert logits.shape == (3, HEIGHT, WIDTH)
    np.testing.assert_array_equal(logits, exact)
    assert (segmenter.segment(white) == 1).all()
    assert segmenter.int8_arithmetic() == "reference"
    fused = OnnxSegmenter(path)
    np.testing.assert_array_equal(fused.logits(white), exact)
    assert (fused.segment(white) == 1).all()
    saturating = cpu_int8_dot_product() == SATURATING_CPU
    assert fused.int8_arithmetic() == (UINT8_WEIGHTS if saturating
                                       else f"fused ({cpu_int8_dot_product()})")
    if saturating:      # the saturation itself, in a plain session of the int8 weights
        plain = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        assert plain.run(["logits"], {"image": white[None]})[0][0, 1, 0, 0] == 65_400.0
    # a QOperator graph computes in integers whatever the options, and says so
    integer = OnnxSegmenter(qoperator_model(tmp_path / "q.onnx"), reference_arithmetic=True)
    assert integer.int8_arithmetic().startswith("integer operators (")
    assert OnnxSegmenter(tmp_path / "q.onnx").logits(white).shape == (3, HEIGHT, WIDTH)


def test_weights_as_uint8_are_the_same_numbers(tmp_path):
    """``weights_as_uint8`` shifts int8 weights and their zero points by 128: the graph as
    written gives bit-identical logits for the hand-built model and the default model, and
    no int8 weight is left; a weight and a zero point shared by two nodes are shifted once."""
    import onnx

    from harborsight.perception.default_model import default_model_path
    from harborsight.perception.onnx_segmenter import (
        _int8_weight_dequantizers,
        weights_as_uint8,
    )
    from tests.int8_models import HEIGHT, WIDTH, saturating_qdq_model

    white = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    frame = np.random.default_rng(3).integers(0, 256, (90, 160, 3), np.uint8)
    for source, image in ((saturating_qdq_model(tmp_path / "sat.onnx"), white),
                          (default_model_path(), frame)):
        model = onnx.load(str(source))
        changed = weights_as_uint8(model)
        assert changed > 0 and not _int8_weight_dequantizers(model.graph)
        shifted = tmp_path / f"u8-{changed}.onnx"
        onnx.save(model, str(shifted))
        before = OnnxSegmenter(source, reference_arithmetic=True).logits(image)
        after = OnnxSegmenter(shifted, reference_arithmetic=True).logits(image)
        np.testing.assert_array_equal(before, after)
    # one int8 weight and one zero point read by two DequantizeLinear nodes
    model = onnx.load(str(tmp_path / "sat.onnx"))
    twin = onnx.helper.make_node("DequantizeLinear", ["wq", "one", "zero_s8"], ["wd2"])
    model.graph.node.insert(5, twin)
    assert weights_as_uint8(model) == 2
    names = {t.name: onnx.numpy_helper.to_array(t) for t in model.graph.initializer}
    assert "wq" not in names and "zero_s8" not in names
    assert names["zero_s8_as_uint8"] == 128 and names["wq_as_uint8"][1].max() == 255


def test_weights_as_uint8_leaves_what_it_cannot_shift(tmp_path):
    """A zero point made by a Constant node, and weights that are also graph inputs, are
    left as they are (no crash, the model still loads and runs); an int8 initialiser that a
    subgraph still reads is kept beside its uint8 copy, and a name already taken is not
    reused."""
    import onnx
    from onnx import helper, numpy_helper

    from harborsight.perception.onnx_segmenter import _int8_weight_dequantizers, weights_as_uint8
    from tests.int8_models import HEIGHT, WIDTH, saturating_qdq_model

    path = saturating_qdq_model(tmp_path / "sat.onnx")
    white = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    # the zero point from a Constant node
    model = onnx.load(str(path))
    zero = next(t for t in model.graph.initializer if t.name == "zero_s8")
    model.graph.node.insert(0, helper.make_node("Constant", [], ["zero_s8"], value=zero))
    model.graph.initializer.remove(zero)
    assert weights_as_uint8(model) == 0
    onnx.save(model, str(tmp_path / "constant.onnx"))
    assert OnnxSegmenter(tmp_path / "constant.onnx").logits(white).shape == (3, HEIGHT, WIDTH)
    # the weights also a graph input (an export that keeps initialisers as inputs)
    model = onnx.load(str(path))
    model.graph.input.append(helper.make_tensor_value_info("wq", onnx.TensorProto.INT8, [3, 4, 1, 1]))
    assert not _int8_weight_dequantizers(model.graph) and weights_as_uint8(model) == 0
    # read by a subgraph too, and "wq_as_uint8" already taken
    model = onnx.load(str(path))
    model.graph.initializer.append(numpy_helper.from_array(np.zeros(1, np.float32), "wq_as_uint8"))
    branch = helper.make_graph([helper.make_node("Identity", ["wq"], ["w_out"])], "branch", [],
                               [helper.make_tensor_value_info("w_out", onnx.TensorProto.INT8, None)])
    model.graph.node.append(helper.make_node("If", ["cond"], ["w_if"], then_branch=branch,
                                             else_branch=branch))
    assert weights_as_uint8(model) == 1
    names = [t.name for t in model.graph.initializer]
    assert "wq" in names and names.count("wq_as_uint8") == 1 and "wq_as_uint8_1" in names


def test_cpu_flags_come_from_py_cpuinfo_without_proc_cpuinfo(monkeypatch):
    """Where /proc/cpuinfo is missing (Windows, macOS) py-cpuinfo's flags decide."""
    import cpuinfo

    from harborsight.perception import onnx_segmenter

    monkeypatch.setattr(onnx_segmenter, "_linux_cpu_flags", lambda: None)
    read = onnx_segmenter.cpu_int8_dot_product.__wrapped__
    for flags, kind in ((["sse4_2", "avx2"], "avx2 without vnni"),
                        (["avx2", "avx512f", "avx512vnni"], "vnni"), (["neon"], "unknown")):
        monkeypatch.setattr(cpuinfo, "get_cpu_info", lambda flags=flags: {"flags": flags})
        assert read() == kind
