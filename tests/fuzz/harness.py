"""A seeded mutation fuzzer for every file reader of carapost.

Seeds are made with carapost's own writers (a small project, label files, brim CSV/SVG,
XCP, take metadata, C3D, a video and an image) plus small third-party files from the
shared fixtures when they are available. Each case mutates one seed with a seeded
generator (bit flips, interesting integers, chunk deletion/insertion/duplication,
truncation, format-aware edits of ZIP headers, ``.npy`` headers, JSON and XML) and is run
in a worker process (`worker.py`) with a time limit and an address-space cap, so a
hang, a crash (a signal) or runaway memory is seen as such instead of taking the test
run down.

Outcome of a case:

``ok``            the reader returned
``documented``    it raised `CaraFileError` (the contract)
``undocumented``  it raised anything else (a bug)
``hang``          it ran over the time limit (the worker is killed and restarted)
``crash``         the worker died (signal, abort, out of memory)

``internal`` counts the documented errors that came from a reader's last-resort net
(an unexpected exception turned into `CaraFileError`): the contract held, but the
message is less precise than it should be.
"""

from __future__ import annotations

import json
import os
import random
import re
import select
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: Reader name -> file name the mutated bytes are written under.
READERS: dict[str, str] = {
    "cara_open": "project.cara",
    "cara_labels": "project.cara",
    "label_file": "take_labels.txt",
    "brim_csv": "brim.csv",
    "brim_svg": "brim.svg",
    "xcp": "take.xcp",
    "take_import": "",  # the file name comes with the seed (one file of a take)
    "take_json": "take.json",
    "c3d": "points.c3d",
    "c3d_import": "points.c3d",  # File > Import C3D: any vendor's points into a project
    "video": "",  # take_cam0.mkv or an image in a sequence folder
}


@dataclass
class Seed:
    reader: str
    name: str  # file name inside the case folder
    data: bytes
    origin: str  # "writer" or the fixture file name


@dataclass
class Outcome:
    reader: str
    case: int
    status: str
    seconds: float = 0.0
    rss_mb: float = 0.0
    exc_type: str = ""
    message: str = ""
    where: str = ""
    internal: bool = False
    mutation: str = ""


# --------------------------------------------------------------------------------------
# Seeds
# --------------------------------------------------------------------------------------
def _small_project():
    import numpy as np

    from carapost.algorithms.camera import CameraIntrinsics
    from carapost.model.project import new_project

    rng = np.random.default_rng(3)
    F, C, P = 6, 4, 3
    project = new_project(F, C)
    det = project.detections
    images, tables = [], []
    for f in range(F):
        for c in range(C):
            images.append((f, c))
            tables.append({
                "centre": rng.uniform(0, 100, size=(3, 2)).astype(np.float32),
                "axes": rng.uniform(3, 6, size=(3, 2)).astype(np.float16),
                "angle": rng.uniform(0, 3, size=3).astype(np.float16),
                "colour": np.zeros(3, np.int8),
                "score": rng.uniform(0.5, 1, size=3).astype(np.float16),
            })
    det.replace_images(images, tables)
    project.points.append(P, labels=["Nose_Tip", "Chin", ""])
    project.points.positions[:] = rng.normal(size=(F, P, 3)).astype(np.float32)
    project.labels = ["Nose_Tip", "Chin", "Brow_L"]
    project.calibration.intrinsics = CameraIntrinsics(
        focal=[900.0] * C, principal_point=[[16, 12]] * C, image_size=[[32, 24]] * C,
        names=[f"cam{c}" for c in range(C)])
    project.calibration.solved[:] = True
    return project


