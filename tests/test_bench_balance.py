"""The serial-replay balancing benchmark: its accounting (pure, a cost map instead of renders) and
one short real run of ``python -m bench.balance`` on llvmpipe."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np
import pytest

from bench.paths import make_path
from bench.replay import FrameRecord, Phases, Pipeline, dispatch, ideal_ms, replay, summarize
from tessera.balancers import create_balancer
from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, Tile
from tessera.balancers.simulate import rect_sums, summed_area
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Rect


def map_measure(cost: np.ndarray):
    """``measure(frame, rects)`` from an (H, W) cost map (ms per pixel), the same every frame;
    a tenth of each tile's cost is read-back, a tenth encode."""
    table = summed_area(cost)

    def measure(frame: int, rects: Sequence[Rect]) -> list[Phases]:
        return [Phases(0.8 * c, 0.1 * c, 0.1 * c) for c in rect_sums(table, rects)]

    return measure


def halves(pull: bool = False) -> Partition:
    return Partition((Tile(Rect(0, 0, 50, 10), None if pull else 1), Tile(Rect(50, 0, 50, 10), None if pull else 2)),
                     pull=pull)


def test_push_node_times_scale_by_slowdown() -> None:
    phases = [Phases(8.0, 1.0, 1.0), Phases(4.0, 0.5, 0.5)]
    timings, node_ms, frame_ms = dispatch(halves(), phases, [1, 2], {1: 1.0, 2: 3.0})
    assert node_ms == {1: 10.0, 2: 15.0} and frame_ms == 15.0
    assert [(t.node_id, t.render_ms, t.readback_ms, t.encode_ms) for t in timings] == [
        (1, 8.0, 1.0, 1.0), (2, 12.0, 1.5, 1.5)]


def test_pull_makespan_and_attribution() -> None:
    """Tiles 5, 4, 3, 3, 3 ms pulled by node 1 (slowdown 1) and node 2 (slowdown 0.5, twice as fast):
    node 2 takes 5, 3, 3 (5.5 ms), node 1 takes 4, 3 (7 ms) = the makespan."""
    rects = [Rect(20 * i, 0, 20, 10) for i in range(5)]
    partition = Partition(tuple(Tile(r, None) for r in rects), pull=True)
    phases = [Phases(ms) for ms in (5.0, 4.0, 3.0, 3.0, 3.0)]
    timings, node_ms, frame_ms = dispatch(partition, phases, [1, 2], {1: 1.0, 2: 0.5})
    assert [t.node_id for t in timings] == [2, 1, 2, 2, 1]
    assert [t.render_ms for t in timings] == [2.5, 4.0, 1.5, 1.5, 3.0]
    assert node_ms == {1: 7.0, 2: 5.5} and frame_ms == 7.0


def test_ideal_and_efficiency() -> None:
    """Uniform cost (20 ms of work), equal halves: balanced at equal speeds; node 2 twice as slow:
    times 10 and 20 ms, ideal 20 / (1 + ½) ms, efficiency ideal / 20."""
    assert ideal_ms(30.0, [1.0, 1.0, 2.0, 4.0]) == pytest.approx(30.0 / 2.75)
    measure = map_measure(np.full((10, 100), 0.02))
    even = replay(StaticBalancer(), 3, (100, 10), [1, 2], measure)
    assert even[-1].imbalance == pytest.approx(1.0) and even[-1].efficiency == pytest.approx(1.0)
    slow = replay(StaticBalancer(), 3, (100, 10), [1, 2], measure, slowdowns={1: 1.0, 2: 2.0})
    assert slow[-1].node_ms == pytest.approx({1: 10.0, 2: 20.0})
    assert slow[-1].imbalance == pytest.approx(20.0 / 15.0)
    assert slow[-1].ideal_ms == pytest.approx(20.0 / 1.5)
    assert slow[-1].efficiency == pytest.approx((20.0 / 1.5) / 20.0)


def pull_frame(count: int) -> Partition:
    return Partition(tuple(Tile(Rect(10 * i, 0, 10, 10), None) for i in range(count)), pull=True)


def test_pipeline_one_frame_in_flight_adds_up_frame_times() -> None:
    """With one frame in flight a frame starts when the last one is done: done = Σ frame times."""
    pipeline = Pipeline([1, 2], {1: 1.0, 2: 2.0}, in_flight=1)
    phases = [Phases(8.0, 1.0, 1.0), Phases(4.0, 0.5, 0.5)]
    assert [pipeline.run(halves(), phases)[0] for _ in range(3)] == [10.0, 20.0, 30.0]


