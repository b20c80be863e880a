"""Balancers on synthetic cost maps through the coordinator's own scheduler on a virtual clock
(:mod:`bench.virtual_cluster`), paced as the balancer tests' figures assume: one frame in flight,
frames started at 30 frames/s, each done before the next starts, so each is partitioned with its
predecessor's timings and 33.3 ms elapsed."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from bench.virtual_cluster import FrameRecord, map_measure, run_path
from tessera.balancers.base import Balancer, ProjectedGroups
from tessera.geometry import Camera

FPS = 30.0


def cameras(count: int) -> list[Camera]:
    """``count`` distinct cameras, for costs that depend only on the camera's index."""
    return [Camera(eye=(0.0, 0.0, 5.0 + i * 1e-3), target=(0.0, 0.0, 0.0)) for i in range(count)]


def run_paced(balancer: Balancer, cost_at: Callable[[int], np.ndarray], node_ids: Sequence[int], frames: int,
              speeds: Mapping[int, float] | None = None, weights: Mapping[int, float] | None = None,
              groups_at: Callable[[int], ProjectedGroups] | None = None,
              nodes_at: Callable[[int], Sequence[int]] | None = None) -> list[FrameRecord]:
    """``frames`` frames, one in flight, started at :data:`FPS`; ``cost_at(i)`` is frame i's (H, W)
    cost map in ms per pixel at speed 1 (its shape is the screen size), ``speeds`` node speeds
    (2 = twice as fast; default 1), ``nodes_at(i)`` the nodes present for frame i (default
    ``node_ids``). Checks that record i shows camera i and that every frame was done before the
    next started."""
    present = {n for i in range(frames) for n in nodes_at(i)} if nodes_at else set(node_ids)
    slowdowns = {n: 1.0 / (speeds or {}).get(n, 1.0) for n in sorted(present)}
    height, width = cost_at(0).shape
    records, _ = run_path(balancer, map_measure(cost_at), cameras(frames), (width, height), slowdowns,
                          weights, in_flight=1, groups_at=groups_at, max_fps=FPS, nodes_at=nodes_at)
    assert [r.camera for r in records] == list(range(frames)), "a frame was dropped"
    assert all(a.done_ms <= b.started_ms for a, b in itertools.pairwise(records)), "a frame outlasted the pace"
    return records