def _writer_seeds(work: Path) -> list[Seed]:
    import cv2
    import numpy as np

    from carapost.io.c3d import write_c3d
    from carapost.io.cara import save_project
    from carapost.io.labels import write_label_file
    from carapost.io.xcp import XcpCalibration, write_xcp

    seeds: list[Seed] = []
    project = _small_project()
    # a stored (the project's own) and a deflated variant of the same project
    cara = save_project(project, work / "seed.cara")
    stored = cara.read_bytes()
    deflated = work / "deflated.cara"
    with zipfile.ZipFile(cara) as src, zipfile.ZipFile(deflated, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            dst.writestr(info.filename, src.read(info.filename))
    for reader in ("cara_open", "cara_labels"):
        seeds.append(Seed(reader, "project.cara", stored, "writer"))
        seeds.append(Seed(reader, "project.cara", deflated.read_bytes(), "writer-deflated"))
    # a stabilised and aligned project (format 2 members), when this version has them
    try:
        from carapost.model.stabilization import Alignment, Stabilization
    except ImportError:
        pass
    else:
        T = np.broadcast_to(np.eye(4), (project.n_frames, 4, 4)).copy()
        T[:, 0, 3] = 5.0
        project.stabilization = Stabilization(T, 0, np.array([1, 2, 3]), "manual")
        project.alignment = Alignment(np.eye(4), (1, 2, 3), 0)
        stab = save_project(project, work / "stabilised.cara").read_bytes()
        seeds.append(Seed("cara_open", "project.cara", stab, "writer-stabilised"))
        project.stabilization = project.alignment = None

    write_label_file(work / "labels.txt", ["Nose_Tip", "Chin", "Brow_L", "Brow_R", "Chin"])
    labels = (work / "labels.txt").read_bytes()
    seeds.append(Seed("label_file", "take_labels.txt", labels, "writer"))

    from carapost.io.brim_svg import default_brim

    names, xyz = default_brim("v1.0")
    csv_text = "label,x,y,z\n" + "".join(
        f"{n},{x:.3f},{y:.3f},{z:.3f}\n" for n, (x, y, z) in zip(names, xyz, strict=True))
    seeds.append(Seed("brim_csv", "brim.csv", csv_text.encode(), "writer"))
    circles = "".join(f'  <circle id="Dot{i:02d}" cx="{10 + 7 * (i % 6)}" cy="{10 + 9 * (i // 6)}" '
                      f'r="2"/>\n' for i in range(12))
    svg = ('<?xml version="1.0"?>\n<svg xmlns="http://www.w3.org/2000/svg" width="80mm" '
           'height="60mm" viewBox="0 0 80 60">\n <g transform="translate(1,2) scale(1)">\n'
           f'{circles} </g>\n <ellipse cx="70" cy="50" rx="2" ry="3"/>\n</svg>\n')
    seeds.append(Seed("brim_svg", "brim.svg", svg.encode(), "writer"))

    cal = project.calibration
    R = np.repeat(np.eye(3)[None], 4, axis=0)
    t = np.array([[0.0, 0, 500]] * 4)
    calib = XcpCalibration.from_arrays(cal.intrinsics, R, t)
    write_xcp(work / "take.xcp", calib)
    xcp = (work / "take.xcp").read_bytes()
    seeds.append(Seed("xcp", "take.xcp", xcp, "writer"))

    meta = {"fps": 60, "timecode_start": "01:02:03:04", "logger": {"name": "L", "id": 3},
            "frames": 4, "cameras": {"cam0": {"frame_offset": 0, "rotation": 90}},
            "blob_parameters": {"black_threshold": 0.4}}
    take_json = json.dumps(meta, indent=1).encode()
    seeds.append(Seed("take_json", "take.json", take_json, "writer"))

    pos = np.random.default_rng(1).normal(size=(8, 3, 3)) * 100
    pos[2, 1] = np.nan
    write_c3d(work / "p.c3d", pos, labels=["A", "B", "C"], rate=60.0,
              residuals=np.full((8, 3), 0.5), timecode_start="01:00:00:00")
    seeds.append(Seed("c3d", "points.c3d", (work / "p.c3d").read_bytes(), "writer"))

    video = work / "take_cam0.mkv"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 60.0, (32, 24),
                             False)
    for k in range(4):
        writer.write(np.full((24, 32), 40 * k, np.uint8))
    writer.release()
    mkv = video.read_bytes()
    ok, png = cv2.imencode(".png", np.arange(24 * 32, dtype=np.uint8).reshape(24, 32))
    assert ok
    seeds.append(Seed("video", "take_cam0.mkv", mkv, "writer"))
    seeds.append(Seed("video", "take_cam0/000.png", png.tobytes(), "writer-png"))
    avi = work / "take_cam1.avi"
    writer = cv2.VideoWriter(str(avi), cv2.VideoWriter_fourcc(*"MJPG"), 60.0, (32, 24), False)
    for k in range(3):
        writer.write(np.full((24, 32), 50 * k, np.uint8))
    writer.release()
    seeds.append(Seed("video", "take_cam0.avi", avi.read_bytes(), "writer-mjpg"))

    # Take import: every file of a take can be the damaged one.
    for name, data in (("take.json", take_json), ("take_labels.txt", labels),
                       ("take_brim.csv", csv_text.encode()), ("take.xcp", xcp),
                       ("take_cam0.mkv", mkv)):
        seeds.append(Seed("take_import", name, data, "writer"))
    return seeds


