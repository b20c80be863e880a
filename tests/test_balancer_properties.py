"""Every balancer, any inputs: exact cover, one tile per node (or a pull list), a minimum tile
size, and the same partitions for the same input sequence (property-based, no GL)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tessera.balancers import BALANCERS, create_balancer
from tessera.balancers.base import BalanceInput, Partition, TileTiming
from tessera.balancers.partition import check_exact_cover
from tessera.balancers.static import minimum_for


@st.composite
def frame_sequences(draw):
    """A few frames: screen size (may change), node set (may gain/lose nodes), per-tile
    timings of the previous partition (some missing, some zero), weights and elapsed time."""
    frames = []
    width, height = draw(st.integers(64, 320)), draw(st.integers(64, 240))
    count = draw(st.integers(1, 64))
    for _ in range(draw(st.integers(2, 4))):
        if draw(st.integers(0, 5)) == 0:
            width, height = draw(st.integers(64, 320)), draw(st.integers(64, 240))
        if draw(st.integers(0, 4)) == 0:
            count = draw(st.integers(1, 64))
        first = draw(st.integers(0, 3))
        frames.append({
            "size": (width, height),
            "nodes": tuple(range(first, first + count)),
            "tile_ms": draw(st.lists(st.one_of(st.none(), st.just(0.0), st.floats(0.01, 100.0)),
                                     min_size=count * 3, max_size=count * 3)),
            "weights": draw(st.lists(st.sampled_from([0.5, 1.0, 2.0, 4.0]), min_size=count, max_size=count)),
            "elapsed_ms": draw(st.sampled_from([0.0, 16.7, 33.3, 250.0])),
        })
    return frames


def timings_for(partition: Partition, tile_ms: list, nodes: tuple[int, ...]) -> tuple[TileTiming, ...]:
    """Timings of ``partition``'s tiles (None in ``tile_ms`` = tile not measured)."""
    out = []
    for i, (tile, ms) in enumerate(zip(partition.tiles, tile_ms, strict=False)):
        if ms is not None:
            owner = tile.node_id if tile.node_id is not None else nodes[i % len(nodes)]
            out.append(TileTiming(tile.rect, owner, ms, readback_ms=ms / 10, encode_ms=ms / 20, send_ms=ms / 20))
    return tuple(out)


def replay(name: str, frames: list[dict]) -> list[Partition]:
    """Feed ``frames`` to a fresh balancer as the coordinator would; checks every partition."""
    balancer = create_balancer(name)
    previous: Partition | None = None
    timings: tuple[TileTiming, ...] = ()
    out = []
    for frame in frames:
        inputs = BalanceInput(size=frame["size"], node_ids=frame["nodes"], previous=previous, timings=timings,
                              weights=dict(zip(frame["nodes"], frame["weights"], strict=True)),
                              elapsed_ms=frame["elapsed_ms"])
        partition = balancer.partition(inputs)
        check_exact_cover(partition.rects, frame["size"])
        if partition.pull:
            assert all(t.node_id is None for t in partition.tiles)
            assert len(partition.tiles) >= len(frame["nodes"])
        else:
            assert sorted(t.node_id for t in partition.tiles) == sorted(frame["nodes"])
        minimum = minimum_for(frame["size"], len(partition.tiles), balancer.params["min_tile_px"])
        assert min(min(t.rect.w, t.rect.h) for t in partition.tiles) >= minimum
        timings = timings_for(partition, frame["tile_ms"], frame["nodes"])
        previous = partition
        out.append(partition)
    return out


@pytest.mark.parametrize("name", sorted(BALANCERS))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames=frame_sequences())
def test_exact_cover_and_determinism(name: str, frames: list[dict]) -> None:
    assert replay(name, frames) == replay(name, frames)


@pytest.mark.parametrize("name", sorted(BALANCERS))
def test_tiny_screen_many_nodes(name: str) -> None:
    """64×64 pixels for 64 nodes: the minimum tile size degrades to what fits."""
    frame = {"size": (64, 64), "nodes": tuple(range(64)), "tile_ms": [5.0] * 192, "weights": [1.0] * 64,
             "elapsed_ms": 33.3}
    partitions = replay(name, [frame, frame, frame])
    assert all(len(p.tiles) >= 64 for p in partitions)


@pytest.mark.parametrize("name", sorted(BALANCERS))
def test_params_exposed_and_checked(name: str) -> None:
    cls = BALANCERS[name]
    assert cls.name == name and "min_tile_px" in cls.defaults
    assert create_balancer(name).params == dict(cls.defaults)
    with pytest.raises(ValueError, match="no parameters"):
        create_balancer(name, {"no_such_parameter": 1})
    with pytest.raises(ValueError):
        create_balancer(name, {"min_tile_px": 0})
