"""Blender's movie-clip tracker on the Target Tracker benchmark's frames (a reference).

    python benchmarks/target_track_blender.py [--case speech] [--frames 300]
        [--modes KEYFRAME,PREV_FRAME] [--cache DIR] [--blender blender]

Writes every camera of the rendered synthetic take as a PNG sequence, runs Blender
headless (``blender -b --python this_file -- ...``) once per camera and pattern-match
mode, with one track per face marker visible in all cameras keyed from the truth at the
first frame (pattern 21 px, search 81 px, the "Loc" motion model, brute-force prepass,
normalisation, minimum correlation 0 so that every track runs as far as Blender can
follow it: the same conditions as ``target_track_median_px``), and prints JSON lines:
``blender_median_px``, ``blender_p95_px`` (over every tracked sample),
``blender_wrong_marker`` (tracks with a sample nearer another marker's truth) and
``blender_complete_fraction``, with the CPU time of Blender's tracking. Blender is not a
dependency of carapost: this script only needs the ``blender`` executable (Debian's
package, 3.4.1, was used).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile


def _in_blender(argv: list[str]) -> None:
    """Inside Blender: track the markers of one camera and write them as JSON."""
    import time

    import bpy  # type: ignore[import-not-found]

    meta_path, out_path, mode = argv
    meta = json.load(open(meta_path))
    W, H, F = meta["W"], meta["H"], meta["F"]
    clip = bpy.data.movieclips.load(meta["first_image"])
    clip.frame_start = 1
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, F
    scene.frame_set(1)
    ts = clip.tracking.settings
    ts.default_pattern_size = meta["pattern"]
    ts.default_search_size = meta["search"]
    ts.default_motion_model = "Loc"
    ts.default_pattern_match = mode
    ts.default_correlation_min = 0.0
    ts.use_default_brute = True
    ts.use_default_normalization = True
    tracks = clip.tracking.tracks
    for m, (x, y) in meta["start"].items():
        t = tracks.new(name=f"m{m}", frame=1)
        # Blender: normalised, origin at the bottom-left corner of the image; carapost:
        # pixel centres, origin at the centre of the top-left pixel
        t.markers.find_frame(1).co = ((x + 0.5) / W, 1.0 - (y + 0.5) / H)
        t.select = True
    # the operator needs a Clip Editor: turn the startup file's first area into one
    win = bpy.context.window_manager.windows[0]
    area = win.screen.areas[0]
    area.type = "CLIP_EDITOR"
    area.spaces.active.clip = clip
    t0 = time.process_time()
    with bpy.context.temp_override(window=win, area=area, space_data=area.spaces.active,
                                   edit_movieclip=clip):
        bpy.ops.clip.track_markers(backwards=False, sequence=True)
    cpu = time.process_time() - t0
    out = {}
    for t in tracks:
        xy = []
        for f in range(1, F + 1):
            mk = t.markers.find_frame(f, exact=True)
            xy.append(None if mk is None or mk.mute else
                      (mk.co[0] * W - 0.5, (1.0 - mk.co[1]) * H - 0.5))
        out[t.name[1:]] = xy
    json.dump({"cpu_s": cpu, "tracks": out}, open(out_path, "w"))


def main(argv: list[str] | None = None) -> int:
    import argparse
    import shutil

    import cv2
    import numpy as np

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import target_track as bench
    from carapost.synth import SynthConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="speech", choices=sorted(bench.CASES))
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--modes", default="KEYFRAME,PREV_FRAME")
    ap.add_argument("--cache", default=None)
    ap.add_argument("--blender", default="blender")
    a = ap.parse_args(argv)
    exe = shutil.which(a.blender)
    if exe is None:
        print(f"no Blender executable {a.blender!r} on PATH", file=sys.stderr)
        return 2
    bench.CACHE_DIR = a.cache
    size = tuple(int(v) for v in a.size.split("x"))
    cfg = SynthConfig(frames=a.frames, size=size, **bench.CASES[a.case])
    scene, imgs = bench.render(cfg)
    uv, vis = scene.uv, scene.visible
    markers = np.flatnonzero(vis.all(axis=(0, 2)))
    F, C = imgs.shape[:2]
    for mode in a.modes.split(","):
        errs, wrong, complete, cpu = [], 0, 0, 0.0
        for c in range(C):
            with tempfile.TemporaryDirectory() as tmp:
                for f in range(F):
                    cv2.imwrite(os.path.join(tmp, f"{f + 1:04d}.png"), np.asarray(imgs[f, c]))
                meta = {"W": size[0], "H": size[1], "F": F, "pattern": 21, "search": 81,
                        "first_image": os.path.join(tmp, "0001.png"),
                        "start": {str(m): [float(v) for v in uv[0, m, c]] for m in markers}}
                meta_path, out_path = os.path.join(tmp, "meta.json"), os.path.join(tmp, "o.json")
                json.dump(meta, open(meta_path, "w"))
                subprocess.run([exe, "-b", "--factory-startup", "--python", __file__, "--",
                                meta_path, out_path, mode], check=True,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                out = json.load(open(out_path))
            cpu += out["cpu_s"]
            for m, xy in out["tracks"].items():
                m = int(m)
                p = np.array([[np.nan, np.nan] if q is None else q for q in xy], float)
                errs.append(np.linalg.norm(p[1:] - uv[1:, m, c], axis=-1))
                wrong += bench._wrong(p, np.arange(F), uv[:, :, c], m)
                complete += int(np.isfinite(p[-1, 0]))
        E = np.array(errs)
        common = {"case": a.case, "mode": mode, "tracks": len(E), "frames": F,
                  "blender_cpu_s": round(cpu, 1)}
        bench.emit("blender_median_px", round(float(np.nanmedian(E)), 4), "px", **common)
        bench.emit("blender_p95_px", round(float(np.nanpercentile(E, 95)), 4), "px", **common)
        bench.emit("blender_wrong_marker", wrong, "tracks", **common)
        bench.emit("blender_complete_fraction", round(complete / len(E), 3), "fraction",
                   **common)
    return 0


def _inside_blender() -> bool:
    try:
        import bpy  # type: ignore[import-not-found]  # noqa: F401
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    if _inside_blender():
        _in_blender(sys.argv[sys.argv.index("--") + 1:])
    else:
        sys.exit(main())