def take_base_files(work: Path) -> dict[str, bytes]:
    """The undamaged files of the 4-camera take a ``take_import`` case is built from."""
    work.mkdir(parents=True, exist_ok=True)
    base = {s.name: s.data for s in _writer_seeds_cached(work) if s.reader == "take_import"}
    mkv = base["take_cam0.mkv"]
    for c in range(1, 4):
        base[f"take_cam{c}.mkv"] = mkv
    return base


_SEED_CACHE: list[list[Seed]] = []


def _writer_seeds_cached(work: Path) -> list[Seed]:
    """The writer seeds, made once per process (in ``work``, left for the caller)."""
    if not _SEED_CACHE:
        _SEED_CACHE.append(_writer_seeds(work))
    return _SEED_CACHE[0]


def _fixture_seeds(fixtures: Path | None) -> list[Seed]:
    out: list[Seed] = []
    if fixtures is None or not fixtures.is_dir():
        return out
    for p in sorted((fixtures / "c3d").glob("*.c3d")) + sorted((fixtures / "xcp").glob("*.c3d")):
        if p.stat().st_size <= 450_000:
            out.append(Seed("c3d", "points.c3d", p.read_bytes(), p.name))
    for p in sorted((fixtures / "xcp").glob("*.xcp")):
        out.append(Seed("xcp", "take.xcp", p.read_bytes(), p.name))
    return out


def make_seeds(work: Path, fixtures: Path | None = None) -> dict[str, list[Seed]]:
    """Seeds of every reader: carapost's own writers, plus small fixture files."""
    work.mkdir(parents=True, exist_ok=True)
    seeds: dict[str, list[Seed]] = {r: [] for r in READERS}
    for s in _writer_seeds_cached(work) + _fixture_seeds(fixtures):
        seeds[s.reader].append(s)
    # Import C3D reads the same files as the C3D reader, through its own checks
    seeds["c3d_import"] = [Seed("c3d_import", s.name, s.data, s.origin) for s in seeds["c3d"]]
    return seeds


# --------------------------------------------------------------------------------------
# Mutations
# --------------------------------------------------------------------------------------
_INTERESTING = [0, 1, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000,
                0xFFFFFFFF, 2**63 - 1, 2**63, 2**64 - 1]
_TOKENS = [b"[" * 20000, b"{" * 20000, b'{"a":' * 3000, b"1e308", b"-1e308", b"NaN",
           b"-1", b"18446744073709551616", b"\x00", b"\xff\xfe", b"&lt;", b"&ent;",
           b"<!-- comment -->", b"<?pi data?>", b"<!DOCTYPE x [<!ENTITY e 'v'>]>",
           b"<circle r='1'/>" * 2000, b'"', b",", b"\r", b"\n" * 3, b"'", b"]]>",
           b"(" * 5000, b"999999999999999999999999", b"0x7fffffff", b"inf"]


def _chunk(rng: random.Random, data: bytes) -> tuple[int, int]:
    if not data:
        return 0, 0
    a = rng.randrange(len(data))
    n = min(len(data) - a, rng.choice([1, 2, 4, 8, 16, 64, 512, 4096]))
    return a, a + n


def _zip_offsets(data: bytes) -> list[int]:
    return [m.start() for m in re.finditer(rb"PK\x01\x02|PK\x03\x04|PK\x05\x06", data)]


