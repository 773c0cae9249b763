"""Target Tracker runs: the cameras that lost the marker, tracked again from the others.

A lip marker moving 15-30 px a frame is lost by some cameras while one goes on; its 3D
from that one camera is then only as good as the depth its neighbours predict (0.2-0.7
mm on the missed-marker takes, `benchmarks/target_track.py`). :func:`reacquire`
projects the point's 3D from the cameras that still see it into the ones that stopped
and tracks them again from there, so those frames are triangulated. It runs inside
:meth:`carapost.commands.target_track.TargetTrackJob.compute`, after the lockstep run
and before the 3D is solved; units are raw pixels and mm.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from carapost.algorithms.camera import project as project_points
from carapost.algorithms.target_track import STOP_THRESHOLD, track_target
from carapost.commands.recipe import Progress

if TYPE_CHECKING:
    from carapost.commands.target_track import TargetTrackJob

__all__ = ["REACQUIRE_ATTEMPTS", "REACQUIRE_PX", "REACQUIRE_SKIP", "REACQUIRE_TRI_PX",
           "reacquire"]

#: A restarted camera's track is kept while it lies this close (px) to the projection of
#: the point's 3D from the other cameras (one camera's 3D at the predicted depth
#: projects 0.1-1.5 px off on the missed-marker takes; a neighbouring marker is 20 px
#: or more away).
REACQUIRE_PX = 3.0
#: ... and within this (px) of the projection of the point triangulated from two other
#: cameras or more.
REACQUIRE_TRI_PX = 0.35
#: Where a restart keeps nothing, the next is tried this many frames on.
REACQUIRE_SKIP = 2
#: Restarts tried per lost track at most (each failed one costs a frame or two).
REACQUIRE_ATTEMPTS = 60


def reacquire(job: TargetTrackJob, block: dict[str, NDArray], touched: NDArray,
              results: list[Any], reasons: dict[tuple[int, int], str],
              progress: Progress, total: int) -> tuple[int, bool]:
    """Put the cameras that lost the marker back where the others still see it.

    Where a camera stopped (score
    below the Break Threshold) and the point still has 3D from the other cameras,
    that 3D is projected into it and the camera tracks again from there
    (:func:`~carapost.algorithms.target_track.track_target` from the projection,
    its own keyframes, no motion assumed, so that the first step is checked against
    every disc around it), up to the track's own stop. A frame is kept while it
    scores above the Break Threshold and lies within `REACQUIRE_PX` of the
    projection (a neighbouring marker is farther); the 3D is solved again after
    every kept restart, so a second camera back makes the projection into a third
    a triangulated one. Where a restart keeps nothing, the next is tried
    `REACQUIRE_SKIP` frames on.

    Writes the kept frames into ``block`` (as the run's own) and ``touched``;
    returns how many observations it added and whether it was paused:
    ``progress(total, total)`` is asked before every restart (the run's frames are
    done), and False stops there (Pause keeps what was put back).
    """
    d, P = job.direction, job.params
    index = {pid: i for i, pid in enumerate(job.ids)}
    n = len(touched)
    # per lost track: the next frame to try a restart from (block row)
    nxt: dict[int, int] = {}
    for j, res in enumerate(results):
        if res is not None and res.reason == STOP_THRESHOLD:
            nxt[j] = int(res.frames[-1]) - job.first
    added, budget = 0, REACQUIRE_ATTEMPTS * len(nxt)
    X: dict[int, NDArray[np.float64]] = {}

    def solved(i: int) -> NDArray[np.float64]:
        if i not in X:
            out = np.full((n, 3), np.nan)
            rows = np.flatnonzero(touched)
            if len(rows):
                out[rows] = job.solve(block, touched, i)[0]
            X[i] = out
        return X[i]

    while nxt and budget > 0:
        if progress is not None and progress(total, total) is False:   # Pause
            return added, True
        # the earliest restart in the direction of travel: its 3D is the best known
        j = min(nxt, key=lambda j: nxt[j] * d)
        tr, g = job.tracks[j], nxt[j]
        i, c = index[tr.point], tr.camera
        end = tr.stop - job.first
        if (end - g) * d <= 0:
            del nxt[j]
            continue
        Xi = solved(i)
        # the first frame from g on where this camera has nothing and the point 3D
        span = np.arange(g, end, d)
        free = span[~np.isfinite(block["obs"][span, i, c, 0])
                    & np.isfinite(Xi[span]).all(-1)]
        if not len(free):
            del nxt[j]
            continue
        if free[0] != g:
            nxt[j] = int(free[0])
            continue
        budget -= 1
        uv = project_points(Xi[:, None], job.R, job.t, job.intr)[0][:, 0, c]  # (n, 2)
        try:
            res = track_target(lambda f, c=c: job.get_image(f, c), tr.keys,
                               start=g + job.first, stop=tr.stop, direction=d,
                               params=tr.params if tr.params is not None else P,
                               start_xy=uv[g])
        except ValueError:   # the projection's pattern box leaves the image
            nxt[j] = g + REACQUIRE_SKIP * d
            continue
        ok = res.tracked & (res.frames != res.frames[0])
        fr = res.frames[ok] - job.first
        xy = res.xy[ok]
        # kept while another camera sees the point (the frame is triangulated, not
        # a new one-camera stretch), the track stays on that 3D, and this camera
        # has no data there
        n_others = np.isfinite(np.delete(block["obs"][fr, i, :, 0], c, axis=1)).sum(1)
        dist = np.linalg.norm(xy - uv[fr], axis=-1)
        far = ~(dist <= REACQUIRE_PX)
        busy = np.isfinite(block["obs"][fr, i, c, 0])
        cut = np.flatnonzero(far | busy | (n_others == 0))
        keep = cut[0] if len(cut) else len(fr)
        fr, xy, sc = fr[:keep], xy[:keep], res.score[ok][:keep]
        # where two other cameras or more triangulate the point its projection is
        # good to a few tenths of a pixel: a frame farther off is this camera's
        # mismatch (a lip's look changed since the keyframe), left out
        off = (n_others[:keep] >= 2) & (dist[:keep] > REACQUIRE_TRI_PX)
        fr, xy, sc = fr[~off], xy[~off], sc[~off]
        if not len(fr):
            nxt[j] = g + REACQUIRE_SKIP * d
            continue
        job.write_tracked(block, touched, fr, i, c, xy, sc)
        added += len(fr)
        X.pop(i, None)
        job.live.extend((tr.point, c, int(f) + job.first, float(q))
                         for f, q in zip(fr, sc, strict=True))
        job.live_xy[(tr.point, c)] = (int(fr[-1]) + job.first, float(xy[-1, 0]),
                                       float(xy[-1, 1]))
        reasons[(tr.point, c)] = job.stop_reason(tr, res)
        nxt[j] = int(fr[-1]) + d
    return added, False
