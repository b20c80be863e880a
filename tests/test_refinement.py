"""The progressive still's parts without GL (issue 20): Halton jitter, the jitter matrix, the LOD
bias, the exact accumulation, the refinement plan and how render on demand asks for the samples;
the scheduler asking for them one frame at a time and dropping them on input; the frame header's
sample count; the coordinator's refiner."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from bench.images import psnr
from server.still_refinement import FIRST_SHOWN, StillRefiner
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, Rect, view_projection
from tessera.scheduling.actions import RenderTiles
from tessera.scheduling.refinement import (
    ADAPTIVE,
    ADAPTIVE_LOD_BIAS,
    CHECKS,
    MAX_STILL_SAMPLES,
    Accumulator,
    RefinementPlan,
    StillPlan,
    Subsample,
    accumulate,
    accumulate_still,
    jitter,
    jitter_matrix,
    lod_bias,
    mean_table,
    radical_inverse,
    subsample,
)
from tessera.scheduling.render_demand import INTERACTIVE, STILL, RenderDemand
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.video.budget import full_analysis
from tessera.wire.codec import Codec, decode, encode
from tessera.wire.protocol import pack_frame, unpack_frame
from tests.test_scheduler import camera, cancels, finish, published, renders, scheduler


def test_radical_inverse_mirrors_the_digits() -> None:
    assert [radical_inverse(i, 2) for i in range(1, 5)] == [0.5, 0.25, 0.75, 0.125]
    assert [radical_inverse(i, 3) for i in range(1, 4)] == pytest.approx([1 / 3, 2 / 3, 1 / 9])
    assert radical_inverse(0, 2) == 0.0
    with pytest.raises(ValueError):
        radical_inverse(-1, 2)


def test_jitter_is_halton_2_3_in_the_pixel_and_none_for_one_sample() -> None:
    """Offsets lie in [-0.5, 0.5)², are distinct, and a prefix of 16 puts one in each 4×4 cell
    of the pixel in x and fills every row of cells (low discrepancy)."""
    assert jitter(0, 1) is None
    offsets = np.array([jitter(k, 16) for k in range(16)])
    assert offsets[0] == pytest.approx((0.0, 1 / 3 - 0.5))
    assert np.all(offsets >= -0.5) and np.all(offsets < 0.5)
    assert len({tuple(o) for o in offsets.tolist()}) == 16
    columns = np.floor((offsets[:, 0] + 0.5) * 4).astype(int)
    assert sorted(columns.tolist()) == sorted(list(range(4)) * 4)
    rows = np.floor((offsets[:, 1] + 0.5) * 4).astype(int)
    assert set(rows.tolist()) == {0, 1, 2, 3}
    assert abs(offsets.mean(axis=0)).max() < 0.05
    with pytest.raises(ValueError):
        jitter(4, 4)


def test_jitter_matrix_moves_projected_points_by_the_offset_in_pixels() -> None:
    """A world point projected with the jittered matrix lands (dx, dy) pixels away (y down)."""
    size = (320, 200)
    camera = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fovy_deg=45.0)
    matrix = view_projection(camera, size, np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    point = np.array([0.3, -0.2, 0.4, 1.0])

    def pixel(m: np.ndarray) -> np.ndarray:
        clip = m @ point
        ndc = clip[:2] / clip[3]
        return np.array([(ndc[0] + 1) / 2 * size[0], (1 - ndc[1]) / 2 * size[1]])

    moved = pixel(jitter_matrix((0.25, -0.375), size) @ matrix) - pixel(matrix)
    assert moved == pytest.approx((0.25, -0.375))
    assert np.array_equal(jitter_matrix(None, size), np.identity(4))


def test_accumulation_is_the_rounded_mean_whatever_the_tile_order() -> None:
    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (6, 8, 3), dtype=np.uint8) for _ in range(5)]
    expected = np.floor(np.mean(np.stack(frames).astype(np.float64), axis=0) + 0.5).astype(np.uint8)
    assert np.array_equal(accumulate(frames), expected)
    tiled = Accumulator((8, 6))
    for frame in frames:
        tiled.add(frame[3:, 5:], 5, 3)
        tiled.add(frame[:, :5])
        tiled.add(frame[:3, 5:], 5, 0)
        tiled.finish_sample()
    assert tiled.count == 5 and np.array_equal(tiled.mean(), expected)
    assert np.array_equal(tiled.mean(5, 3, 3, 3), expected[3:, 5:])
    assert np.array_equal(accumulate([frames[0]]), frames[0])
    with pytest.raises(ValueError):
        Accumulator((8, 6)).mean()
    full = Accumulator((1, 1))
    for _ in range(MAX_STILL_SAMPLES):   # the most samples of 255 still fit the sums
        full.add(np.full((1, 1, 3), 255, np.uint8))
        full.finish_sample()
    assert full.mean().tolist() == [[[255, 255, 255]]]
    with pytest.raises(ValueError):
        full.finish_sample()
    for count in (1, 2, 3, 8, 127):   # the table is the mean rounded half up
        sums = np.arange(255 * count + 1)
        assert np.array_equal(mean_table(count), np.floor(sums / count + 0.5).astype(np.uint8))


def test_subsamples_pair_the_jitter_with_the_lod_bias_of_the_sample_density() -> None:
    assert subsample(0, 1) is None and lod_bias(1) == 0.0
    assert subsample(5, 16) == Subsample(jitter(5, 16), -2.0)
    assert lod_bias(8) == pytest.approx(-1.5)
    assert Subsample.of(None, None) is None and Subsample.of(None, 0.0) is None
    assert Subsample.of((0.25, -0.25), None) == Subsample((0.25, -0.25), 0.0)


def test_refinement_plan_counts_the_samples_started() -> None:
    plan = RefinementPlan(3)
    assert [plan.start() for _ in range(3)] == [0, 1, 2] and not plan.owed
    with pytest.raises(ValueError):
        plan.start()
    plan.restart()
    assert plan.owed and plan.start() == 0
    for bad in (-1, MAX_STILL_SAMPLES + 1):
        with pytest.raises(ValueError):
            RefinementPlan(bad)
    adaptive = RefinementPlan(StillPlan(ADAPTIVE, max_samples=4))
    assert [adaptive.start() for _ in range(2)] == [0, 1] and adaptive.owed
    adaptive.finish()
    assert not adaptive.owed, "converged: no more samples"
    adaptive.restart()
    assert [adaptive.start() for _ in range(4)] == [0, 1, 2, 3] and not adaptive.owed, "at most max_samples"


def test_an_adaptive_plan_checks_at_the_halton_counts_and_reads_textures_as_the_reference() -> None:
    plan = StillPlan(ADAPTIVE, max_samples=40, target_db=47.0)
    assert plan.adaptive and plan.most == 40 and plan.checks() == (8, 16, 24, 32, 40)
    assert plan.subsample(5) == Subsample(jitter(5, 40), ADAPTIVE_LOD_BIAS) and plan.subsample(0) is not None
    assert StillPlan(8).checks() == (8,) and StillPlan(1).checks() == () and StillPlan(1).subsample(0) is None
    assert StillPlan(8).subsample(3) == subsample(3, 8)
    assert not plan.done(16, None) and not plan.done(16, 46.9) and plan.done(16, 47.0) and plan.done(40, None)
    assert not StillPlan(8).done(7, 99.0) and StillPlan(8).done(8, 10.0), "a fixed count ignores the estimate"
    for bad in ({"samples": 128}, {"samples": -1}, {"max_samples": 1}, {"max_samples": 128}, {"target_db": 0.0}):
        with pytest.raises(ValueError):
            StillPlan(**{"samples": ADAPTIVE, **bad})


def test_the_estimate_is_the_rms_difference_of_the_mean_and_its_first_halfs_mean_exactly() -> None:
    """At each check the accumulator's estimate is the PSNR of the mean of all n samples against
    the mean of the first n // 2, computed exactly from the sums (whatever the tile order), the
    copies of the halves' sums are dropped once used (at most two kept at a time), and an adaptive
    still converges at the first check whose estimate reaches the target, its mean the rounded mean
    of the samples up to there."""
    rng = np.random.default_rng(11)
    truth = rng.integers(40, 216, (5, 7, 3)).astype(np.float64)
    frames = [np.clip(truth + rng.normal(0, 24 / (k + 1), truth.shape), 0, 255).astype(np.uint8) for k in range(32)]
    plan = StillPlan(ADAPTIVE, max_samples=32, target_db=99.0)
    whole, tiled = Accumulator((7, 5), plan), Accumulator((7, 5), plan)
    kept = []
    for count, frame in enumerate(frames, 1):
        whole.add(frame)
        whole.finish_sample()
        tiled.add(frame[:, 3:], 3)
        tiled.add(frame[:, :3])
        tiled.finish_sample()
        kept.append(sum(v is not None for v in whole._halves.values()))
        if count in CHECKS:
            means = np.cumsum(np.stack(frames[:count]).astype(np.float64), axis=0)
            expected = np.mean((means[count - 1] / count - means[count // 2 - 1] / (count // 2)) ** 2)
            assert whole.estimated_at == count
            assert whole.estimate_db == pytest.approx(10 * np.log10(255.0 ** 2 / expected), rel=1e-12)
            assert tiled.estimate_db == whole.estimate_db
    assert max(kept) <= 2 and whole.converged and whole.count == 32, "an unreachable target: at most max_samples"
    for count in (16, 32):
        reached = StillPlan(ADAPTIVE, max_samples=32, target_db=estimate_after(frames, count) - 1e-9)
        render, seen = drawing(frames)
        still = accumulate_still(render, (7, 5), reached)
        assert still.count == count and seen == [reached.subsample(k) for k in range(count)]
        assert np.array_equal(still.mean(), accumulate(frames[:count]))
    flat = Accumulator((2, 2), StillPlan(ADAPTIVE, max_samples=8))
    for _ in range(8):
        flat.add(np.full((2, 2, 3), 9, np.uint8))
        flat.finish_sample()
    assert flat.estimate_db == np.inf and flat.converged


def estimate_after(frames: list[np.ndarray], count: int) -> float:
    """The estimate an adaptive accumulator makes after ``count`` of ``frames`` (a check)."""
    accumulator = Accumulator(frames[0].shape[1::-1], StillPlan(ADAPTIVE, max_samples=MAX_STILL_SAMPLES))
    for frame in frames[:count]:
        accumulator.add(frame)
        accumulator.finish_sample()
    assert accumulator.estimated_at == count and accumulator.estimate_db is not None
    return accumulator.estimate_db


def drawing(frames: list[np.ndarray]):
    """A render callback that draws ``frames`` in turn, and the subsamples it was asked for."""
    seen: list[Subsample | None] = []

    def render(sub: Subsample | None) -> np.ndarray:
        seen.append(sub)
        return frames[len(seen) - 1]

    return render, seen


def test_demand_asks_for_the_still_samples_one_at_a_time_and_a_change_restarts_them() -> None:
    demand = RenderDemand(settle_frames=0, still_delay_s=0.2, still_frames=True, still_samples=3)
    assert demand.owed(0.0, False, False, False) is None, "nothing before the first change"
    demand.changed(1.0)
    assert demand.owed(1.0, False, False, False) == INTERACTIVE
    assert demand.started(False) == 0
    assert demand.owed(1.1, False, False, False) is None, "the still waits for the quiet time"
    assert demand.owed(1.3, False, False, True) is None, "and for the frame in flight"
    samples = []
    while demand.owed(1.3, False, False, False) == STILL:
        samples.append(demand.started(True))
        assert demand.owed(1.3, False, False, True) is None, "nor while an interactive frame is in flight"
    assert samples == [0, 1, 2] and demand.owed(9.0, False, False, False) is None
    demand.changed(10.0)
    demand.started(False)
    assert demand.owed(10.3, False, False, False) == STILL and demand.started(True) == 0
    demand.changed(10.4)   # input during the refinement: an interactive frame, then the still anew
    assert demand.owed(10.4, False, False, False) == INTERACTIVE
    demand.started(False)
    assert [demand.started(True) for _ in range(3)] == [0, 1, 2]


def test_a_still_sample_dropped_with_nothing_changed_restarts_the_still() -> None:
    demand = RenderDemand(settle_frames=0, still_delay_s=0.0, still_frames=True, still_samples=2)
    demand.changed(0.0)
    demand.started(False)
    assert [demand.started(True) for _ in range(2)] == [0, 1]
    assert demand.owed(1.0, False, False, False) is None
    demand.still_dropped(demand.version - 1)
    assert demand.owed(1.0, False, False, False) is None, "a still of an older state is not owed again"
    demand.still_dropped(demand.version)
    assert demand.owed(1.0, False, False, False) == STILL and demand.started(True) == 0


def test_the_scheduler_renders_the_still_samples_one_frame_each_then_nothing() -> None:
    """At rest the still's samples come one frame at a time, each jittered as its render message
    says, the last one converged; input during the refinement drops the sample in flight and an
    interactive frame starts at once; after the last sample nothing renders."""
    s = scheduler(still_delay_ms=200, still_samples=3)
    s.set_camera(camera(), 0.0)
    s.drain()
    finish(s, 1, 0.05)
    s.tick(0.2)
    frames = []
    actions = s.drain()
    for now in (0.3, 0.4, 0.5):
        (frame_id,) = s.in_flight
        job = s.in_flight[frame_id]
        messages = [a.message for a in actions if isinstance(a, RenderTiles)]
        sub = job.subsample
        assert job.still and sub is not None and sub.lod_bias == pytest.approx(-0.5 * np.log2(3))
        assert {(m.jitter, m.lod_bias) for m in messages} == {(sub.offset, sub.lod_bias)}
        frames.append((job.sample, job.samples))
        actions = finish(s, frame_id, now)
        assert published(actions) == [frame_id]
    assert frames == [(0, 3), (1, 3), (2, 3)]
    assert s.default.settled and s.next_deadline(0.5) is None
    for now in (1.0, 10.0):
        s.tick(now)
        assert s.drain() == [] and not s.in_flight, "after the last sample nothing renders"
    s.set_camera(camera(1), 11.0)
    s.drain()
    finish(s, max(s.in_flight), 11.05)
    s.tick(11.3)
    (sample,) = s.in_flight
    s.drain()
    s.set_camera(camera(2), 11.35)
    actions = s.drain()
    assert sample in {f for frames in cancels(actions).values() for f in frames}, "the sample is dropped"
    (interactive,) = s.in_flight
    assert not s.in_flight[interactive].still and s.in_flight[interactive].subsample is None
    assert renders(actions), "the interactive frame starts at once"


def test_an_adaptive_still_takes_samples_until_the_coordinator_says_it_converged() -> None:
    """An adaptive still's samples (the reference's texture LOD bias) keep coming until the
    coordinator reports the still converged: the samples in flight are then dropped, nothing more
    renders, and the session is settled; a report for an older state changes nothing; unreported,
    the samples stop at the most."""
    s = scheduler(still_delay_ms=0, still_samples=ADAPTIVE, still_samples_max=12)
    s.set_camera(camera(), 0.0)
    s.drain()
    finish(s, 1, 0.05)
    s.tick(0.1)
    version = s.default.demand.version
    s.still_converged(0.1, version - 1)
    samples, now = [], 0.1
    while len(samples) < 8:
        job = s.in_flight[min(s.in_flight)]
        assert job.still and job.subsample == StillPlan(ADAPTIVE, 12).subsample(job.sample)
        samples.append(job.sample)
        now += 0.05
        finish(s, job.frame_id, now)
        s.tick(now)
    assert samples == list(range(8)) and any(job.still for job in s.in_flight.values()), "the next sample is on its way"
    s.drain()
    in_flight = set(s.in_flight)
    s.still_converged(now, version)
    actions = s.drain()
    assert in_flight and not s.in_flight, "the samples in flight are dropped"
    assert max(in_flight) in {f for frames in cancels(actions).values() for f in frames}, "nodes skip the queued one"
    assert s.default.settled and s.next_deadline(now) is None
    s.tick(now + 5.0)
    assert s.drain() == [] and not s.in_flight, "once converged nothing renders"
    s.still_converged(now, version)
    assert s.drain() == []
    s.set_camera(camera(1), 10.0)
    started = []
    for step in range(1, 40):
        s.tick(10.0 + 0.05 * step)
        if not s.in_flight:
            break
        job = s.in_flight[min(s.in_flight)]
        started += [job.sample] if job.still else []
        finish(s, job.frame_id, 10.0 + 0.05 * step)
    assert started == list(range(12)) and s.default.settled, "unreported, the still stops at its most samples"


def test_the_next_sample_goes_ahead_to_nodes_ending_the_one_before_and_input_drops_both() -> None:
    """A node ending its tile of a sample (within its measured round trip) gets the next sample's
    tile at once, so two samples are in flight (never more than max_in_flight) and published in
    order; input drops both and its interactive frame starts at once."""
    s = scheduler(still_delay_ms=200, still_samples=4)
    s.set_camera(camera(), 0.0)
    s.drain()
    finish(s, 1, 0.05)
    s.tick(0.2)
    s.drain()
    (first,) = s.in_flight
    wanted = s.next_deadline(0.2)
    assert wanted is not None and wanted < 0.3, "the nodes will want the next sample before they end this one"
    s.tick(wanted)
    actions = s.drain()
    assert sorted(s.in_flight) == [first, first + 1] and [s.in_flight[f].sample for f in sorted(s.in_flight)] == [0, 1]
    assert {frame for pairs in renders(actions).values() for frame, _ in pairs} == {first + 1}
    assert all(len(node.outstanding) == 2 for node in s.nodes.values()), "queued behind the first sample"
    s.tick(wanted + 0.01)
    assert not renders(s.drain()) and len(s.in_flight) == 2, "max_in_flight holds the third back"
    assert published(finish(s, first, 0.3)) == [first]
    samples = set(s.in_flight)
    assert len(samples) == 2 and all(s.in_flight[f].still for f in samples), "the third went ahead in turn"
    s.set_camera(camera(1), 0.31)
    actions = s.drain()
    assert not samples & set(s.in_flight) and not any(job.still for job in s.in_flight.values())
    assert max(samples) in {frame for frames in cancels(actions).values() for frame in frames}, "nodes skip it"
    assert renders(actions), "the interactive frame starts at once"


@pytest.mark.parametrize("local", [(True, True), (True, False)])
def test_samples_travel_raw_when_every_node_is_on_the_coordinators_machine(local) -> None:
    """A still's samples are asked for raw from nodes that all connected over loopback (the
    coordinator accumulates them), in the still codec otherwise; interactive frames keep theirs."""
    s = FrameScheduler(SchedulerConfig(size=(64, 48), max_fps=1e6, settle_frames=0, still_delay_ms=0,
                                       still_samples=2), StaticBalancer())
    for node_id, on_this_machine in enumerate(local, 1):
        s.add_node(node_id, 0.0, local=on_this_machine)
        s.node_ready(node_id, 0.0)
    s.set_camera(camera(), 0.0)
    s.drain()
    assert s.in_flight[1].codec is Codec.JPEG
    finish(s, 1, 0.05)
    s.tick(0.1)
    codecs = {a.message.codec for a in s.drain() if isinstance(a, RenderTiles)}
    assert codecs == ({Codec.RAW} if all(local) else {Codec.PNG})


@pytest.mark.parametrize("local, video_only, size", [((True, True), True, (1280, 720)),
                                                     ((True, False), True, (1280, 720)),
                                                     ((True, True), False, (1280, 720)),
                                                     ((True, True), True, (1282, 720))])
def test_a_video_only_sessions_interactive_tiles_travel_raw_from_local_nodes(local, video_only, size) -> None:
    """While every viewer takes the session as video (issue 21), its interactive tiles, the
    encoder's source, are asked for raw from nodes that all connected over loopback, for frames
    the stream thread can afford to convert (up to 1280×720); otherwise (a node elsewhere, a
    viewer of tiles, a larger frame) as JPEG at the video source's quality."""
    s = FrameScheduler(SchedulerConfig(size=size, max_fps=1e6, settle_frames=0, still_delay_ms=0),
                       StaticBalancer())
    for node_id, on_this_machine in enumerate(local, 1):
        s.add_node(node_id, 0.0, local=on_this_machine)
        s.node_ready(node_id, 0.0)
    s.default.video_source_quality, s.default.video_only = 88, video_only
    s.set_camera(camera(), 0.0)
    s.drain()
    job = s.in_flight[1]
    if all(local) and video_only and full_analysis(size):
        assert job.codec is Codec.RAW
    else:
        assert (job.codec, job.jpeg_quality) == (Codec.JPEG, 88)


