"""Where the Target Tracker's error tail on the ``noisy`` case comes from.

    python benchmarks/target_track_noisy_tail.py [--frames 300] [--cache DIR]
        [--scratch DIR]

The ``noisy`` case of ``benchmarks/target_track.py`` is the speech take with noise 5 and
motion blur, one keyframe from the truth at frame 0, tracked forwards at Break Threshold
0. Its error has three possible sources: the keyframe image (its noise, its motion
blur) and the tracked frames (their noise, their blur). This script tracks the same
markers with the keyframe image and the frames swapped between renders of the same take
(the same scene and truth; ``speech`` without either, ``blur`` with motion blur only,
``noise`` with noise only, ``noisy`` with both), so each source is switched off in turn:

- ``noisy frames, <key>``: the noisy case's frames, the keyframe image from the noisy
  render (the benchmark), the blurred noiseless render, the sharp noiseless render, or
  the sharp render plus the noisy render's own noise at frame 0 (``noisy - blur``);
- ``blur frames`` / ``noise frames``: frames with one of the two, the keyframe from the
  same render or the sharp noiseless one.

Prints JSON lines: ``noisy_tail_median_px`` and ``noisy_tail_p95_px`` (over every tracked
sample, as ``target_track_p95_px``) per ``run``, and ``noisy_tail_first_step_px`` (the
markers' median image motion from frame 0 to 1, and from 1 to 2: the speech take starts
with a jump, so the keyframe at frame 0 is blurred by it). ``--cache`` is where
``benchmarks/target_track.py`` keeps its renders (read from it); ``--scratch`` keeps the
two extra renders (``blur``, ``noise``) between runs.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import target_track as tt
from carapost.algorithms.target_track import TargetTrackerParameters
from carapost.synth import SynthConfig


class _Keyed:
    """``frames[f, c]`` with frame 0 of every camera replaced by ``key_img(c)`` (the
    keyframe image), indexed like the benchmark's image arrays for `target_track.ours`."""

    def __init__(self, frames: np.ndarray, key_img) -> None:
        self.frames, self.key_img, self.keys = frames, key_img, {}

    def __getitem__(self, fc: tuple[int, int]) -> np.ndarray:
        f, c = fc
        if f != 0:
            return self.frames[f, c]
        if c not in self.keys:
            self.keys[c] = self.key_img(c)
        return self.keys[c]


def _errors(frames_imgs: np.ndarray, key_img, uv: np.ndarray, markers: np.ndarray
            ) -> np.ndarray:
    """(tracks, F - 1) errors (px) of every marker in every camera, keyframe at 0 from
    ``key_img(c)``, the other frames from ``frames_imgs``; NaN where not tracked."""
    params = TargetTrackerParameters(break_threshold=0.0)
    return tt.ours(_Keyed(frames_imgs, key_img), uv, markers, params)[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--cache", default=None)
    ap.add_argument("--scratch", default=None)
    args = ap.parse_args(argv)
    size = (1280, 720)
    base = {"frames": args.frames, "size": size}
    tt.CACHE_DIR = args.cache
    scene, noisy = tt.render(SynthConfig(**base, **tt.CASES["noisy"]))
    _, sharp = tt.render(SynthConfig(**base, **tt.CASES["speech"]))
    tt.CACHE_DIR = args.scratch
    _, blur = tt.render(SynthConfig(**base, preset="speech", motion_blur=True))
    _, noise = tt.render(SynthConfig(**base, preset="speech", noise=5.0))
    uv, vis = scene.uv, scene.visible
    markers = np.flatnonzero(vis.all(axis=(0, 2)))
    v01 = np.linalg.norm(uv[1, markers] - uv[0, markers], axis=-1)
    v12 = np.linalg.norm(uv[2, markers] - uv[1, markers], axis=-1)
    tt.emit("noisy_tail_first_step_px", round(float(np.median(v01)), 2), "px",
            second_step_px=round(float(np.median(v12)), 2),
            tracks_over_2px=int((v01 > 2).sum()), tracks=int(v01.size))

    def own_noise(c: int) -> np.ndarray:   # the noisy render's noise at frame 0, on sharp
        d = noisy[0, c].astype(np.float64) - blur[0, c]
        return np.clip(np.round(sharp[0, c] + d), 0, 255).astype(np.uint8)

    runs = {
        "noisy frames, noisy key (the benchmark)": (noisy, lambda c: noisy[0, c]),
        "noisy frames, blurred noiseless key": (noisy, lambda c: blur[0, c]),
        "noisy frames, sharp noiseless key": (noisy, lambda c: sharp[0, c]),
        "noisy frames, sharp key + its noise": (noisy, own_noise),
        "blur frames, blurred key": (blur, lambda c: blur[0, c]),
        "blur frames, sharp key": (blur, lambda c: sharp[0, c]),
        "noise frames, noisy key": (noise, lambda c: noise[0, c]),
        "noise frames, sharp noiseless key": (noise, lambda c: sharp[0, c]),
    }
    for name, (imgs, key) in runs.items():
        E = _errors(imgs, key, uv, markers)
        tt.emit("noisy_tail_median_px", round(float(np.nanmedian(E)), 4), "px", run=name)
        tt.emit("noisy_tail_p95_px", round(float(np.nanpercentile(E, 95)), 4), "px",
                run=name, tracks=int(E.shape[0]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
