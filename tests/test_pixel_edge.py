"""The pixel-boundary correction (harborsight.clearance.pixel_edge), against analytic edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from harborsight.clearance.obstacles import ObstacleContours
from harborsight.clearance.pixel_edge import edge_shift_px, square_exit_px

SIZE = 120


def _contours(solid: np.ndarray) -> ObstacleContours:
    """Every contour of a bool mask, as :func:`obstacle_contours` lists them."""
    found, _ = cv2.findContours(solid.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    lengths = np.array([len(c) for c in found])
    points = np.concatenate(found).reshape(-1, 2)
    next_index = np.arange(1, len(points) + 1)
    ends = np.cumsum(lengths)
    next_index[ends - 1] = ends - lengths
    h, w = solid.shape
    on_border = ((points[:, 0] == 0) | (points[:, 0] == w - 1)
                 | (points[:, 1] == 0) | (points[:, 1] == h - 1))
    return ObstacleContours(points, next_index, np.zeros(len(points), bool), on_border)


def _reading_error_px(solid: np.ndarray, hull: np.ndarray, true_px: float,
                      rule: str) -> float:
    """The nearest contour pixel's distance to ``hull`` less its correction, minus the truth."""
    contours = _contours(solid)
    points = contours.points_px.astype(float)
    distance = np.hypot(*(hull - points).T)
    distance[contours.on_border] = np.inf
    best = int(np.argmin(distance))
    unit = ((hull - points[best]) / distance[best])[None]
    shift = (edge_shift_px(contours, np.array([best]), unit) if rule == "line"
             else square_exit_px(unit))[0]
    return float(distance[best] - shift - true_px)


def _half_plane(rng: np.random.Generator, clear_px: float):
    """A solid half-plane sampled at pixel centres (a pixel is solid where its centre is),
    at a random angle and sub-pixel offset, and a hull point ``clear_px`` off its edge."""
    angle = rng.uniform(0.0, 2 * np.pi)
    outward = np.array([np.cos(angle), np.sin(angle)])
    on_edge = np.array([SIZE / 2, SIZE / 2]) + rng.uniform(-0.5, 0.5, 2)
    v, u = np.mgrid[0:SIZE, 0:SIZE]
    centres = np.stack([u, v], axis=-1).astype(float)
    solid = (centres - on_edge) @ outward <= 0
    return solid, on_edge + clear_px * outward


@pytest.mark.parametrize("clear_px", [8.0, 30.0])
def test_straight_edges_read_without_the_square_rules_half_pixel(clear_px):
    """Against the analytic distance of a point from a line: over random slanted edges the
    square rule reads short by a third of a pixel or more on average, the line rule within a
    tenth (both measured on the same rasterised edges)."""
    rng = np.random.default_rng(11)
    square, line = [], []
    for _ in range(300):
        solid, hull = _half_plane(rng, clear_px)
        square.append(_reading_error_px(solid, hull, clear_px, "square"))
        line.append(_reading_error_px(solid, hull, clear_px, "line"))
    square, line = np.array(square), np.array(line)
    assert square.mean() < -0.25
    assert abs(line.mean()) < 0.1 and np.abs(line).mean() < 0.15
    assert np.abs(line).max() < 1.0           # within a pixel, every one


def test_an_edge_along_a_pixel_row_moves_half_a_pixel():
    solid = np.zeros((SIZE, SIZE), bool)
    solid[60:, :] = True                       # rows 60 and down solid; the hull above
    hull = np.array([55.0, 40.0])
    contours = _contours(solid)
    points = contours.points_px.astype(float)
    best = int(np.argmin(np.where(contours.on_border, np.inf, np.hypot(*(hull - points).T))))
    unit = ((hull - points[best]) / np.hypot(*(hull - points[best])))[None]
    assert edge_shift_px(contours, np.array([best]), unit)[0] == pytest.approx(0.5)


def test_a_corner_or_a_speck_keeps_the_square_rule_and_no_shift_exceeds_it():
    rng = np.random.default_rng(5)
    # a 90-degree corner pointing at the hull: its contour bends within the fitted window
    solid = np.zeros((SIZE, SIZE), bool)
    v, u = np.mgrid[0:SIZE, 0:SIZE]
    solid[(u - 60) + (v - 60) >= 0] = True
    solid &= (u - 60) - (v - 60) <= 0
    contours = _contours(solid)
    tip = int(np.flatnonzero((contours.points_px == [60, 60]).all(axis=1))[0])
    unit = np.array([[-np.sqrt(0.5), -np.sqrt(0.5)]])
    assert edge_shift_px(contours, np.array([tip]), unit)[0] == pytest.approx(
        square_exit_px(unit)[0])
    # a speck of 3 pixels: its contour is shorter than the window
    speck = np.zeros((SIZE, SIZE), bool)
    speck[50, 50:53] = True
    contours = _contours(speck)
    unit = np.array([[0.0, -1.0]])
    assert edge_shift_px(contours, np.array([0]), unit)[0] == pytest.approx(0.5)
    # not a contour pixel (-1): the square rule
    assert edge_shift_px(contours, np.array([-1]), unit)[0] == pytest.approx(0.5)
    for _ in range(100):
        solid, hull = _half_plane(rng, 20.0)
        contours = _contours(solid)
        index = rng.integers(0, len(contours.points_px), 5)
        rays = hull - contours.points_px[index]
        rays /= np.hypot(*rays.T)[:, None]
        shift = edge_shift_px(contours, index, rays)
        assert (shift >= 0).all() and (shift <= square_exit_px(rays) + 1e-12).all()