def test_pipeline_push_is_bound_by_the_slowest_node() -> None:
    """Two frames in flight: the light node runs a frame ahead but cannot run further; the frame
    period settles at the slow node's 10 ms."""
    pipeline = Pipeline([1, 2], {}, in_flight=2)
    done = [pipeline.run(halves(), [Phases(10.0), Phases(2.0)])[0] for _ in range(6)]
    assert done == [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    assert pipeline.free_at.tolist() == [60.0, 42.0]


def test_pipeline_pull_fills_gaps_with_the_next_frame() -> None:
    """Tiles 6 and 2 ms on two equal nodes: one frame alone takes 6 ms (efficiency 4/6), but a node
    that finishes early pulls from the next frame, so the period falls to the ideal 4 ms."""
    pipeline = Pipeline([1, 2], {}, in_flight=2)
    runs = [pipeline.run(pull_frame(2), [Phases(6.0), Phases(2.0)]) for _ in range(4)]
    assert [done for done, _ in runs] == [6.0, 8.0, 14.0, 16.0]
    assert runs[1][1] == ((2.0, 8.0, 6.0), (6.0, 8.0, 2.0))
    single = Pipeline([1, 2], {}, in_flight=1)
    assert [single.run(pull_frame(2), [Phases(6.0), Phases(2.0)])[0] for _ in range(2)] == [6.0, 12.0]


def test_pipelined_efficiency_in_summary() -> None:
    """summarize: the kept frames' work inside the window from the last skipped frame's completion
    to the last but one, as ideal ms, over the window; one frame in flight gives the per-frame
    figure."""
    measure = map_measure(np.full((10, 100), 0.02))
    slow = replay(StaticBalancer(), 12, (100, 10), [1, 2], measure, slowdowns={1: 1.0, 2: 2.0}, lag=0)
    summary = summarize(slow, skip=2)
    assert summary["efficiency_pipelined"] == pytest.approx(summary["efficiency"])
    assert summary["frame_ms_pipelined"] == pytest.approx(summary["frame_ms"]) == pytest.approx(20.0)
    records = [FrameRecord(halves(), {}, 10.0, 20.0, 10.0, 1.0, 1.0, 10.0, ((0.0, 10.0, 10.0), (0.0, 10.0, 10.0))),
               FrameRecord(halves(), {}, 20.0, 30.0, 15.0, 1.0, 0.75, 30.0, ((5.0, 15.0, 10.0), (10.0, 30.0, 20.0))),
               FrameRecord(halves(), {}, 20.0, 25.0, 12.5, 1.0, 0.75, 40.0, ((20.0, 35.0, 15.0), (30.0, 40.0, 10.0)))]
    pipelined = summarize(records, skip=1)
    assert pipelined["frame_ms_pipelined"] == pytest.approx(20.0)
    assert pipelined["efficiency_pipelined"] == pytest.approx((2.5 + 10.0 + 5.0) / 20.0)
    assert np.isnan(summarize([*records[:2], FrameRecord(halves(), {}, 1.0, 1.0, 1.0, 1.0, 1.0)],
                              skip=1)["efficiency_pipelined"])


def test_rotate_pipelined_beats_one_frame_makespan() -> None:
    """Tile rotation over frames in flight keeps nodes busy: its pipelined efficiency is at least
    its per-frame one, and static's stays bound by the slowest node."""
    cost = np.ones((60, 80))
    cost[:20, :30] = 20.0
    measure = map_measure(cost / cost.sum() * 30.0)
    rotate = summarize(replay(create_balancer("rotate"), 30, (80, 60), [1, 2, 3], measure))
    static = summarize(replay(StaticBalancer(), 30, (80, 60), [1, 2, 3], measure))
    assert rotate["efficiency"] < rotate["efficiency_pipelined"] <= 1.0 + 1e-9
    assert rotate["efficiency_pipelined"] > 0.97
    assert static["efficiency_pipelined"] == pytest.approx(static["efficiency"])


class Recorder(Balancer):
    """Static halves; records every input it is given."""

    name = "recorder"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"min_tile_px": 1}

    def __init__(self, **params) -> None:
        super().__init__(**params)
        self.inputs: list[BalanceInput] = []

    def partition(self, inputs: BalanceInput) -> Partition:
        self.inputs.append(inputs)
        cut = 30 + 10 * len(self.inputs)
        return Partition((Tile(Rect(0, 0, cut, 10), 1), Tile(Rect(cut, 0, 100 - cut, 10), 2)))


