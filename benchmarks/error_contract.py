"""Costs of the error contract: refusing bad files, linear-time readers, copy-on-open.

Prints JSON lines:

* ``zip_bomb_refuse_s`` / ``zip_bomb_rss_mb``: opening a project whose manifest (or an
  array member) claims 2 GiB deflated into 2 MB, in a fresh process (time to the
  refusal, peak resident set of the process);
* ``c3d_overflow_refuse_s``: the 9 KB C3D whose parameter dimensions overflow int64;
* ``labels_repeat_s``, ``brim_csv_s``, ``brim_svg_s``: time to read a file of n and 2n
  entries (``n`` in the record; ``ratio`` ~2 means linear): repeated label names through
  take import's merge, an 80,000-row brim CSV, an SVG of 48,000 circles with repeated ids
  (refused, naming them) and one of 48,000 nested-group circles (read);
* ``project_open_private_s`` / ``project_open_mapped_s``: opening a 36,000-frame,
  90-point, 4-camera project with 100 detections per image, read into private memory
  (the default up to 4 GiB: survives its file changing) or mapped from its file.

Medians of ``--repeat`` runs; CPU time alongside wall time. Run from the repository root:
``python benchmarks/error_contract.py [--repeat 3] [--skip-open]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from carapost.io.errors import CaraFileError


def emit(metric: str, value: float, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": round(value, 4), "unit": unit, **extra}),
          flush=True)


def timed(fn, repeat: int) -> tuple[float, float]:
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def refused(fn):
    def run(*args: object) -> None:
        try:
            fn(*args)
        except CaraFileError:
            return
        raise AssertionError("not refused")
    return run


def bombs(folder: Path) -> None:
    from tests.fuzz.damaged import damaged_files

    files = damaged_files(folder / "damaged")
    for name in ("cara_manifest_bomb", "cara_array_bomb"):
        path = files[name][1]
        code = ("import resource, sys, time; t0 = time.perf_counter()\n"
                "from carapost.io.cara import load_project\n"
                "from carapost.io.errors import CaraFileError\n"
                "t1 = time.perf_counter()\n"
                f"try:\n    load_project({str(path)!r})\nexcept CaraFileError:\n    pass\n"
                "print(time.perf_counter() - t1, "
                "resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True)
        seconds, rss = map(float, out.stdout.split())
        emit("zip_bomb_refuse_s", seconds, "s", file=name, size_mb=path.stat().st_size / 1e6)
        emit("zip_bomb_rss_mb", rss, "MB", file=name)
    from carapost.io.c3d import read_c3d

    path = files["c3d_dims_overflow"][1]
    wall, cpu = timed(refused(lambda: read_c3d(path)), 5)
    emit("c3d_overflow_refuse_s", wall, "s", cpu_s=round(cpu, 5), size_kb=path.stat().st_size / 1e3)


def linear(folder: Path, repeat: int) -> None:
    from carapost.io.brim_svg import read_brim_svg
    from carapost.io.labels import merge_labels, read_label_file
    from carapost.io.take_import import read_brim_csv

    def labels(n: int) -> Path:
        p = folder / f"labels{n}.txt"
        p.write_text("Nose_Tip\n" * n)
        return p

    def csv(n: int) -> Path:
        p = folder / f"brim{n}.csv"
        p.write_text("label,x,y,z\n" + "".join(f"B{i},{i},1,2\n" for i in range(n)))
        return p

    def svg_dup(n: int) -> Path:
        p = folder / f"dup{n}.svg"
        p.write_text('<svg xmlns="http://www.w3.org/2000/svg">'
                     + "".join(f'<circle id="D{i % 100}" cx="{i}" r="1"/>' for i in range(n))
                     + "</svg>")
        return p

    def svg_nested(n: int) -> Path:
        p = folder / f"nested{n}.svg"
        body = "".join(f'<g transform="translate({i},0)"><g><circle id="D{i}" cy="1" r="1"/>'
                       "</g></g>" for i in range(n))
        p.write_text(f'<svg xmlns="http://www.w3.org/2000/svg">{body}</svg>')
        return p

    cases = [
        ("labels_repeat_s", 27_000, labels, lambda p: merge_labels([], read_label_file(p))),
        ("brim_csv_s", 40_000, csv, read_brim_csv),
        ("brim_svg_s", 24_000, svg_dup, refused(lambda p: read_brim_svg(p))),
        ("brim_svg_s", 24_000, svg_nested, read_brim_svg),
    ]
    for metric, n, make, read in cases:
        times = []
        for size in (n, 2 * n):
            path = make(size)
            wall, cpu = timed(lambda path=path, read=read: read(path), repeat)
            times.append(wall)
            emit(metric, wall, "s", n=size, cpu_s=round(cpu, 4), file=make.__name__,
                 bytes=path.stat().st_size)
        emit(metric[:-2] + "_ratio_2n", times[1] / times[0], "", file=make.__name__)


def project_open(folder: Path, repeat: int) -> None:
    from carapost.io.cara import load_project, save_project
    from carapost.model.project import new_project

    F, C, P, D = 36_000, 4, 90, 100
    rng = np.random.default_rng(0)
    project = new_project(F, C)
    project.points.append(P)
    pts = project.points
    pts.positions[:] = rng.normal(0, 50, size=pts.positions.shape).astype(np.float32)
    pts.obs[:] = rng.uniform(0, 1280, size=pts.obs.shape).astype(np.float32)
    det = project.detections
    n = F * C * D
    det.offsets = np.arange(0, n + 1, D, dtype=np.int64)
    det.arrays = {
        "centre": rng.uniform(0, 1280, size=(n, 2)).astype(np.float32),
        "axes": np.full((n, 2), 4, np.float16),
        "angle": np.zeros(n, np.float16),
        "colour": np.zeros(n, np.int8),
        "score": np.ones(n, np.float16),
    }
    path = save_project(project, folder / "long.cara")
    del project, det
    size_mb = path.stat().st_size / 1e6
    load_project(path)  # page cache warm for both
    for metric, private in (("project_open_private_s", True), ("project_open_mapped_s", False)):
        wall, cpu = timed(lambda private=private: load_project(path, private=private), repeat)
        emit(metric, wall, "s", cpu_s=round(cpu, 3), file_mb=round(size_mb, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-open", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bombs(folder)
        linear(folder, args.repeat)
        if not args.skip_open:
            project_open(folder, args.repeat)


if __name__ == "__main__":
    main()
