"""Point-cloud filters (perception/cloud_filters.py, ARES §3.5.1): the body's box, the near-field
ghost filter against its rule computed by brute force, and a realistic frame of the three
LiDARs (tests/lidar_scene.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core.config import load_vehicle
from perception.cloud_filters import BodyBox, CloudFilterParams, ghost_mask, keep_mask, self_hit_mask
from tests.helpers import lidar_scene

BODY = BodyBox(*lidar_scene.BODY)
ORIGINS = lidar_scene.ORIGINS


def test_the_body_box_comes_from_the_vehicle_profile():
    box = BodyBox.of(load_vehicle("ares_shuttle"), 2.6)  # length 3.93, wheelbase 2.8, width 1.99
    assert box == pytest.approx(lidar_scene.BODY)


def test_points_inside_the_grown_box_are_self_hits():
    points = np.array(
        [
            (1.0, 0.0, 1.0),
            (3.45, 0.5, 0.5),
            (-0.7, 0.0, 1.0),
            (1.0, 1.1, 2.0),
            (1.0, 0.0, 2.7),  # in, or within 0.15 m
            (3.6, 0.5, 0.5),
            (-0.8, 0.0, 1.0),
            (1.0, 1.2, 2.0),
            (1.0, 0.0, 2.8),
            (5.0, 0.0, 0.0),  # out
        ],
        np.float32,
    )
    assert self_hit_mask(points, BODY, 0.15).tolist() == [True] * 5 + [False] * 5
    assert self_hit_mask(points, BODY, 0.0).tolist()[:5] == [True, False, False, False, False]
    empty = np.zeros((0, 3), np.float32)
    assert keep_mask(empty, np.zeros(0, int), ORIGINS, BODY, CloudFilterParams()).shape == (0,)


def brute_force_ghosts(points, sensors, origins, body, near_field, radius, k, min_range):
    """The rule read literally: all pairwise distances."""
    near_box = body.grown(near_field)
    too_close = np.linalg.norm(points - origins[sensors], axis=1) < min_range
    kept = points[~too_close].astype(np.float64)
    ghost = too_close.copy()
    for i in np.flatnonzero(~too_close & near_box.contains(points)):
        others = (np.linalg.norm(kept - points[i].astype(np.float64), axis=1) <= radius).sum() - 1
        ghost[i] = others < k
    return ghost


def pedestrian(distance_m=1.5):
    """The front of a person `distance_m` ahead of the bumper as a corner LiDAR sees it from
    ~2 m: 0.2° between firings, 2° between rings."""
    y = np.arange(-0.25, 0.25, 0.007)
    z = np.arange(0.05, 1.75, 0.07)
    yy, zz = np.meshgrid(y, z)
    x = np.full(yy.size, BODY.x_max + distance_m)
    return np.column_stack([x, yy.ravel() + 0.6, zz.ravel()]).astype(np.float32)


def test_a_pedestrian_by_the_bumper_stays_lone_points_around_go_far_ones_stay():
    rng = np.random.default_rng(7)
    person = pedestrian()
    near = BODY.grown(4.0)
    lone = rng.uniform([near.x_min, near.y_min, 0.3], [near.x_max, near.y_max, 3.0], (150, 3)).astype(np.float32)
    lone = lone[~BODY.grown(0.5).contains(lone)]
    far = rng.uniform([12.0, -20.0, 0.0], [40.0, 20.0, 3.0], (100, 3)).astype(np.float32)
    points = np.concatenate([person, lone, far])
    sensors = np.ones(len(points), int)  # all from the front-left sensor
    ghost = ghost_mask(points, sensors, ORIGINS, BODY)
    assert not ghost[: len(person)].any()
    isolated = brute_force_ghosts(points, sensors, ORIGINS, BODY, 4.0, 0.3, 3, 0.5)[len(person) : -len(far)]
    assert isolated.mean() > 0.95 and (ghost[len(person) : -len(far)] == isolated).all()
    assert not ghost[-len(far) :].any()


def test_returns_closer_than_the_minimum_range_are_ghosts_even_in_a_crowd():
    sensor = ORIGINS[1]
    patch = (sensor + np.array([0.3, 0.3, -0.2]) + np.random.default_rng(1).normal(0, 0.02, (50, 3))).astype(np.float32)
    ghost = ghost_mask(patch, np.ones(50, int), ORIGINS, BODY, min_range_m=0.5)
    assert ghost.all()
    assert not ghost_mask(patch, np.ones(50, int), ORIGINS, BODY, min_range_m=0.3).any()
    per_sensor = [0.9, 0.3, 0.3]  # the roof's datasheet says more
    assert not ghost_mask(patch, np.ones(50, int), ORIGINS, BODY, min_range_m=per_sensor).any()
    assert ghost_mask(patch, np.zeros(50, int), ORIGINS[[1]], BODY, min_range_m=per_sensor[:1]).all()


def test_self_hits_do_not_vouch_for_a_ghost_beside_them():
    bumper = np.array([(BODY.x_max - 0.01, y, z) for y in np.arange(-0.5, 0.5, 0.02) for z in (0.5, 0.55, 0.6)])
    ghost = np.array([(BODY.x_max + 0.2, 0.0, 0.55)])
    points = np.concatenate([bumper, ghost]).astype(np.float32)
    sensors = np.ones(len(points), int)
    assert not ghost_mask(points, sensors, ORIGINS, BODY)[-1]  # judged among the self hits: kept
    keep = keep_mask(points, sensors, ORIGINS, BODY, CloudFilterParams())
    assert not keep.any()  # the bumper, then the ghost


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    radius=st.sampled_from([0.1, 0.3, 0.5]),
    k=st.integers(1, 6),
    near_field=st.sampled_from([1.0, 4.0]),
    ordered=st.booleans(),
)
def test_the_ghost_filter_is_exactly_its_rule(seed, n, radius, k, near_field, ordered):
    rng = np.random.default_rng(seed)
    # clusters of varied density, some near the body, some past the near field's edge
    centres = rng.uniform([-6.0, -6.0, -0.5], [9.0, 6.0, 3.0], (max(n // 15, 1), 3))
    points = centres[rng.integers(0, len(centres), n)] + rng.normal(0, rng.uniform(0.02, 0.5), (n, 3))
    points = points.astype(np.float32)
    if ordered:  # neighbours next to each other in the array, as along a LiDAR's rings: the filter's shortcut
        points = points[np.lexsort((points[:, 1], points[:, 0]))]
    sensors = rng.integers(0, 3, n)
    fast = ghost_mask(points, sensors, ORIGINS, BODY, near_field, radius, k, 0.5)
    slow = brute_force_ghosts(points, sensors, ORIGINS, BODY, near_field, radius, k, 0.5)
    assert fast.tolist() == slow.tolist()


def test_a_frame_of_the_three_lidars():
    frame = lidar_scene.frame()
    rng = np.random.default_rng(3)
    near = BODY.grown(4.0)
    ghosts = rng.uniform([near.x_min, near.y_min, 0.3], [near.x_max, near.y_max, 2.5], (300, 3)).astype(np.float32)
    # in the air, not beside the body or an obstacle (a ghost that close has real neighbours)
    for box in (lidar_scene.BODY, *lidar_scene.SCENE):
        ghosts = ghosts[~BodyBox(*box).grown(0.35).contains(ghosts)]
    points = np.concatenate([frame.points, ghosts])
    sensors = np.concatenate([frame.sensor, rng.integers(0, 3, len(ghosts))])
    keep = keep_mask(points, sensors, ORIGINS, BODY, CloudFilterParams())
    real = keep[: len(frame.points)]
    assert not real[frame.body].any()  # every self hit
    assert not keep[len(frame.points) :].any()  # every ghost
    person = BodyBox(5.0, 5.4, 1.8, 2.3, 0.0, 1.75).grown(0.02).contains(frame.points) & ~frame.body
    assert person.sum() > 100 and real[person].all()
    assert len(ghosts) > 200 and (~real[~frame.body]).sum() <= 0.001 * (~frame.body).sum()  # a few real ones at most
