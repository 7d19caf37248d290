"""Bootstrapped cross-entropy against a hand computation; schedules; parameter groups."""

import math

import pytest
import torch

from harborsight.perception.networks import create_network
from harborsight.training.losses import (
    BootstrappedCrossEntropy,
    agreeing_distillation_loss,
    bootstrap_keep_fraction,
    bootstrapped_cross_entropy,
)
from harborsight.training.optim import parameter_groups, poly_learning_rate


def test_bootstrapped_loss_by_hand():
    # one image, 2 classes, 4 pixels; the last pixel is ignored
    logits = torch.tensor([[[[2.0, 0.0], [0.0, 1.0]],      # class 0 scores
                            [[0.0, 0.0], [3.0, 5.0]]]])    # class 1 scores
    target = torch.tensor([[[0, 1], [1, 255]]])

    def ce(z_true, z_other):
        return -(z_true - math.log(math.exp(z_true) + math.exp(z_other)))

    losses = sorted([ce(2.0, 0.0), ce(0.0, 0.0), ce(3.0, 0.0)], reverse=True)
    assert bootstrapped_cross_entropy(logits, target, 1.0).item() == pytest.approx(sum(losses) / 3)
    # keep 50 % of 3 valid pixels -> ceil(1.5) = 2 hardest
    assert bootstrapped_cross_entropy(logits, target, 0.5).item() == pytest.approx(sum(losses[:2]) / 2)
    assert bootstrapped_cross_entropy(logits, target, 0.1).item() == pytest.approx(losses[0])


def test_pixel_weights_scale_each_loss_before_the_hardest_are_chosen():
    logits = torch.tensor([[[[2.0, 0.0], [0.0, 1.0]],
                            [[0.0, 0.0], [3.0, 5.0]]]])
    target = torch.tensor([[[0, 1], [1, 255]]])

    def ce(z_true, z_other):
        return -(z_true - math.log(math.exp(z_true) + math.exp(z_other)))

    easy, middle, hard = ce(2.0, 0.0), ce(0.0, 0.0), ce(3.0, 0.0)   # pixels (0,0), (0,1), (1,0)
    ones = torch.ones(1, 2, 2)
    assert bootstrapped_cross_entropy(logits, target, 1.0, pixel_weights=ones).item() == \
        pytest.approx(bootstrapped_cross_entropy(logits, target, 1.0).item())
    # the easy pixel weighted x40 becomes the hardest one: 40 * 0.127 = 5.08 > 3.05
    weights = torch.tensor([[[40.0, 1.0], [1.0, 7.0]]])     # the ignored pixel's weight is moot
    assert bootstrapped_cross_entropy(logits, target, 1.0, pixel_weights=weights).item() == \
        pytest.approx((40 * easy + middle + hard) / 3)
    assert bootstrapped_cross_entropy(logits, target, 0.1, pixel_weights=weights).item() == \
        pytest.approx(40 * easy)
    with pytest.raises(ValueError, match="pixel_weights"):
        bootstrapped_cross_entropy(logits, target, 1.0, pixel_weights=torch.ones(1, 4))


def test_loss_is_a_mean_over_images_and_handles_empty_images():
    torch.manual_seed(0)
    logits = torch.randn(2, 3, 4, 5, requires_grad=True)
    target = torch.randint(0, 3, (2, 4, 5))
    target[1] = 255
    both = bootstrapped_cross_entropy(logits, target, 0.3)
    first = bootstrapped_cross_entropy(logits[:1], target[:1], 0.3)
    assert both.item() == pytest.approx(first.item() / 2)
    both.backward()
    assert logits.grad is not None and torch.all(logits.grad[1] == 0)



def test_distillation_loss_by_hand_on_the_pixels_the_teacher_gets_right():
    """T²·KL(softmax(t/T) ‖ softmax(s/T)), averaged over the valid pixels whose teacher argmax
    is the label; computed here with plain arithmetic on a 1x3 image."""
    teacher = torch.tensor([[[[2.0, 0.0, 1.0]], [[0.0, 3.0, 0.0]], [[0.0, 0.0, 0.5]]]])
    student = torch.tensor([[[[1.0, 0.0, 0.0]], [[0.0, 1.0, 2.0]], [[1.0, 0.0, 0.0]]]])
    # pixel 0: teacher says 0, label 0 (kept); pixel 1: teacher 1, label 2 (dropped);
    # pixel 2: teacher 0, label 255 (ignored)
    target = torch.tensor([[[0, 2, 255]]])
    temperature = 2.0
    t = [math.exp(v / temperature) for v in (2.0, 0.0, 0.0)]
    s = [math.exp(v / temperature) for v in (1.0, 0.0, 1.0)]
    p = [v / sum(t) for v in t]
    q = [v / sum(s) for v in s]
    by_hand = temperature**2 * sum(pi * math.log(pi / qi) for pi, qi in zip(p, q, strict=True))
    loss = agreeing_distillation_loss(student, teacher, target, temperature)
    assert float(loss) == pytest.approx(by_hand, rel=1e-6)
    assert float(agreeing_distillation_loss(teacher, teacher, target)) == pytest.approx(0, abs=1e-7)
    # no pixel where the teacher is right: zero, and still differentiable
    wrong = student.clone().requires_grad_(True)
    none = agreeing_distillation_loss(wrong, teacher, torch.tensor([[[1, 0, 255]]]))
    none.backward()
    assert float(none.detach()) == 0.0 and wrong.grad is not None
    # the gradient pulls the student's kept pixel toward the teacher's class
    pulled = student.clone().requires_grad_(True)
    agreeing_distillation_loss(pulled, teacher, target, temperature).backward()
    assert pulled.grad[0, 0, 0, 0] < 0 and pulled.grad[0, :, 0, 1:].abs().max() == 0
    with pytest.raises(ValueError, match="temperature must be positive"):
        agreeing_distillation_loss(student, teacher, target, 0.0)
    with pytest.raises(ValueError, match="differ from teacher"):
        agreeing_distillation_loss(student[..., :2], teacher, target)


def test_keep_fraction_schedule():
    values = [bootstrap_keep_fraction(i) for i in (0, 1000, 5000, 9000, 20000)]
    assert values == pytest.approx([1.0, 1.0, 0.6, 0.2, 0.2])
    loss = BootstrappedCrossEntropy(start_iteration=0, end_iteration=10, end_fraction=0.5)
    logits, target = torch.randn(1, 3, 8, 8), torch.randint(0, 3, (1, 8, 8))
    assert loss(logits, target, 10).item() == pytest.approx(
        bootstrapped_cross_entropy(logits, target, 0.5).item())


def test_poly_schedule_and_parameter_groups():
    assert poly_learning_rate(0.01, 0, 100) == pytest.approx(0.01)
    assert poly_learning_rate(0.01, 50, 100) == pytest.approx(0.01 * 0.5**0.9)
    assert poly_learning_rate(0.01, 100, 100) == 0.0
    network = create_network("ddrnet23_slim", 3)
    decay, no_decay = parameter_groups(network, 5e-4)
    assert decay["weight_decay"] == 5e-4 and no_decay["weight_decay"] == 0.0
    assert all(p.ndim >= 2 for p in decay["params"]) and all(p.ndim == 1 for p in no_decay["params"])
    assert len(decay["params"]) + len(no_decay["params"]) == len(list(network.parameters()))
