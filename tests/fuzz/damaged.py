"""Minimal damaged files: one of each class of bad input the fuzz runs found.

Made the same way as the fuzz inputs (from carapost's own writers, then damaged by one
targeted edit), so that tests of the contract and of the window's dialogs can go over
each class by name. ``damaged_files(folder)`` returns ``{name: (reader, path)}``.
"""

from __future__ import annotations

import io
import json
import re
import struct
import zipfile
import zlib
from pathlib import Path

from .harness import _small_project


def _patch_central(data: bytes, member: str, offset: int, fmt: str, value: int) -> bytes:
    """Set a field of ``member``'s central-directory and local headers."""
    buf = bytearray(data)
    name = member.encode()
    local_off = {6: 4, 8: 6, 10: 8, 20: 18, 24: 22}[offset]  # central -> local offsets
    for m in re.finditer(rb"PK\x01\x02", data):
        n = struct.unpack_from("<H", data, m.start() + 28)[0]
        if data[m.start() + 46:m.start() + 46 + n] == name:
            struct.pack_into(fmt, buf, m.start() + offset, value)
            (lh,) = struct.unpack_from("<I", data, m.start() + 42)
            struct.pack_into(fmt, buf, lh + local_off, value)
    return bytes(buf)


def _zip_with(members: dict[str, bytes], *, deflate: bool = False) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) as zf:
        for name, raw in members.items():
            zf.writestr(name, raw)
    return out.getvalue()


def raw_zip(entries: list[tuple[str, int, bytes, int, int]]) -> bytes:
    """A ZIP of ``(name, method, payload, declared size, crc)`` entries, written by hand
    (so the payload can be a deflate stream made elsewhere and sizes can lie)."""
    body, central = b"", b""
    for name, method, payload, size, crc in entries:
        fname = name.encode()
        offset = len(body)
        body += struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 20, 0, method, 0, 0x21, crc,
                            len(payload), size, len(fname), 0) + fname + payload
        central += struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 20, 20, 0, method, 0,
                               0x21, crc, len(payload), size, len(fname), 0, 0, 0, 0, 0,
                               offset) + fname
    end = struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, len(entries), len(entries),
                      len(central), len(body), 0)
    return body + central + end