@pytest.mark.parametrize("lag", [0, 1])
def test_timings_lag_weights_elapsed_and_groups(lag: int) -> None:
    """Frame f gets frame f-1-lag's timings (none before), the weights, dt (0 on frame 0) and its groups."""
    recorder = Recorder()
    measure = map_measure(np.ones((10, 100)))
    groups = [ProjectedGroups(np.array([[0.0, 0.0, float(f + 1), 1.0]]), np.ones(1)) for f in range(5)]
    records = replay(recorder, 5, (100, 10), [1, 2], measure, weights={1: 1.0, 2: 2.0}, dt_ms=25.0, lag=lag,
                     groups_at=groups.__getitem__)
    for frame, inputs in enumerate(recorder.inputs):
        source = frame - 1 - lag
        measured = records[source].partition if source >= 0 else None
        assert inputs.timings == (dispatch(measured, measure(source, measured.rects), [1, 2], {})[0]
                                  if measured else ())
        assert inputs.previous == (records[frame - 1].partition if frame else None)
        assert inputs.elapsed_ms == (25.0 if frame else 0.0) and inputs.weights == {1: 1.0, 2: 2.0}
        assert inputs.groups is groups[frame]
    plain = replay(StaticBalancer(), 2, (100, 10), [1, 2], map_measure(np.ones((10, 100))),
                   groups_at=lambda frame: pytest.fail("groups projected for a balancer that does not use them"))
    assert len(plain) == 2


def test_summary_skips_frames_and_counts_repartitions() -> None:
    partitions = [halves(), halves(), Partition((Tile(Rect(0, 0, 40, 10), 1), Tile(Rect(40, 0, 60, 10), 2))),
                  Partition((Tile(Rect(40, 0, 60, 10), 2), Tile(Rect(0, 0, 40, 10), 1))), halves()]
    records = [FrameRecord(p, {1: 1.0, 2: 1.0}, 10.0, 20.0, 8.0, 1.0 + i / 10, 0.8) for i, p in enumerate(partitions)]
    summary = summarize(records, skip=1)
    assert summary["frames"] == 4 and summary["repartitions"] == 2
    assert summary["imbalance_mean"] == pytest.approx(1.25) and summary["efficiency"] == pytest.approx(0.8)
    assert summary["imbalance_p95"] == pytest.approx(np.percentile([1.1, 1.2, 1.3, 1.4], 95))
    with pytest.raises(ValueError):
        summarize(records, skip=5)


def test_rotate_replays_pull_lists() -> None:
    """rotate's pull list is dispatched by the schedule: every node works, the makespan is the slowest."""
    cost = np.ones((60, 80))
    cost[:20, :30] = 20.0
    records = replay(create_balancer("rotate"), 20, (80, 60), [1, 2, 3], map_measure(cost / cost.sum() * 30.0))
    assert all(r.partition.pull for r in records)
    last = records[-1]
    assert last.frame_ms == pytest.approx(max(last.node_ms.values())) and min(last.node_ms.values()) > 0.0
    assert last.efficiency == pytest.approx(last.work_ms / 3 / last.frame_ms)


@pytest.mark.gl
def test_benchmark_runs_end_to_end(tmp_path, monkeypatch) -> None:
    """14-frame orbit of the built-in spheres, 2 nodes, 160x120, one push and one pull balancer."""
    from bench.balance import main
    from node.scene import load_scene

    monkeypatch.setenv("LP_NUM_THREADS", "0")  # main() sets it; restored after the test
    path = tmp_path / "orbit.json"
    path.write_text(json.dumps(make_path("orbit", load_scene("builtin:spheres").bounds, frames=14)))
    out = tmp_path / "figures.json"
    assert main(["--scene", "builtin:spheres", "--path", str(path), "--nodes", "2", "--size", "160x120",
                 "--balancers", "adaptive,rotate", "--speeds", "1,2", "--repeats", "1", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert set(figures) == {"adaptive", "rotate", "meta"}
    for name in ("adaptive", "rotate"):
        row = figures[name]
        assert {"imbalance_mean", "imbalance_p95", "efficiency", "repartitions", "frames"} <= set(row)
        assert row["frames"] == 4
        assert 1.0 <= row["imbalance_mean"] <= row["imbalance_p95"]
        assert 0.0 < row["efficiency"] <= 1.0001 and 0.0 < row["efficiency_pipelined"] <= 1.0001
        assert 0 <= row["repartitions"] <= 4
    meta = figures["meta"]
    assert meta["nodes"] == 2 and meta["size"] == [160, 120] and meta["speeds"] == [1.0, 2.0] and meta["lag"] == 1
    assert meta["weights"]["1"] == pytest.approx(2.0) and meta["weights"]["2"] == pytest.approx(1.0)
    assert meta["lp_num_threads"] == 0 and meta["renderer"]