def mutate(data: bytes, rng: random.Random, *, max_size: int = 4 << 20) -> tuple[bytes, str]:
    """One seeded mutation of ``data``; returns the new bytes and what was done."""
    buf = bytearray(data)
    kind = rng.choice(["flip", "int", "delete", "insert", "duplicate", "truncate", "token",
                       "zip", "npy", "lines", "flip", "int", "zip"])
    if kind == "zip" and not _zip_offsets(data):
        kind = "int"
    if kind == "npy" and b"\x93NUMPY" not in data:
        kind = "token"
    if not buf:
        return bytes(rng.randbytes(rng.randrange(1, 64))), "random"
    if kind == "flip":
        for _ in range(rng.randrange(1, 9)):
            i = rng.randrange(len(buf))
            buf[i] ^= 1 << rng.randrange(8)
    elif kind == "int":
        width = rng.choice([1, 2, 4, 8])
        value = rng.choice(_INTERESTING) & ((1 << (8 * width)) - 1)
        i = rng.randrange(max(1, len(buf) - width))
        buf[i:i + width] = value.to_bytes(width, rng.choice(["little", "big"]))
    elif kind == "delete":
        a, b = _chunk(rng, data)
        del buf[a:b]
    elif kind == "insert":
        i = rng.randrange(len(buf) + 1)
        buf[i:i] = rng.randbytes(rng.choice([1, 4, 16, 256]))
    elif kind == "duplicate":
        a, b = _chunk(rng, data)
        times = rng.choice([2, 10, 100, 5000])
        times = max(1, min(times, max_size // max(1, b - a)))
        buf[b:b] = bytes(buf[a:b]) * times
        kind = f"duplicate x{times}"
    elif kind == "truncate":
        buf = buf[: rng.randrange(len(buf))]
    elif kind == "token":
        i = rng.randrange(len(buf) + 1)
        tok = rng.choice(_TOKENS)
        if rng.random() < 0.5:
            end = min(len(buf), i + rng.randrange(1, 12))
            buf[i:end] = tok
        else:
            buf[i:i] = tok
    elif kind == "zip":
        at = rng.choice(_zip_offsets(data))
        sig = bytes(buf[at:at + 4])
        # (offset, width) of method, flags, CRC, sizes, name/extra lengths, disk offset
        fields = ({b"PK\x03\x04": [(6, 2), (8, 2), (14, 4), (18, 4), (22, 4), (26, 2), (28, 2)],
                   b"PK\x01\x02": [(8, 2), (10, 2), (16, 4), (20, 4), (24, 4), (28, 2),
                                   (30, 2), (42, 4)],
                   b"PK\x05\x06": [(8, 2), (10, 2), (12, 4), (16, 4)]})[sig]
        off, width = rng.choice(fields)
        value = rng.choice(_INTERESTING + [8, 9, 12, 14, 93, 99, 1, 0x41])
        buf[at + off:at + off + width] = (value & ((1 << (8 * width)) - 1)).to_bytes(
            width, "little")
        kind = f"zip field +{off}"
    elif kind == "npy":
        starts = [m.start() for m in re.finditer(rb"\x93NUMPY", data)]
        at = rng.choice(starts)
        (hlen,) = struct.unpack("<H", data[at + 8:at + 10])
        header = bytes(buf[at + 10:at + 10 + hlen])
        edits = [(rb"'shape': \([^)]*\)", b"'shape': (99999999999, 99999999999)"),
                 (rb"'shape': \([^)]*\)", b"'shape': (-1,)"),
                 (rb"'descr': '[^']*'", b"'descr': 'O'"),
                 (rb"'descr': '[^']*'", b"'descr': '<U99999'"),
                 (rb"'fortran_order': False", b"'fortran_order': True"),
                 (rb"\}", b""), (rb"'shape'", b"'shap'"), (rb"\{", b"{{{{")]
        pat, rep = rng.choice(edits)
        new = re.sub(pat, rep, header, count=1)
        new = new[:hlen].ljust(hlen)
        buf[at + 10:at + 10 + hlen] = new
        kind = "npy header"
    elif kind == "lines":
        lines = bytes(buf).split(b"\n")
        i = rng.randrange(len(lines))
        times = rng.choice([3, 1000, 20000])
        times = max(1, min(times, max_size // max(1, len(lines[i]) + 1)))
        lines[i + 1:i + 1] = [lines[i]] * times
        buf = bytearray(b"\n".join(lines))
        kind = f"line x{times}"
    return bytes(buf[:max_size * 2]), kind


def cases(seeds: dict[str, list[Seed]], reader: str, n: int, seed: int = 0
          ) -> Iterator[tuple[int, Seed, bytes, str]]:
    """``n`` mutated inputs of ``reader`` (deterministic for a given ``seed``)."""
    rng = random.Random(f"{reader}:{seed}")
    pool = seeds[reader]
    for k in range(n):
        s = pool[k % len(pool)]
        data, what = s.data, []
        for _ in range(rng.choice([1, 1, 1, 2, 3])):
            data, kind = mutate(data, rng)
            what.append(kind)
        yield k, s, data, "+".join(what)


# --------------------------------------------------------------------------------------
# Running: a worker process per reader, restarted after a hang or a crash
# --------------------------------------------------------------------------------------
@dataclass
class Worker:
    timeout: float = 10.0
    mem_limit_mb: int = 4096
    proc: subprocess.Popen[str] | None = None
    env: dict[str, str] = field(default_factory=dict)

    def start(self) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO)]
                                            + env.get("PYTHONPATH", "").split(os.pathsep))
        env["CARAPOST_FUZZ_MEM_MB"] = str(self.mem_limit_mb)
        env.setdefault("OPENCV_LOG_LEVEL", "SILENT")
        env.update(self.env)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tests.fuzz.worker"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env,
            cwd=str(REPO))
        assert self.proc.stdout is not None
        line = self._readline(120.0)
        if line is None or json.loads(line).get("ready") is not True:
            raise RuntimeError("the fuzz worker did not start")

    def _readline(self, timeout: float) -> str | None:
        assert self.proc is not None and self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            return None
        line = self.proc.stdout.readline()
        return line or None

    def stop(self) -> None:
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.kill()
            self.proc.wait()
            for stream in (self.proc.stdin, self.proc.stdout):
                if stream is not None:
                    stream.close()
            self.proc = None

    def run(self, reader: str, path: Path) -> dict[str, object]:
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        assert self.proc is not None and self.proc.stdin is not None
        t0 = time.perf_counter()
        try:
            self.proc.stdin.write(json.dumps({"reader": reader, "path": str(path)}) + "\n")
            self.proc.stdin.flush()
        except BrokenPipeError:
            pass
        line = self._readline(self.timeout)
        seconds = time.perf_counter() - t0
        if line is None:
            hung = self.proc.poll() is None
            code = self.proc.returncode
            self.stop()
            if hung:
                return {"status": "hang", "seconds": seconds}
            return {"status": "crash", "seconds": seconds, "exc_type": f"exit {code}"}
        return json.loads(line)


