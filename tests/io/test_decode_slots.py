"""The frame service's decoders decode at most `DECODE_SLOTS` frames at once (by default
as many as the cores), so a camera's thread beyond them waits for a slot instead of
competing for the cores and the GIL with the GUI thread; closing ends them all."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from carapost.io import frameservice, video
from carapost.io.encode import FFV1Writer
from carapost.io.frameservice import DecodeSlots, FrameService, decode_slots, shared_slots
from carapost.model.project import CameraChannel, Take

W, H, N, CAMERAS = 64, 48, 60, 4
FPS = 60.0


def _write(path: Path, cam: int) -> Path:
    with FFV1Writer(path, (W, H), FPS, gop=1) as writer:
        for i in range(N):
            img = np.full((H, W), 40 * cam, np.uint8)
            img[:4, :4] = i
            writer.write(img)
    return path


@pytest.fixture(scope="module")
def take(tmp_path_factory) -> Take:
    folder = tmp_path_factory.mktemp("slots")
    cams = [CameraChannel(name=f"cam{c}", video_path=str(_write(folder / f"s_cam{c}.mkv", c)),
                          image_size=(W, H)) for c in range(CAMERAS)]
    return Take(name="s", n_frames=N, cameras=cams, fps=FPS)


@pytest.fixture
def counted_reads(monkeypatch):
    """Every video read takes 15 ms; the most reads that ran at once is recorded."""
    original = video.VideoSource.read
    state = {"now": 0, "peak": 0}
    lock = threading.Lock()

    def read(self, index):
        with lock:
            state["now"] += 1
            state["peak"] = max(state["peak"], state["now"])
        try:
            time.sleep(0.015)
            return original(self, index)
        finally:
            with lock:
                state["now"] -= 1

    monkeypatch.setattr(video.VideoSource, "read", read)
    return state


def _wait_all(fs: FrameService, frame: int, timeout: float = 10.0) -> bool:
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        if all(fs.get_cached(frame, c) is not None for c in range(CAMERAS)):
            return True
        time.sleep(0.005)
    return False


def test_default_is_the_cores_of_the_process():
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)
    assert decode_slots() == max(expected, 1)


@pytest.mark.parametrize("slots", [1, 2])
def test_jumps_steps_and_playback_never_decode_more_frames_at_once(
        take, counted_reads, monkeypatch, slots):
    monkeypatch.setattr(frameservice, "DECODE_SLOTS", slots)
    with FrameService(take) as fs:
        fs.request(30)  # a jump: four cameras wanted at once
        assert _wait_all(fs, 30)
        fs.request(31, direction=1)  # a step, with read-ahead behind it
        assert _wait_all(fs, 31)
        fs.set_read_ahead(int(2 * FPS), playing=True)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < 0.4:
            fs.set_clock(int((time.perf_counter() - t0) * FPS))
            time.sleep(0.008)
        # a job (Detect Blobs [Current Frame]) goes through the same slots
        img = fs.get(50, 2)
        assert fs._slots.limit == slots
    assert counted_reads["peak"] == slots  # every slot was used, never more
    assert int(img[0, 0]) == 50 and int(img[10, 10]) == 80  # the video's own pixels


def test_two_open_takes_share_the_slots(take, counted_reads, monkeypatch):
    """While a take opens the previous one's decoders may still run: together they
    stay within the slots."""
    monkeypatch.setattr(frameservice, "DECODE_SLOTS", 2)
    with FrameService(take) as old, FrameService(take) as new:
        assert old._slots is new._slots is shared_slots()
        old.request(20)
        new.request(40)
        assert _wait_all(old, 20) and _wait_all(new, 40)
    assert counted_reads["peak"] == 2


def test_closing_ends_decoders_waiting_for_a_slot(take, counted_reads, monkeypatch):
    monkeypatch.setattr(frameservice, "DECODE_SLOTS", 1)
    fs = FrameService(take)
    fs.request(10)  # four cameras, one slot: three threads wait at the gate
    time.sleep(0.03)
    decoders = [t for t in threading.enumerate() if t.name.startswith("carapost-decode")]
    assert len(decoders) == CAMERAS
    fs.close()
    for t in decoders:
        t.join(timeout=5)
    assert not any(t.is_alive() for t in decoders)


def test_slots_wait_and_count():
    slots = DecodeSlots(2)
    inside, peak, lock = [0], [0], threading.Lock()

    def work():
        with slots:
            with lock:
                inside[0] += 1
                peak[0] = max(peak[0], inside[0])
            time.sleep(0.01)
            with lock:
                inside[0] -= 1

    threads = [threading.Thread(target=work) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert peak[0] == slots.peak == 2
    assert DecodeSlots(0).limit == 1  # at least one decode at a time


def test_read_ahead_leaves_a_core_to_the_gui_thread():
    """Read-ahead decodes start only while fewer than `ahead_limit` (one core fewer
    than the slots) decode; urgent ones use every slot and never queue behind
    read-ahead that waits for its cap."""
    slots = DecodeSlots(2)
    assert slots.ahead_limit == 1 and DecodeSlots(1).ahead_limit == 1
    assert DecodeSlots(4, ahead_limit=9).ahead_limit == 4
    assert slots.acquire(urgent=False)  # one read-ahead decodes
    got: list[str] = []

    def ask(name: str, urgent: bool) -> threading.Thread:
        def run():
            slots.acquire(urgent)
            got.append(name)
        t = threading.Thread(target=run)
        t.start()
        return t

    ahead = ask("ahead", False)
    while not slots._queues[1]:
        time.sleep(0.001)
    assert got == []  # a second read-ahead waits: the other core is the GUI's
    view = ask("view", True)
    view.join(timeout=5)
    assert got == ["view"] and slots._busy == 2  # the view's decode took the free slot
    slots.release()  # the view's: the read-ahead would make two with the first one
    assert got == ["view"] and slots._busy == 1
    slots.release()  # the first read-ahead's: now the waiting one starts
    ahead.join(timeout=5)
    assert got == ["view", "ahead"] and slots._busy == 1 and slots.peak == 2
    slots.release()
    assert slots._busy == 0


def test_a_slot_given_up_goes_to_the_waiters_urgent_first():
    """A thread reading ahead that gives its slot up and asks again at once queues
    behind the waiters (no barging), and urgent waiters go before read-ahead."""
    slots = DecodeSlots(1)
    order: list[str] = []
    slots.acquire(urgent=False)  # a decoder reading ahead holds the only slot

    def wait(name: str, urgent: bool) -> threading.Thread:
        def run():
            slots.acquire(urgent)
            order.append(name)
            slots.release()
        t = threading.Thread(target=run)
        t.start()
        while len(slots._queues[0]) + len(slots._queues[1]) < wait.count + 1:
            time.sleep(0.001)
        wait.count += 1
        return t

    wait.count = 0
    threads = [wait("ahead-1", False), wait("view-1", True), wait("view-2", True)]
    slots.release()
    slots.acquire(urgent=False)  # asks again at once: behind every waiter
    order.append("again")
    slots.release()
    for t in threads:
        t.join(timeout=5)
    assert order == ["view-1", "view-2", "ahead-1", "again"]
    assert slots._busy == 0 and slots.peak == 1


def test_a_cancelled_read_ahead_wait_returns_without_a_slot():
    """A read-ahead waiting for a slot is called off (its camera's frame was asked for):
    it returns at once without a slot, and the slot still goes to the next waiter."""
    from carapost.io.decode_slots import SlotWait

    slots = DecodeSlots(1)
    slots.acquire()  # a view's decode holds the only slot
    wait, got = SlotWait(), []
    t = threading.Thread(target=lambda: got.append(slots.acquire(False, wait)))
    t.start()
    while not slots._queues[1]:
        time.sleep(0.001)
    slots.cancel(wait)
    t.join(timeout=5)
    assert got == [False] and not slots._queues[1]
    slots.release()
    assert slots.acquire(True) is True  # the slot was free again, not lost
    slots.release()
    # cancelled before it queued: the acquire sees it and never waits
    early = SlotWait()
    slots.cancel(early)
    assert slots.acquire(False, early) is False
    # handed the slot already: cancelling changes nothing, it releases as usual
    late = SlotWait()
    assert slots.acquire(False, late) is True
    slots.cancel(late)
    slots.release()
    assert slots._busy == 0


def test_a_jump_does_not_wait_for_read_ahead_queued_for_a_slot(take, monkeypatch):
    """With one slot and every camera reading ahead, a jump's four frames are the next
    four decodes: no camera decodes a stale read-ahead frame first."""
    monkeypatch.setattr(frameservice, "DECODE_SLOTS", 1)
    decoded: list[tuple[int, int]] = []
    original = video.VideoSource.read
    lock = threading.Lock()

    def read(self, index):
        time.sleep(0.01)
        img = original(self, index)
        with lock:
            decoded.append((int(img[0, 0]), int(img[10, 10]) // 40))
        return img

    monkeypatch.setattr(video.VideoSource, "read", read)
    with FrameService(take) as fs:
        fs.set_read_ahead(24)
        fs.request(5, direction=1)
        assert _wait_all(fs, 5)
        time.sleep(0.03)  # every camera reads ahead now, three of them queued for the slot
        with lock:
            before = len(decoded)
        fs.request(45, direction=1)
        assert _wait_all(fs, 45)
        with lock:
            after = decoded[before:]
    # at most the one read-ahead frame in hand finishes before the jump's frames
    first = [i for i, (frame, _) in enumerate(after) if frame == 45]
    assert len(first) == CAMERAS and first[-1] <= CAMERAS, after[:8]
