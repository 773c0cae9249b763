"""Contact sheets: the views of one frame side by side, with the truth overlaid."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from carapost.synth.render import render_frame
from carapost.synth.scene import SynthScene

__all__ = ["contact_sheet"]


def contact_sheet(scene: SynthScene, frame: int = 0, *, scale: float = 0.5,
                  overlay: bool = True, labels: bool = False, columns: int = 2
                  ) -> NDArray[np.uint8]:
    """A grid of every camera's image of one frame, as a BGR image.

    Parameters
    ----------
    scene : SynthScene
    frame : int
    scale : float
        Downscale factor of each view.
    overlay : bool
        Draw the truth: a red circle around each visible face marker, green around brim dots.
    labels : bool
        Also write the face marker labels.
    columns : int
        Views per row.

    Returns
    -------
    ndarray, shape (rows * h, columns * w, 3), uint8
    """
    w, h = scene.size
    tiles = []
    for c in range(scene.n_cameras):
        img = cv2.cvtColor(render_frame(scene, frame, c), cv2.COLOR_GRAY2BGR)
        img = cv2.resize(img, (int(round(w * scale)), int(round(h * scale))),
                         interpolation=cv2.INTER_AREA)
        if overlay:
            # rings just outside each disc, so the rendered dots stay visible inside them
            R, t = scene.cam_R[frame, c], scene.cam_t[frame, c]
            for uv, vis, pts, rad, col in (
                    (scene.uv, scene.visible, scene.points3d[frame], scene.marker_radius_mm,
                     (40, 40, 255)),
                    (scene.brim_uv, scene.brim_visible, scene.brim3d, scene.brim_radius_mm,
                     (60, 220, 60))):
                depth = (pts @ R.T + t)[:, 2]
                for m in np.nonzero(vis[frame, :, c])[0]:
                    u, v = (uv[frame, m, c] + 0.5) * scale - 0.5
                    r = scene.intrinsics.focal[c] * rad[m] / depth[m] * scale + 2.0
                    cv2.circle(img, (int(round(u * 4)), int(round(v * 4))), int(round(r * 4)),
                               col, 1, cv2.LINE_AA, shift=2)
            if labels:
                for m in np.nonzero(scene.visible[frame, :, c])[0]:
                    u, v = (scene.uv[frame, m, c] + 0.5) * scale - 0.5
                    cv2.putText(img, scene.labels[m], (int(u) + 4, int(v) - 3),
                                cv2.FONT_HERSHEY_PLAIN, 0.6, (0, 200, 255), 1, cv2.LINE_AA)
        cv2.putText(img, f"{scene.intrinsics.names[c]}  frame {frame}", (8, 20),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        cv2.rectangle(img, (0, 0), (img.shape[1] - 1, img.shape[0] - 1), (90, 90, 90), 1)
        tiles.append(img)
    while len(tiles) % columns:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i:i + columns]) for i in range(0, len(tiles), columns)]
    return np.vstack(rows)


def main(argv: list[str] | None = None) -> int:
    """``python -m carapost.synth.preview OUT.png [--frame N] [--preset P] [--seed S]``."""
    import argparse

    from carapost.synth.scene import SynthConfig, build_scene

    p = argparse.ArgumentParser(description="Write a contact sheet of a synthetic frame.")
    p.add_argument("out")
    p.add_argument("--frame", type=int, default=0)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--preset", default="speech")
    p.add_argument("--markers", default="standard")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scale", type=float, default=0.5)
    p.add_argument("--no-overlay", action="store_true")
    a = p.parse_args(argv)
    scene = build_scene(SynthConfig(frames=a.frames, preset=a.preset, markers=a.markers,
                                    seed=a.seed))
    sheet = contact_sheet(scene, a.frame, scale=a.scale, overlay=not a.no_overlay)
    if not cv2.imwrite(a.out, sheet):
        print(f"cannot write {a.out}")
        return 1
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