def test_a_one_sample_still_is_not_jittered() -> None:
    s = scheduler(still_delay_ms=0)
    s.set_camera(camera(), 0.0)
    s.drain()
    finish(s, 1, 0.05)
    s.tick(0.1)
    (still,) = s.in_flight.values()
    assert still.still and still.samples == 1 and still.subsample is None
    assert all(a.message.jitter is None and a.message.lod_bias is None
               and not {"jitter", "lod_bias"} & set(a.message.to_json())
               for a in s.drain() if isinstance(a, RenderTiles))


def test_a_refinement_frame_says_its_samples_in_the_frame_header_and_old_frames_are_unchanged() -> None:
    tiles = [(Rect(0, 0, 2, 1), Codec.RAW, 3, bytes(6))]
    plain = pack_frame(9, (2, 1), tiles, still=True, input_seq=4)
    assert plain == pack_frame(9, (2, 1), tiles, still=True, input_seq=4, samples=0)
    assert unpack_frame(plain).samples == 0 and unpack_frame(plain).still
    refining = unpack_frame(pack_frame(9, (2, 1), tiles, samples=5))
    assert refining.samples == 5 and not refining.still
    final = unpack_frame(pack_frame(9, (2, 1), tiles, still=True, samples=MAX_STILL_SAMPLES))
    assert final.samples == MAX_STILL_SAMPLES and final.still and final.input_seq == 0
    with pytest.raises(ValueError):
        pack_frame(9, (2, 1), tiles, samples=MAX_STILL_SAMPLES + 1)