def write_case(folder: Path, reader: str, seed: Seed, data: bytes) -> Path:
    """Lay out one case in an empty ``folder``; returns the path handed to the reader."""
    if reader == "take_import":
        for name, raw in take_base_files(folder.parent / "_seeds").items():
            (folder / name).write_bytes(raw)
        (folder / seed.name).write_bytes(data)
        return folder
    target = folder / seed.name
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(data)
    return target.parent if seed.name.endswith(".png") else target


def run_fuzz(readers: list[str], n: int, *, timeout: float = 10.0, seed: int = 0,
             fixtures: Path | None = None, mem_limit_mb: int = 4096,
             on_outcome: Callable[[Outcome], None] | None = None,
             keep: Path | None = None, worker: Worker | None = None) -> list[Outcome]:
    """Run ``n`` cases of every reader in ``readers``; returns every outcome.

    ``keep``: a folder where the input of every non-contract outcome is copied.
    ``worker``: reuse this worker (else one is started per reader and stopped after).
    """
    root = Path(tempfile.mkdtemp(prefix="carapost-fuzz-"))
    outcomes: list[Outcome] = []
    given = worker
    try:
        seeds = make_seeds(root / "_seeds", fixtures)
        for reader in readers:
            worker = given or Worker(timeout=timeout, mem_limit_mb=mem_limit_mb)
            try:
                for k, s, data, what in cases(seeds, reader, n, seed):
                    folder = root / f"{reader}-{k}"
                    folder.mkdir()
                    path = write_case(folder, reader, s, data)
                    res = worker.run(reader, path)
                    fields = {key: res[key] for key in res if key in Outcome.__annotations__}
                    out = Outcome(reader=reader, case=k, mutation=f"{s.origin}: {what}",
                                  **fields)
                    outcomes.append(out)
                    if keep is not None and out.status in ("undocumented", "hang", "crash"):
                        dest = keep / f"{reader}-{k}-{out.status}"
                        shutil.copytree(folder, dest, dirs_exist_ok=True)
                    if on_outcome is not None:
                        on_outcome(out)
                    shutil.rmtree(folder, ignore_errors=True)
            finally:
                if given is None:
                    worker.stop()
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return outcomes
