"""LiDAR extrinsics (perception/extrinsics.py): the ZYX convention, the inverse, float32 clouds."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from perception.extrinsics import apply, inverse, pose_matrix


def test_yaw_then_pitch_then_roll_and_a_positive_pitch_looks_down():
    # the front-left sensor: turned 45° left, tilted 15° down; its x axis in the vehicle frame
    m = pose_matrix(3.3, 0.95, 0.9, 0.0, math.radians(15), math.radians(45))
    forward = m[:3, :3] @ [1.0, 0.0, 0.0]
    c, s = math.cos(math.radians(15)), math.sin(math.radians(15))
    assert forward == pytest.approx([c / math.sqrt(2), c / math.sqrt(2), -s])
    assert m[:3, :3] @ [0.0, 1.0, 0.0] == pytest.approx([-1 / math.sqrt(2), 1 / math.sqrt(2), 0.0])  # y stays level
    # roll last: about the sensor's own (already turned and tilted) x axis, which it keeps
    rolled = pose_matrix(0, 0, 0, 0.3, math.radians(15), math.radians(45))
    assert rolled[:3, :3] @ [1.0, 0.0, 0.0] == pytest.approx(forward)
    assert apply(m, np.zeros((1, 3))) == pytest.approx(np.array([[3.3, 0.95, 0.9]]))


@settings(max_examples=50, deadline=None)
@given(pose=st.tuples(*[st.floats(-5, 5)] * 3, *[st.floats(-math.pi, math.pi)] * 3))
def test_the_inverse_undoes_the_transform(pose):
    m = pose_matrix(*pose)
    assert inverse(m) @ m == pytest.approx(np.eye(4), abs=1e-12)
    assert np.linalg.det(m[:3, :3]) == pytest.approx(1.0)
    points = np.random.default_rng(0).uniform(-50, 50, (1000, 3)).astype(np.float32)
    moved = apply(m, points)
    assert moved.dtype == np.float32 and moved.shape == (1000, 3)
    exact = points.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    assert np.abs(moved - exact).max() < 1e-4  # float32 of ~50 m: ~4 µm
    assert np.abs(apply(inverse(m), moved) - points).max() < 1e-4


def test_an_empty_cloud():
    assert apply(np.eye(4), np.zeros((0, 3))).shape == (0, 3)
