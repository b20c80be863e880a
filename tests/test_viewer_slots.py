"""Viewer fan-out: a latest-frame slot per viewer; frames may be skipped, control messages never."""

from __future__ import annotations

import asyncio
import json

from server.viewers import MAX_QUEUED_CONTROL, ViewerHub, ViewerSlot
from tessera.geometry import Camera
from tessera.wire.messages import CameraUpdate, ViewerError


class Frame:
    """A published interactive frame whose message is the same bytes for every viewer."""

    still = False
    samples = 0

    def __init__(self, body: bytes) -> None:
        self.body = body

    def message_for(self, viewer_id: object) -> bytes:
        return self.body

DEADLINE_S = 30.0


async def settle() -> None:
    """Let every ready task run until it blocks (a few event-loop turns, no wall-clock wait)."""
    for _ in range(5):
        await asyncio.sleep(0)


def test_a_slow_consumer_sees_only_the_newest_frame():
    async def scenario() -> None:
        slot = ViewerSlot()
        for i in range(5):
            slot.put_frame(b"frame %d" % i)
        assert await slot.next_message() == b"frame 4"
        assert (slot.frames_dropped, slot.frames_sent) == (4, 1)
        slot.put_frame(b"frame 5")
        assert await slot.next_message() == b"frame 5"
        assert (slot.frames_dropped, slot.frames_sent) == (4, 2)

    asyncio.run(scenario())


def test_a_consumer_that_never_reads_holds_one_frame():
    async def scenario() -> None:
        slot = ViewerSlot()
        for i in range(1000):
            slot.put_frame(bytes([i % 256]) * 100)
        assert slot.frames_dropped == 999
        assert await slot.next_message() == bytes([999 % 256]) * 100
        waiter = asyncio.create_task(slot.next_message())
        await settle()
        assert not waiter.done(), "nothing is left after the newest frame"
        waiter.cancel()

    asyncio.run(scenario())


def test_control_messages_come_first_in_order_and_are_never_dropped():
    async def scenario() -> None:
        slot = ViewerSlot()
        slot.put_frame(b"old")
        for i in range(100):
            slot.put_control(ViewerError(message=str(i)))
        slot.put_frame(b"new")
        received = [await slot.next_message() for _ in range(101)]
        assert [json.loads(m)["message"] for m in received[:100]] == [str(i) for i in range(100)]
        assert all(isinstance(m, str) for m in received[:100])
        assert received[100] == b"new"
        assert (slot.frames_dropped, slot.frames_sent) == (1, 1)

    asyncio.run(scenario())


def test_a_viewer_that_does_not_read_is_behind_once_its_queue_is_full():
    async def scenario() -> None:
        slot = ViewerSlot()
        for i in range(MAX_QUEUED_CONTROL):
            slot.put_control(ViewerError(message=str(i)))
        assert not slot.behind, "a full queue is still every message"
        slot.put_control(ViewerError(message="one too many"))
        assert slot.behind and len(slot.control) == MAX_QUEUED_CONTROL
        assert json.loads(await slot.next_message())["message"] == "0"

    asyncio.run(scenario())


def test_cameras_from_other_viewers_keep_only_the_newest_after_queued_control():
    async def scenario() -> None:
        slot = ViewerSlot()
        cameras = [CameraUpdate(camera=Camera(eye=(0.0, 0.0, 2.0 + i), target=(0.0, 0.0, 0.0))) for i in range(1000)]
        slot.put_frame(b"frame")
        slot.put_control(ViewerError(message="first"))
        for camera in cameras:
            slot.put_control(camera)
        assert not slot.behind, "cameras never fill the queue"
        assert json.loads(await slot.next_message())["message"] == "first"
        assert await slot.next_message() == cameras[-1].to_text()
        assert await slot.next_message() == b"frame"

    asyncio.run(scenario())


def test_a_waiting_consumer_wakes_for_a_frame_and_for_a_control_message():
    async def scenario() -> None:
        slot = ViewerSlot()
        waiter = asyncio.create_task(slot.next_message())
        await settle()
        assert not waiter.done()
        slot.put_frame(b"first")
        assert await asyncio.wait_for(waiter, DEADLINE_S) == b"first"
        waiter = asyncio.create_task(slot.next_message())
        await settle()
        assert not waiter.done(), "the slot was drained; the consumer must wait again"
        slot.put_control(ViewerError(message="x"))
        assert json.loads(await asyncio.wait_for(waiter, DEADLINE_S)) == {"type": "error", "message": "x"}

    asyncio.run(scenario())


def test_a_producer_never_waits_for_a_stalled_consumer():
    async def scenario() -> None:
        hub = ViewerHub()
        stalled, reader = hub.join(), hub.join()
        seen: list[bytes] = []

        async def read() -> None:
            while True:
                message = await reader.next_message()
                seen.append(message)
                if message == b"last":
                    return

        task = asyncio.create_task(read())
        for i in range(50):
            hub.publish_frame(Frame(b"frame %d" % i))
            await asyncio.sleep(0)
        hub.publish_frame(Frame(b"last"))
        await asyncio.wait_for(task, DEADLINE_S)
        numbers = [int(m.split()[1]) for m in seen[:-1]]
        assert seen[-1] == b"last" and numbers == sorted(set(numbers)), "in order, no repeats"
        assert stalled.frames_dropped == 50 and await stalled.next_message() == b"last"

    asyncio.run(scenario())


def test_hub_publishes_to_every_slot_and_broadcasts_with_exclusion():
    async def scenario() -> None:
        hub = ViewerHub()
        hub.publish_frame(Frame(b"nobody"))
        assert hub.bytes_published == 0
        first, second = hub.join(), hub.join()
        assert first.viewer_id != second.viewer_id
        hub.publish_frame(Frame(b"12345"))
        assert hub.bytes_published == 5
        moved = CameraUpdate(camera=Camera(eye=(0.0, 0.0, 2.0), target=(0.0, 0.0, 0.0)))
        hub.broadcast(moved, exclude=first)
        assert await second.next_message() == moved.to_text()
        assert await second.next_message() == b"12345"
        assert await first.next_message() == b"12345"
        assert not first.control
        hub.leave(first)
        hub.leave(first)
        hub.publish_frame(Frame(b"67"))
        assert first.frame is None and await second.next_message() == b"67"
        assert hub.slots == {second} and hub.bytes_published == 7

    asyncio.run(scenario())


def test_each_viewer_gets_its_own_copy_and_its_latency_report_in_the_stats():
    class Tagged:
        still, samples = False, 0

        def message_for(self, viewer_id: object) -> bytes:
            return b"for %d" % viewer_id

    async def scenario() -> None:
        hub = ViewerHub()
        first, second = hub.join(), hub.join()
        hub.publish_frame(Tagged())
        assert await first.next_message() == b"for %d" % first.viewer_id
        assert await second.next_message() == b"for %d" % second.viewer_id
        second.latency = {"p50_ms": 40.0, "p90_ms": 55.0, "samples": 12.0, "interval_ms": 30.0}
        described = hub.describe()
        assert [v["id"] for v in described] == sorted([first.viewer_id, second.viewer_id])
        assert described[1]["input_latency"]["p50_ms"] == 40.0 and described[0]["input_latency"] == {}
        assert described[0]["frames_sent"] == 1

    asyncio.run(scenario())
