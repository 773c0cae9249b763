"""Write ``tests/data/cara_v1.cara``, the version-1 project fixture (run once, at 0.1.0).

The expected values live in ``tests/io/test_cara_v1.py``; this script only puts them into
a :class:`~carapost.model.project.Project` and saves it with the version-1 writer. The
committed file must never be regenerated: it stands for the projects users saved with
format version 1 (see the test module's docstring). Run from the repository root::

    PYTHONPATH=src:. python scripts/make_cara_v1_fixture.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from tests.io import test_cara_v1 as v1

from carapost.algorithms.camera import CameraIntrinsics
from carapost.io.cara import FORMAT_VERSION, save_project
from carapost.model.project import CameraChannel, Project, RomReference, Selection, Stick, Take


def build_project() -> Project:
    """The fixture project, from the values of ``tests/io/test_cara_v1.py``."""
    take = Take(
        name=v1.TAKE_NAME,
        cameras=[
            CameraChannel(name=n, video_path=p, image_size=s, rotation=r, frame_offset=o)
            for n, p, s, r, o in zip(v1.CAMERA_NAMES, v1.VIDEO_PATHS, v1.IMAGE_SIZES,
                                     v1.ROTATIONS, v1.FRAME_OFFSETS, strict=True)
        ],
        n_frames=v1.F,
        fps=v1.FPS,
        timecode_start=v1.TIMECODE,
        metadata=dict(v1.METADATA),
    )
    project = Project(take)
    pts = project.points
    pts.ids = np.array(v1.POINT_IDS, dtype=np.int64)
    pts.labels = list(v1.POINT_LABELS)
    pts.kind = np.array(v1.POINT_KINDS, dtype=np.int8)
    pts.next_id = v1.NEXT_ID
    pts.arrays = v1.expected_point_arrays()
    offsets, fields = v1.expected_detections()
    project.detections.offsets = offsets
    project.detections.arrays = fields
    cal = project.calibration
    cal.R, cal.t, cal.solved = v1.expected_calibration()
    cal.intrinsics = CameraIntrinsics(**v1.INTRINSICS)
    project.labels = list(v1.LABELS)
    project.sticks = [Stick(a, b, colour) for a, b, colour in v1.STICKS]
    project.properties.update(v1.PROPERTIES)
    project.current_frame = v1.CURRENT_FRAME
    project.active_range = v1.ACTIVE_RANGE
    project.view_range = v1.VIEW_RANGE
    project.selection = Selection(points=frozenset(v1.SELECTED_POINTS),
                                  cameras=frozenset(v1.SELECTED_CAMERAS))
    project.rom = RomReference(path=v1.ROM_PATH)
    project.imported_blob_parameters = dict(v1.IMPORTED_BLOB_PARAMETERS)
    return project


def main() -> int:
    """Write the fixture; refuses to overwrite it or to write another format version."""
    if FORMAT_VERSION != 1:
        print(f"the writer is at format version {FORMAT_VERSION}: the v1 fixture must "
              "stay the file written at version 1", file=sys.stderr)
        return 1
    if v1.FIXTURE.exists() and "--force" not in sys.argv[1:]:
        print(f"{v1.FIXTURE} exists; it must never be regenerated (--force to overwrite)",
              file=sys.stderr)
        return 1
    Path(v1.FIXTURE).parent.mkdir(parents=True, exist_ok=True)
    out = save_project(build_project(), v1.FIXTURE)
    print(f"wrote {out} ({out.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