def test_the_coordinator_refiner_shows_the_converged_mean_exactly_and_skips_a_sample_out_of_turn() -> None:
    """Samples come as tiles (two rects, RAW or PNG); the converged still's tiles are the exact mean
    of the samples, encoded in the still codec; refinements of fewer than FIRST_SHOWN samples are not
    shown, later ones as JPEG near the mean (after the first, only if no later sample waits already);
    a sample whose predecessor is missing is not added."""
    rng = np.random.default_rng(5)
    samples = FIRST_SHOWN + 2
    frames = [rng.integers(0, 256, (4, 6, 3), dtype=np.uint8) for _ in range(samples)]
    rects = [Rect(0, 0, 4, 4), Rect(4, 0, 2, 4)]

    def tiles(frame: np.ndarray, codec: Codec = Codec.PNG) -> list:
        return [(r, codec, i, encode(frame[r.y:r.y1, r.x:r.x1], codec)) for i, r in enumerate(rects)]

    def image(out: list) -> np.ndarray:
        return np.concatenate([decode(t[3], t[1], t[0].w, t[0].h) for t in out], axis=1)

    plan = StillPlan(samples)
    with ThreadPoolExecutor(1) as pool:
        refiner = StillRefiner(pool)
        for sample in range(samples):
            codec = Codec.RAW if sample % 2 else Codec.PNG
            refined = refiner.submit(sample, plan, (6, 4), tiles(frames[sample], codec), Codec.PNG, 95).result()
            if sample + 1 < FIRST_SHOWN:
                assert refined is None, "too few samples to show"
                continue
            assert refined is not None and refined.samples == sample + 1
            assert refined.converged == (sample + 1 == samples)
            out = refined.tiles
            assert [t[0] for t in out] == rects and [t[2] for t in out] == [0, 1]
            expected = accumulate(frames[:sample + 1])
            if sample + 1 < samples:
                assert {t[1] for t in out} == {Codec.JPEG} and psnr(image(out), expected) > 30.0
            else:
                assert {t[1] for t in out} == {Codec.PNG} and np.array_equal(image(out), expected)
        assert refiner.submit(samples + 2, plan, (6, 4), tiles(frames[0]), Codec.PNG, 95).result() is None
        assert refiner.pending == samples + 1 and refiner.cpu_ms > 0.0
        # A later sample submitted before the thread takes a refinement: that refinement is not shown.
        gate = threading.Event()
        pool.submit(gate.wait)
        waiting = [refiner.submit(k, plan, (6, 4), tiles(frames[k]), Codec.PNG, 95) for k in range(samples)]
        gate.set()
        shown = [k + 1 for k, future in enumerate(waiting) if future.result() is not None]
        assert shown == [FIRST_SHOWN, samples], "the first refinement shown always, then the converged still"
        # A point cloud's still of every point after its first still: only the converged mean is shown.
        quiet = [refiner.submit(k, plan, (6, 4), tiles(frames[k]), Codec.PNG, 95, refinements=False).result()
                 for k in range(samples)]
        assert all(refined is None for refined in quiet[:-1]) and quiet[-1] is not None
        assert np.array_equal(image(quiet[-1].tiles), accumulate(frames)), "the converged still, exact"