def deflate_bomb(inflated: int) -> bytes:
    """A deflate stream of ``inflated`` bytes of spaces (a few MB for gigabytes).

    One full-flush block repeated is valid deflate, so it takes milliseconds to make.
    """
    chunk = 1 << 20
    comp = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = comp.compress(b" " * chunk) + comp.flush(zlib.Z_FULL_FLUSH)
    return block * (inflated // chunk) + comp.flush()


def bomb_member(name: str, inflated: int, *, honest: bool = True) -> bytes:
    """A ZIP holding ``name``: ``inflated`` bytes deflated to a few MB; ``honest=False``
    declares a small size in the headers instead."""
    return raw_zip([(name, 8, deflate_bomb(inflated), inflated if honest else 1000, 0)])


def stored(name: str, data: bytes) -> tuple[str, int, bytes, int, int]:
    """A stored `raw_zip` entry."""
    return (name, 0, data, len(data), zlib.crc32(data))


def c3d_overflow(folder: Path) -> bytes:
    """A C3D whose parameter has nine dimensions of 255 (np.prod wraps in int64)."""
    import numpy as np

    from carapost.io.c3d import write_c3d

    p = folder / "_ok.c3d"
    write_c3d(p, np.zeros((4, 2, 3)), labels=["A", "B"], rate=60.0)
    data = bytearray(p.read_bytes())
    p.unlink()
    pstart = (data[0] - 1) * 512
    body = struct.pack("<bB", 1, 9) + bytes([255] * 9) + b"\x00"
    rec = struct.pack("<bb", 4, 1) + b"BOMB" + struct.pack("<h", len(body) + 2) + body
    pend = pstart + data[pstart + 2] * 512
    if any(data[pend - len(rec):pend]):  # no slack at the end: extend by one block
        raise RuntimeError("the seed C3D has no room in its parameter section")
    data[pend - len(rec):pend] = b""
    data[pstart + 4:pstart + 4] = rec
    return bytes(data)


def damaged_files(folder: Path) -> dict[str, tuple[str, Path]]:
    """Write one file per class of damage into ``folder``; ``{name: (reader, path)}``."""
    import numpy as np

    from carapost.io.cara import save_project
    from carapost.io.xcp import XcpCalibration, write_xcp

    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, tuple[str, Path]] = {}

    def put(name: str, reader: str, data: bytes, suffix: str) -> None:
        path = folder / f"{name}{suffix}"
        path.write_bytes(data)
        out[name] = (reader, path)

    project = _small_project()
    seed = save_project(project, folder / "_seed.cara").read_bytes()
    (folder / "_seed.cara").unlink()
    with zipfile.ZipFile(io.BytesIO(seed)) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
        manifest = json.loads(members["manifest.json"])
    i = seed.index(b"manifest.json") + len("manifest.json")

    bad_crc = bytearray(seed)
    bad_crc[i + 5] ^= 0xFF  # a byte of the stored manifest
    put("cara_bad_crc", "cara_open", bytes(bad_crc), ".cara")
    bad_magic = bytearray(seed)
    bad_magic[0:4] = b"PK\x07\x08"
    put("cara_bad_local_header", "cara_open", bytes(bad_magic), ".cara")
    put("cara_manifest_method_99", "cara_open",
        _patch_central(seed, "manifest.json", 10, "<H", 99), ".cara")
    put("cara_array_method_14", "cara_open",
        _patch_central(seed, "points/positions.npy", 10, "<H", 14), ".cara")
    put("cara_array_encrypted", "cara_open",
        _patch_central(seed, "points/positions.npy", 8, "<H", 1), ".cara")
    put("cara_truncated", "cara_open", seed[: len(seed) // 2], ".cara")
    npy = bytearray(members["points/positions.npy"])
    npy[npy.index(b"}")] = ord(" ")
    put("cara_npy_unclosed_brace", "cara_open",
        _zip_with({**members, "points/positions.npy": bytes(npy)}), ".cara")
    huge_id = dict(manifest, points=dict(manifest["points"], ids=[1e308, 2, 3]))
    put("cara_point_id_1e308", "cara_open",
        _zip_with({**members, "manifest.json": json.dumps(huge_id).encode()}), ".cara")
    put("cara_nested_manifest", "cara_open",
        _zip_with({"manifest.json": b"[" * 100_000}), ".cara")
    put("cara_manifest_bomb", "cara_open", bomb_member("manifest.json", 2 << 30), ".cara")
    put("cara_manifest_bomb_lying", "cara_open",
        bomb_member("manifest.json", 256 << 20, honest=False), ".cara")
    big = dict(manifest)
    big["arrays"] = dict(manifest["arrays"])
    big["arrays"]["points/positions.npy"] = {"dtype": "float32", "shape": [1 << 29, 1]}
    entries = [stored("manifest.json", json.dumps(big).encode())]
    entries += [stored(n, raw) for n, raw in members.items()
                if n not in ("manifest.json", "points/positions.npy")]
    entries.append(("points/positions.npy", 8, deflate_bomb(2 << 30), (2 << 30) + 128, 0))
    put("cara_array_bomb", "cara_open", raw_zip(entries), ".cara")
    put("cara_not_zip", "cara_open", b"this is not a project\n" * 10, ".cara")
    put("cara_empty", "cara_open", b"", ".cara")
    put("labels_cara_bad_crc", "cara_labels", bytes(bad_crc), ".cara")

    put("brim_csv_huge_field", "brim_csv", b"label,x,y,z\n" + b'"' + b"a" * 200_000 +
        b'",1,2,3\n', ".csv")
    put("brim_csv_binary", "brim_csv", b"B1,1,2,3\n\x00\x01\x02", ".csv")
    put("brim_svg_no_dots", "brim_svg", b"<svg xmlns='http://www.w3.org/2000/svg'/>", ".svg")
    put("brim_svg_not_xml", "brim_svg", b"<svg><circle", ".svg")

    cal = project.calibration
    calib = XcpCalibration.from_arrays(cal.intrinsics, np.repeat(np.eye(3)[None], 4, 0),
                                       np.array([[0.0, 0, 500]] * 4))
    write_xcp(folder / "_ok.xcp", calib)
    xcp = (folder / "_ok.xcp").read_text()
    (folder / "_ok.xcp").unlink()
    put("xcp_frame_2e63", "xcp", re.sub(r'FRAME="0"', 'FRAME="9223372036854775808"', xcp,
                                        count=1).encode(), ".xcp")
    put("xcp_not_xml", "xcp", xcp[: len(xcp) // 2].encode(), ".xcp")

    put("take_json_nested", "take_json", b'{"a":' * 5000 + b"1" + b"}" * 5000, ".json")
    put("take_json_not_object", "take_json", b"[1, 2]", ".json")
    put("c3d_dims_overflow", "c3d", c3d_overflow(folder), ".c3d")
    put("c3d_truncated", "c3d", c3d_overflow(folder)[:700], ".c3d")
    put("video_garbage", "video", b"\x1aE\xdf\xa3" + bytes(range(256)) * 40, ".mkv")
    return out
