"""ares.core.geometry: angles and the projection of a point onto polyline segments."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ares.core.geometry import project_on_segment, project_on_segments, signed_distance, wrap_angle

coordinates = st.floats(-50.0, 50.0)


@given(st.floats(-100.0, 100.0))
def test_wrap_angle_is_the_same_direction_in_minus_pi_to_pi(a):
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.cos(w) == pytest.approx(math.cos(a), abs=1e-9) and math.sin(w) == pytest.approx(math.sin(a), abs=1e-9)


def test_wrap_angle_of_pi_is_minus_pi():
    assert wrap_angle(math.pi) == -math.pi
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


def test_the_foot_is_clamped_to_the_segment_unless_that_side_extends():
    # segment from (0, 0) to (10, 0); the point 2 m past its end and 1 m to the left
    assert project_on_segment(12.0, 1.0, 0.0, 0.0, 10.0, 0.0) == (1.0, 5.0)
    assert project_on_segment(12.0, 1.0, 0.0, 0.0, 10.0, 0.0, extend_ahead=True) == (1.2, 1.0)
    assert project_on_segment(-3.0, -1.0, 0.0, 0.0, 10.0, 0.0, extend_back=True) == (-0.3, 1.0)
    assert project_on_segment(-3.0, -1.0, 0.0, 0.0, 10.0, 0.0, extend_ahead=True) == (0.0, 10.0)
    assert project_on_segment(4.0, 3.0, 1.0, 1.0, 0.0, 0.0) == (0.0, 13.0)  # a segment of no length


def test_the_signed_distance_is_positive_to_the_left():
    t, d2 = project_on_segment(5.0, 2.0, 0.0, 0.0, 10.0, 0.0)
    assert signed_distance(5.0, 2.0, 0.0, 0.0, 10.0, 0.0, d2) == 2.0
    t, d2 = project_on_segment(5.0, -2.0, 0.0, 0.0, 10.0, 0.0)
    assert signed_distance(5.0, -2.0, 0.0, 0.0, 10.0, 0.0, d2) == -2.0
    assert signed_distance(5.0, 0.0, 0.0, 0.0, 10.0, 0.0, 0.0) == 0.0


segments = st.lists(
    st.tuples(coordinates, coordinates, st.floats(-5.0, 5.0), st.floats(-5.0, 5.0), st.booleans(), st.booleans()),
    min_size=1,
    max_size=20,
)


@given(x=coordinates, y=coordinates, segments=segments)
def test_the_array_form_gives_what_the_scalar_form_gives(x, y, segments):
    ax, ay, ex, ey, back, ahead = (np.array(column) for column in zip(*segments))
    t, d2 = project_on_segments(x, y, ax, ay, ex, ey, back, ahead)
    for k, segment in enumerate(segments):
        scalar_t, scalar_d2 = project_on_segment(x, y, *segment)
        assert t[k] == scalar_t
        # the squares may differ in the last bit: Python's ** 2 calls the C library's pow(),
        # which does not always round as numpy's square (an exact product) does
        assert d2[k] == pytest.approx(scalar_d2, rel=1e-15, abs=1e-300)