def test_the_refiner_stops_an_adaptive_still_where_it_converged_and_adds_no_later_sample() -> None:
    """An adaptive still is converged at the first check whose estimate reaches the target: that
    sample's result is the still (the exact mean in the still codec, with its estimate), and the
    samples already on their way after it are not added."""
    rng = np.random.default_rng(8)
    truth = rng.integers(0, 256, (4, 6, 3)).astype(np.float64)
    frames = [np.clip(truth + rng.normal(0, 3.0, truth.shape), 0, 255).astype(np.uint8) for _ in range(24)]
    rect = Rect(0, 0, 6, 4)
    plan = StillPlan(ADAPTIVE, max_samples=24, target_db=estimate_after(frames, 16) - 1e-9)
    with ThreadPoolExecutor(1) as pool:
        refiner = StillRefiner(pool)
        results = [refiner.submit(k, plan, (6, 4), [(rect, Codec.RAW, 0, frames[k].tobytes())], Codec.PNG, 95).result()
                   for k in range(20)]
    converged = [r for r in results if r is not None and r.converged]
    assert len(converged) == 1 and converged[0].samples == 16 and results[15] is converged[0]
    assert converged[0].estimate_db == pytest.approx(estimate_after(frames, 16))
    (tile,) = converged[0].tiles
    assert tile[1] is Codec.PNG and np.array_equal(decode(tile[3], Codec.PNG, 6, 4), accumulate(frames[:16]))
    assert results[16:] == [None] * 4, "samples after convergence are not added"
