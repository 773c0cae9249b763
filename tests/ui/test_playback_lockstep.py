"""Playback from the originals in lockstep: when the decoders cannot keep up, the
window shows whole frames only (every camera on the frame shown), and the frames the
decoders spent their time on are the frames shown."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from carapost.io import video
from carapost.io.encode import FFV1Writer
from carapost.io.lockstep import AHEAD_SLACK, LOCKSTEP_SLACK
from carapost.model.project import new_project

W, H, N, CAMERAS = 96, 64, 120, 4


def test_slow_decoders_play_whole_frames(make_window, qtbot, monkeypatch, tmp_path):
    p = new_project(N, CAMERAS, image_size=(W, H))
    for c, cam in enumerate(p.take.cameras):
        path = tmp_path / f"t_cam{c}.mkv"
        with FFV1Writer(path, (W, H), 60.0) as writer:
            for f in range(N):
                img = np.full((H, W), 30 * c, np.uint8)
                img[:4, :4] = f
                writer.write(img)
        cam.video_path = str(path)
    original = video.VideoSource.read
    # slower than the take's 60 frames/s, and each camera at its own speed
    delay = {f"t_cam{c}.mkv": 0.02 + 0.008 * c for c in range(CAMERAS)}

    def slow(self, index):
        time.sleep(delay[Path(self.path).name])
        return original(self, index)

    monkeypatch.setattr(video.VideoSource, "read", slow)
    w = make_window(p)
    w.show()
    views = sorted((v for v in w.all_views() if v.kind == "sensor"), key=lambda v: v.camera)
    frames = w.context.frames
    seen: list[tuple[int, list[int | None]]] = []
    decoded: list[set[int]] = []  # per camera, the frames cached while playing

    def follow(change) -> None:
        if w.context.playback.playing:
            seen.append((p.current_frame, [v.image_frame for v in views]))
            decoded[:] = [{f for f in range(N) if frames.cached(f, c) is not None}
                          for c in range(CAMERAS)]

    w.context.view.changed.connect(follow)
    p.set_view_range((0, N - 1))
    w.action("view.play").trigger()
    qtbot.waitUntil(lambda: not w.context.playback.playing, timeout=30000)
    pb = w.context.playback
    assert pb.dropped > 0 and pb.shown > 5
    # every frame shown was drawn by all four views at once (the views follow the
    # change before this test's listener does)
    shown = [frame for frame, _ in seen]
    for frame, drawn in seen:
        assert drawn == [frame] * CAMERAS
    # the decoders worked on the frames shown: of the frames any camera decoded while
    # playing, nearly all are complete; the partial ones are about a schedule's slack
    # (read ahead as playback starts, in flight as it stops: on a loaded machine a few
    # more; chasing the clock alone left 70-101 of them, most of what was decoded)
    complete = set.intersection(*decoded)
    union = set.union(*decoded)
    partial = union - complete
    assert len(partial) <= max(AHEAD_SLACK + LOCKSTEP_SLACK, len(union) // 5), \
        (sorted(partial), len(union))
    assert set(shown) <= complete
