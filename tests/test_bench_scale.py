"""The scale benchmark: its cost model and CPU accounting (pure), one end-to-end run of
``bench.scale.main`` (virtual cluster + a real coordinator with synthetic nodes over loopback), and
the measured cost model on llvmpipe. Speeds are reported, never asserted."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from bench.scale import CostModel, EntryPointCpu, grid_rects, main, measure_cost_model, synthetic_cost_model
from bench.synthetic_nodes import tile_payload
from tessera.geometry import Rect
from tessera.wire.codec import Codec, decode
from tests.conftest import scene_path


def positive_finite(value: float) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value) and value > 0


def cell_model() -> CostModel:
    """A 40x20 frame of 4x2 cells; cell (row r, col c) costs 10·r + c + 1 ms of render."""
    cells = np.zeros((3, 2, 4))
    cells[0] = np.arange(1, 5)[None, :] + 10.0 * np.arange(2)[:, None]
    return CostModel((40, 20), np.array([0.5, 0.25, 0.125]), cells)


def test_cost_model_cells_overhead_and_roll() -> None:
    model = cell_model()
    cell = model.phases([Rect(10, 10, 10, 10)])[0]
    assert (cell.render_ms, cell.readback_ms, cell.encode_ms) == pytest.approx((0.5 + 12.0, 0.25, 0.125))
    assert model.phases([Rect(5, 0, 10, 10)])[0].render_ms == pytest.approx(0.5 + 0.5 * 1 + 0.5 * 2)
    # rolled one cell (10 px) right: the last column's cost wraps round to the first
    assert model.phases([Rect(0, 0, 10, 10)], shift_px=10)[0].render_ms == pytest.approx(0.5 + 4.0)
    total = model.cells.sum() + 8 * model.overhead.sum()
    for shift in (0, 3, 17, 40, 57):
        assert sum(p.busy_ms for p in model.phases(grid_rects((40, 20), (4, 2)), shift)) == pytest.approx(total)


def test_synthetic_cost_model_is_a_central_column() -> None:
    model = synthetic_cost_model((640, 360), (16, 9))
    assert model.cells.sum() == pytest.approx(100.0)
    left, middle = model.phases([Rect(0, 0, 80, 360), Rect(280, 0, 80, 360)])
    assert middle.busy_ms > 10 * left.busy_ms


def test_entry_point_cpu_counts_nested_calls_once() -> None:
    target = SimpleNamespace()
    target.inner = lambda: sum(range(1000))
    target.outer = lambda: target.inner() + target.inner()
    cpu = EntryPointCpu(target, ["inner", "outer"])
    assert target.outer() == 2 * sum(range(1000))
    assert cpu.calls == 1 and cpu.seconds >= 0.0
    target.inner()
    assert cpu.calls == 2


@pytest.mark.parametrize("codec", [Codec.JPEG, Codec.PNG])
def test_synthetic_tiles_have_the_rect_size(codec: Codec) -> None:
    payload = tile_payload(codec, 60, (640, 360), 123, 45)
    assert decode(payload, codec, 123, 45).shape == (45, 123, 3)
    assert tile_payload(codec, 60, (640, 360), 123, 45) is payload   # encoded once


@pytest.mark.integration
def test_scale_end_to_end(tmp_path) -> None:
    out = tmp_path / "scale.json"
    assert main(["--virtual-nodes", "16", "--loopback-nodes", "4", "--seconds", "2", "--warmup-s", "1",
                 "--size", "640x360", "--cost-model", "synthetic", "--frames", "40", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["meta"]["cpus"] >= 1 and result["meta"]["python"] and "--json" in result["meta"]["argv"]

    virtual = result["virtual"]
    assert {r["balancer"] for r in virtual["runs"]} >= {"static", "adaptive", "rotate", virtual["default_balancer"]}
    for run in virtual["runs"]:
        assert run["nodes"] == 16 and run["frames"] == 40, run
        for key in ("fps_virtual", "imbalance_mean", "efficiency_pipelined", "tiles_per_frame",
                    "scheduler_cpu_ms_per_frame", "scheduler_ceiling_fps", "scheduler_ceiling_tiles_per_s"):
            assert positive_finite(run[key]), (key, run)
        assert run["tiles_per_frame"] >= 16
    assert next(r for r in virtual["runs"] if r["balancer"] == "static")["tiles_per_frame"] == 16

    [run] = result["loopback"]["runs"]
    assert run["nodes"] == 4 and run["nodes_connected"] == 4, run["coordinator_log"]
    assert run["synthetic_nodes_ended"] == ["stopped"], run["synthetic_log"]
    assert run["frames"] > 0 and run["tiles"] >= run["frames"]
    assert run["node_tiles_min"] > 0, "a synthetic node rendered no tile in the window"
    assert run["synthetic_tiles_sent"] >= run["tiles"]
    for key in ("fps", "tiles_per_s", "coordinator_cpu_ms_per_frame", "receive_cpu_ms_per_frame",
                "nodes_cpu_ms_per_frame", "ceiling_fps", "ceiling_tiles_per_s", "viewer_fps"):
        assert positive_finite(run[key]), (key, run)
    assert run["frame_png"]["size"] == [640, 360]


@pytest.mark.gl
def test_measured_cost_model(monkeypatch) -> None:
    monkeypatch.setenv("LP_NUM_THREADS", "0")
    scene = str(scene_path("large_scan/stanford_lucy_240k.ply"))
    model, info = measure_cost_model(scene, (320, 180), (4, 3), 60)
    assert model.cells.shape == (3, 3, 4) and (model.cells >= 0).all() and model.cells.sum() > 0
    assert all(positive_finite(v) for v in model.overhead[[0, 2]]), model.overhead
    assert len(info["check"]) == 5
    for check in info["check"]:
        assert positive_finite(check["measured_ms"]) and positive_finite(check["model_ms"]), check
