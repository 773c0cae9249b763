"""Binary FBX 7.4 export of point trajectories (and optionally cameras): our own writer.

No library on PyPI writes FBX, so this module writes the binary node tree itself (layout of
the FBX SDK / Blender exporter, see docs/file-formats.md). What a reader sees:

* one animated Null per point, named by its label, under ``<take>/face`` or ``<take>/brim``;
* linear ``Lcl Translation`` keys at every valid frame. Across a gap one extra key on the last
  gap frame repeats the value before the gap, so every reader (including Blender, which
  ignores interpolation flags) holds the marker still instead of sliding it along an invented
  path; an animated ``Visibility`` (stepped, 0 in gaps, switching half a frame before the
  change) says where the point is missing.
* frame rate: the FBX ``TimeMode`` enum for standard rates, else mode 14 + ``CustomFrameRate``;
  key times are exact per frame, ``round(frame * 46186158000 / rate)`` ticks;
* units: millimetres (``UnitScaleFactor`` 0.1, FBX counts in centimetres);
* axes: ``"y"`` converts our Z-up brim frame to Y-up, ``(x, y, z) -> (x, z, -y)``; ``"z"``
  keeps Z-up and declares it in ``GlobalSettings``;
* optional sticks: one two-vertex line mesh per stick under ``<take>/sticks``, moved by
  animated translation / rotation / uniform scale so its ends sit on the two points (plain
  TRS animation reads the same in ufbx, assimp and Blender; a skin would turn the marker
  nulls into armature bones in Blender).
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, BinaryIO

import numpy as np

from carapost import __version__
from carapost.io.atomic import atomic_output

__all__ = ["write_fbx", "KTIME_PER_SECOND", "fbx_time_mode"]

KTIME_PER_SECOND = 46186158000
_VERSION = 7400
_NULL = b"\0" * 13
_HEAD = b"Kaydara FBX Binary  \x00\x1a\x00"
# Blender's consistent (CreationTime, FileId, footer code) triple; the SDK derives the last two
# from the first, and Autodesk tools accept Blender files.
_CREATION_TIME = "1970-01-01 10:00:00:000"
_FILE_ID = b"\x28\xb3\x2a\xeb\xb6\x24\xcc\xc2\xbf\xc8\xb0\x2a\xa9\x2b\xfc\xf1"
_FOOT_ID = b"\xfa\xbc\xab\x09\xd0\xc8\xd4\x66\xb1\x76\xfb\x83\x1c\xf7\x26\x7e"
_FOOT_MAGIC = b"\xf8\x5a\x8c\x6a\xde\xf5\xd9\x7e\xec\xe9\x0c\xe3\x75\x8f\x29\x0b"
_LINEAR, _CONSTANT = 0x4, 0x2
# Blender's KeyAttrDataFloat entry (slopes 0, default weights 1/3 packed, no velocity).
_KEY_DATA = np.array([0, 0, 218434821, 0], dtype="<i4").view("<f4")
# FBX TimeMode enum values of the standard rates (FBX SDK / ufbx / Blender tables).
_TIME_MODES = {
    120.0: 1, 100.0: 2, 60.0: 3, 50.0: 4, 48.0: 5, 30.0: 6, 30000 / 1001: 9,
    25.0: 10, 24.0: 11, 1000.0: 12, 24000 / 1001: 13, 96.0: 15, 72.0: 16, 60000 / 1001: 17,
}  # fmt: skip
_CUSTOM_TIME_MODE = 14
_FILM_WIDTH_MM = 36.0  # nominal camera back; focal length in mm is scaled to keep the FOV


def fbx_time_mode(rate: float) -> int:
    """FBX ``TimeMode`` for a frame rate: the standard enum value, or 14 (custom)."""
    for fps, mode in _TIME_MODES.items():
        if abs(rate - fps) <= 1e-9 * fps:
            return mode
    return _CUSTOM_TIME_MODE


# --------------------------------------------------------------------------------------
# Binary encoding
# --------------------------------------------------------------------------------------


def _i(v: int) -> bytes:
    return b"I" + struct.pack("<i", int(v))


def _l(v: int) -> bytes:
    return b"L" + struct.pack("<q", int(v))


def _d(v: float) -> bytes:
    return b"D" + struct.pack("<d", float(v))


def _s(v: str | bytes) -> bytes:
    raw = v.encode("utf-8") if isinstance(v, str) else v
    return b"S" + struct.pack("<I", len(raw)) + raw


def _c(v: int) -> bytes:
    return b"C" + bytes([v])


class _Deferred:
    """An array property whose zlib compression runs on a worker thread (zlib drops the GIL)."""

    __slots__ = ("_head", "_future", "_bytes")

    def __init__(self, head: bytes, future: Future[bytes]) -> None:
        self._head = head
        self._future = future
        self._bytes: bytes | None = None

    def resolve(self) -> bytes:
        if self._bytes is None:
            payload = self._future.result()
            self._bytes = self._head + struct.pack("<II", 1, len(payload)) + payload
        return self._bytes


def _arr(
    code: str, values: np.ndarray, pool: ThreadPoolExecutor | None = None, compress: bool = True
) -> bytes | _Deferred:
    """Array property; arrays over 128 bytes are zlib-compressed (level 1, like Blender)
    unless ``compress`` is False."""
    dtype = {"f": "<f4", "d": "<f8", "l": "<i8", "i": "<i4"}[code]
    raw = np.ascontiguousarray(values, dtype=dtype).tobytes()
    head = code.encode() + struct.pack("<I", len(raw) // np.dtype(dtype).itemsize)
    if len(raw) <= 128 or not compress:
        return head + struct.pack("<II", 0, len(raw)) + raw
    if pool is None:
        payload = zlib.compress(raw, 1)
        return head + struct.pack("<II", 1, len(payload)) + payload
    return _Deferred(head, pool.submit(zlib.compress, raw, 1))


class _Node:
    """One FBX node: name, encoded properties, children; ``block`` forces a null record."""

    __slots__ = ("name", "props", "children", "block")

    def __init__(self, name: str, *props: bytes | _Deferred, block: bool = False) -> None:
        self.name = name.encode("ascii")
        self.props: list[bytes | _Deferred] = list(props)
        self.children: list[_Node] = []
        self.block = block

    def add(self, name: str, *props: bytes | _Deferred, block: bool = False) -> _Node:
        node = _Node(name, *props, block=block)
        self.children.append(node)
        return node


def _emit(node: _Node, pos: int, out: list[bytes]) -> int:
    """Append the encoding of ``node`` starting at absolute offset ``pos``; return its end."""
    props = [p if isinstance(p, bytes) else p.resolve() for p in node.props]
    plen = sum(len(p) for p in props)
    slot = len(out)
    out.append(b"")
    out.extend(props)
    end = pos + 13 + len(node.name) + plen
    if node.children or node.block or not node.props:
        for child in node.children:
            end = _emit(child, end, out)
        out.append(_NULL)
        end += len(_NULL)
    out[slot] = struct.pack("<IIIB", end, len(node.props), plen, len(node.name)) + node.name
    return end


def _props70(parent: _Node) -> _Node:
    return parent.add("Properties70", block=True)


def _p(props: _Node, name: str, t1: str, t2: str, flags: str, *values: bytes) -> None:
    props.add("P", _s(name), _s(t1), _s(t2), _s(flags), *values)


def _obj_name(name: str, cls: str) -> bytes:
    return _s(name.encode("utf-8") + b"\x00\x01" + cls.encode("ascii"))


# --------------------------------------------------------------------------------------
# Scene building
# --------------------------------------------------------------------------------------


class _Scene:
    def __init__(self) -> None:
        self.objects = _Node("Objects")
        self.connections = _Node("Connections")
        self.counts: dict[str, int] = {}
        self._next = 1_000_000

    def new_id(self) -> int:
        self._next += 1
        return self._next

    def obj(self, kind: str, name: str, cls: str, sub: str, count_as: str | None = None) -> tuple:
        oid = self.new_id()
        node = self.objects.add(kind, _l(oid), _obj_name(name, cls), _s(sub))
        key = count_as or kind
        self.counts[key] = self.counts.get(key, 0) + 1
        return oid, node

    def oo(self, child: int, parent: int) -> None:
        self.connections.add("C", _s("OO"), _l(child), _l(parent))

    def op(self, child: int, parent: int, prop: str) -> None:
        self.connections.add("C", _s("OP"), _l(child), _l(parent), _s(prop))

    def model(self, name: str, sub: str, attr_id: int, parent: int,
              translation: Sequence[float], rotation: Sequence[float] | None = None) -> tuple:
        """A ``Model`` node of type ``sub`` (with its NodeAttribute ``attr_id``) under
        ``parent``, at ``translation`` (and XYZ Euler ``rotation``, deg): (id, Properties70)."""
        mid, model = self.obj("Model", name, "Model", sub)
        model.add("Version", _i(232))
        props = _props70(model)
        _p(props, "Lcl Translation", "Lcl Translation", "", "A", *map(_d, translation))
        if rotation is not None:
            _p(props, "Lcl Rotation", "Lcl Rotation", "", "A", *map(_d, rotation))
        _p(props, "DefaultAttributeIndex", "int", "Integer", "", _i(0))
        _p(props, "InheritType", "enum", "", "", _i(1))
        model.add("Shading", _c(1))
        model.add("Culling", _s("CullingOff"))
        self.oo(attr_id, mid)
        self.oo(mid, parent)
        return mid, props

    def null(self, name: str, parent: int, translation: Sequence[float] = (0, 0, 0)) -> tuple:
        aid, attr = self.obj("NodeAttribute", name, "NodeAttribute", "Null")
        attr.add("TypeFlags", _s("Null"))
        return self.model(name, "Null", aid, parent, translation)


class _Curves:
    """Builds animation curves; caches compressed KeyTime arrays shared by many curves."""

    def __init__(self, scene: _Scene, layer_id: int, rate: float, pool: ThreadPoolExecutor) -> None:
        self.scene = scene
        self.pool = pool
        self.layer = layer_id
        self.ticks_per_frame = KTIME_PER_SECOND / rate
        self._time_cache: dict[bytes, bytes | _Deferred] = {}

    def _key_time(self, frames: np.ndarray, cache_key: bytes | None) -> bytes | _Deferred:
        enc = self._time_cache.get(cache_key) if cache_key is not None else None
        if enc is None:
            # Exact per key (never an accumulated rounded step): rates like 72 or 59.94 fps
            # have no whole number of ticks per frame.
            times = np.rint(np.asarray(frames, np.float64) * self.ticks_per_frame)
            enc = _arr("l", times.astype(np.int64), self.pool)
            if cache_key is not None:
                self._time_cache[cache_key] = enc
        return enc

    def curve_node(
        self,
        model_id: int,
        prop: str,
        channels: Sequence[str],
        frames: np.ndarray,
        values: np.ndarray,
        flag: int = _LINEAR,
        cache_key: bytes | None = None,
    ) -> None:
        """Animate ``prop`` of ``model_id``: ``values`` [K, n_channels] at (fractional) frames."""
        sc = self.scene
        short = {"Lcl Translation": "T", "Lcl Rotation": "R", "Lcl Scaling": "S"}.get(prop, prop)
        nid, cnode = sc.obj("AnimationCurveNode", short, "AnimCurveNode", "")
        props = _props70(cnode)
        for k, ch in enumerate(channels):
            _p(props, f"d|{ch}", "Number", "", "A", _d(values[0, k]))
        sc.oo(nid, self.layer)
        sc.op(nid, model_id, prop)
        # One key-attribute entry shared by all keys (run length = key count).
        attr_flags = _arr("i", np.array([flag]))
        attr_data = _arr("f", _KEY_DATA)
        attr_ref = _arr("i", np.array([len(frames)]))
        key_time = self._key_time(frames, cache_key)
        for k, ch in enumerate(channels):
            cid, curve = sc.obj("AnimationCurve", "", "AnimCurve", "")
            curve.add("Default", _d(values[0, k]))
            curve.add("KeyVer", _i(4008))
            curve.add("KeyTime", key_time)
            # Measured float32 samples barely compress (~0.85 of raw with zlib) while costing
            # two thirds of the export time, so sample values are stored raw; key times
            # (regular int64 steps) compress well and are.
            curve.add("KeyValueFloat", _arr("f", values[:, k], compress=False))
            curve.add("KeyAttrFlags", attr_flags)
            curve.add("KeyAttrDataFloat", attr_data)
            curve.add("KeyAttrRefCount", attr_ref)
            sc.op(cid, nid, f"d|{ch}")


def _hold_keys(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Key frames for one track and the frame whose value each key takes.

    Keys sit on every valid frame; across a gap an extra key on the last gap frame repeats the
    value before the gap, so linear interpolation holds the point still through the gap and
    jumps in the last frame interval (robust to the tick rounding of any reader).
    """
    frames = np.flatnonzero(valid)
    after = np.flatnonzero(np.diff(frames) > 1)
    keys = np.concatenate([frames, frames[after + 1] - 1])
    src = np.concatenate([frames, frames[after]])
    order = np.argsort(keys, kind="stable")
    return keys[order], src[order]


def _visibility_keys(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stepped visibility keys: frame 0, then half a frame before each change (unambiguous
    whatever the reader's rounding), with the 0/1 value from there on."""
    change = np.flatnonzero(np.diff(valid.astype(np.int8))) + 1
    frames = np.concatenate([[0.0], change - 0.5])
    values = np.concatenate([valid[:1], valid[change]]).astype(np.float64)
    return frames, values


def _euler_xyz_deg(m: np.ndarray) -> np.ndarray:
    """[..., 3, 3] rotation -> FBX XYZ Euler angles (deg), M = Rz(c) Ry(b) Rx(a)."""
    b = np.arcsin(np.clip(-m[..., 2, 0], -1.0, 1.0))
    a = np.arctan2(m[..., 2, 1], m[..., 2, 2])
    c = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    return np.degrees(np.stack([a, b, c], axis=-1))


# Axis conversion of our Z-up brim frame to the file's frame.
_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
# Columns: the FBX camera axes (+X view, +Y up, +Z right) in OpenCV camera coordinates.
_FBX_CAM_IN_CV = np.array([[0.0, 0, 1], [0, -1.0, 0], [1.0, 0, 0]])


def write_fbx(
    path: str | os.PathLike[str],
    positions: np.ndarray,
    *,
    labels: Sequence[str],
    rate: float,
    kinds: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    take_name: str = "take",
    up_axis: str = "y",
    cameras: Mapping[str, Any] | None = None,
    sticks: Sequence[tuple[int, int]] | None = None,
    groups: Sequence[str] | None = None,
) -> None:
    """Write point trajectories (and optional cameras) as a binary FBX 7.4 file.

    Parameters
    ----------
    path : str or PathLike
        Output file; written atomically (temporary file, fsync, rename).
    positions : array_like, shape (F, P, 3)
        Point positions in mm in the Z-up brim frame; NaN = missing.
    labels : sequence of str, length P
        Unique, non-empty node names.
    rate : float
        Frame rate in Hz (> 0); frame f is at time f / rate seconds.
    kinds : array_like of int, shape (P,), optional
        0 = face point, 1 = brim point (default: all face).
    valid : array_like of bool, shape (F, P), optional
        Samples to key (default: where positions are finite). Non-finite samples are never keyed.
    take_name : str
        Name of the top node and of the animation stack.
    up_axis : {"y", "z"}
        ``"y"``: convert to Y-up (Maya, MotionBuilder); ``"z"``: keep Z-up.
    cameras : mapping, optional
        ``R`` [F, C, 3, 3] and ``t`` [F, C, 3] (world -> camera, ``x_cam = R X + t``, mm,
        NaN = unknown frame), ``focal_px`` [C], ``image_size`` [C, 2] (width, height px) and
        optional ``names`` [C]: written as animated FBX cameras under the take node.
    sticks : sequence of (int, int), optional
        Point index pairs: each becomes a two-vertex line mesh ``<label_i>-<label_j>`` under
        ``<take>/sticks`` whose animated translation, rotation and uniform scale put its
        vertices on the two points at every frame where both are valid (held, and Visibility
        0, elsewhere).
    groups : sequence of str, length P, optional
        The node each point goes under, as a path of null nodes below the take node
        (``"face/mouth"``: a ``mouth`` null under ``face``); default ``"face"`` for face
        points and ``"brim"`` for brim points.

    Raises
    ------
    ValueError
        For arrays of the wrong shape, bad labels or options.
    CaraFileError
        If the file cannot be written.
    """
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 3 or pos.shape[2] != 3:
        raise ValueError(f"positions must be an [F, P, 3] array, got shape {pos.shape}")
    n_frames, n_points, _ = pos.shape
    if n_frames < 1 or n_points < 1:
        raise ValueError("positions must hold at least one frame and one point")
    labels = [str(s) for s in labels]
    if len(labels) != n_points:
        raise ValueError(f"labels has {len(labels)} entries for {n_points} points")
    if any(not s.strip() for s in labels) or len(set(labels)) != len(labels):
        raise ValueError("labels must be unique and non-empty")
    rate = float(rate)
    if not np.isfinite(rate) or rate <= 0:
        raise ValueError(f"rate must be a positive frame rate in Hz, got {rate}")
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    kinds_arr = np.zeros(n_points, int) if kinds is None else np.asarray(kinds)
    if kinds_arr.shape != (n_points,) or not np.isin(kinds_arr, (0, 1)).all():
        raise ValueError(f"kinds must be a [{n_points}] array of 0 (face) / 1 (brim)")
    ok = np.isfinite(pos).all(axis=2)
    if valid is not None:
        v = np.asarray(valid)
        if v.shape != (n_frames, n_points) or v.dtype != bool:
            raise ValueError(f"valid must be a bool array of shape ({n_frames}, {n_points})")
        ok &= v
    pairs = _check_sticks(sticks, n_points)
    cams = _check_cameras(cameras, n_frames) if cameras is not None else None
    if not take_name.strip():
        raise ValueError("take_name must not be empty")
    if groups is not None:
        groups = [str(g).strip("/") for g in groups]
        if len(groups) != n_points or any(
                not part.strip() for g in groups for part in g.split("/")):
            raise ValueError(f"groups must be {n_points} node paths like 'face' or "
                             "'face/mouth' (no empty names)")

    axis = _TO_Y_UP if up_axis == "y" else np.eye(3)
    pts = pos @ axis.T if up_axis == "y" else pos
    stop = round((n_frames - 1) * KTIME_PER_SECOND / rate)

    sc = _Scene()
    stack_id, stack = sc.obj("AnimationStack", take_name, "AnimStack", "")
    sp = _props70(stack)
    for key in ("LocalStart", "ReferenceStart"):
        _p(sp, key, "KTime", "Time", "", _l(0))
    for key in ("LocalStop", "ReferenceStop"):
        _p(sp, key, "KTime", "Time", "", _l(stop))
    layer_id, _layer = sc.obj("AnimationLayer", "BaseLayer", "AnimLayer", "")
    _layer.block = True  # assimp needs the empty block
    sc.oo(layer_id, stack_id)
    take_id, _ = sc.null(take_name, 0)
    nulls: dict[str, int] = {"": take_id}

    def node(path: str) -> int:  # the null at ``path`` under the take, made once
        if path not in nulls:
            parent, _, name = path.rpartition("/")
            nulls[path] = sc.null(name, node(parent))[0]
        return nulls[path]

    if groups is None:  # both nulls, as always, also when one is empty
        by_kind = [node("face"), node("brim")]
        group_ids = [by_kind[k] for k in kinds_arr.tolist()]
    else:
        group_ids = [node(g) for g in groups]

    with ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1))) as pool:
        curves = _Curves(sc, layer_id, rate, pool)
        _add_points(sc, curves, pts, ok, labels, kinds_arr, group_ids)
        if len(pairs):
            _add_sticks(sc, curves, pts, ok, labels, pairs, sc.null("sticks", take_id)[0])
        if cams is not None:
            _add_cameras(sc, curves, cams, take_id, axis)
        root = _build_document(sc, take_name, rate, up_axis, stop)
        with atomic_output(path) as fh:
            _write_file(fh, root)


def _write_file(fh: BinaryIO, root: list[_Node]) -> None:
    fh.write(_HEAD + struct.pack("<I", _VERSION))
    parts: list[bytes] = []
    end = len(_HEAD) + 4
    for node in root:
        end = _emit(node, end, parts)
    parts.append(_NULL)
    end += len(_NULL)
    # Few large writes instead of tens of thousands of small ones.
    batch: list[bytes] = []
    size = 0
    for part in parts:
        batch.append(part)
        size += len(part)
        if size >= 1 << 23:
            fh.write(b"".join(batch))
            batch, size = [], 0
    fh.write(b"".join(batch))
    # SDK footer: code, zero padding to a 16-byte boundary (at least 1 byte), 0, version,
    # 120 zero bytes, magic.
    pad = 16 - ((end + len(_FOOT_ID)) % 16)
    fh.write(_FOOT_ID + b"\0" * pad + struct.pack("<II", 0, _VERSION))
    fh.write(b"\0" * 120 + _FOOT_MAGIC)


def _add_points(
    sc: _Scene,
    curves: _Curves,
    pts: np.ndarray,
    ok: np.ndarray,
    labels: list[str],
    kinds: np.ndarray,
    group_ids: list[int],
) -> None:
    """One animated null per point, under ``group_ids[p]``."""
    n_frames, n_points, _ = pts.shape
    # Point-major copies: each point's track is then one contiguous block.
    pts = np.ascontiguousarray(pts.transpose(1, 0, 2), dtype=np.float32)
    ok = np.ascontiguousarray(ok.T)
    for p in range(n_points):
        frames = np.flatnonzero(ok[p])
        first = pts[p, frames[0]] if len(frames) else np.zeros(3)
        mid, props = sc.null(labels[p], group_ids[p], first)
        if len(frames) == 0:
            _p(props, "Visibility", "Visibility", "", "A", _d(0.0))
            continue
        keys, src = _hold_keys(ok[p])
        curves.curve_node(
            mid,
            "Lcl Translation",
            "XYZ",
            keys,
            pts[p, src],
            cache_key=np.packbits(ok[p]).tobytes(),
        )
        if len(frames) < n_frames:
            _p(props, "Visibility", "Visibility", "", "A", _d(1.0))
            vf, vv = _visibility_keys(ok[p])
            curves.curve_node(mid, "Visibility", ["Visibility"], vf, vv[:, None], _CONSTANT)


def _check_sticks(sticks: Sequence[tuple[int, int]] | None, n_points: int) -> np.ndarray:
    """Validate stick index pairs; return them as an [S, 2] int array."""
    if sticks is None:
        return np.zeros((0, 2), np.int64)
    try:
        pairs = np.asarray(sticks, dtype=np.int64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise ValueError("sticks must be a sequence of (i, j) point index pairs") from None
    if len(pairs) != len(sticks):
        raise ValueError("sticks must be a sequence of (i, j) point index pairs")
    if ((pairs < 0) | (pairs >= n_points)).any():
        raise ValueError(f"sticks hold point indices outside 0..{n_points - 1}")
    if (pairs[:, 0] == pairs[:, 1]).any():
        raise ValueError("sticks must join two different points")
    if len(np.unique(np.sort(pairs, axis=1), axis=0)) != len(pairs):
        raise ValueError("sticks holds the same pair of points twice")
    return pairs


def _align_rotations(v: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Smallest rotations taking unit vectors ``v`` [..., 3] to unit vectors ``u`` [..., 3]."""
    w = np.cross(v, u)
    c = np.einsum("...i,...i->...", v, u)
    k = np.zeros(w.shape + (3,))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    k -= np.swapaxes(k, -1, -2)
    with np.errstate(divide="ignore", invalid="ignore"):
        rot = np.eye(3) + k + k @ k / (1.0 + c)[..., None, None]
    # u == -v: half turn about an axis perpendicular to v.
    flip = ~(1.0 + c > 1e-9)
    if flip.any():
        vf = v[flip] if v.shape == u.shape else np.broadcast_to(v, u.shape)[flip]
        a = np.cross(vf, np.eye(3)[np.argmin(np.abs(vf), axis=-1)])
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        rot[flip] = 2 * a[:, :, None] * a[:, None, :] - np.eye(3)
    return rot


def _add_sticks(
    sc: _Scene,
    curves: _Curves,
    pts: np.ndarray,
    ok: np.ndarray,
    labels: list[str],
    pairs: np.ndarray,
    parent: int,
) -> None:
    """One two-vertex line mesh per stick, rigidly animated onto its two points.

    The geometry is the segment from the origin to the stick's mean unit direction ``v``;
    the node sits on point i (translation), turns ``v`` onto the current direction by the
    smallest rotation (small angles, so the Euler angles stay far from gimbal lock) and
    scales uniformly by the current length, which puts vertex 1 on point j. Only plain
    TRS animation is used, which every importer reads (skin clusters would turn the marker
    nulls into armature bones in Blender).
    """
    a, b = pts[:, pairs[:, 0]], pts[:, pairs[:, 1]]  # [F, S, 3]
    d = b - a
    length = np.linalg.norm(d, axis=2)
    ok_s = ok[:, pairs[:, 0]] & ok[:, pairs[:, 1]] & (length > 1e-9)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(ok_s[..., None], d / length[..., None], 0.0)
    mean = u.sum(axis=0)
    norm = np.linalg.norm(mean, axis=1)
    rest = np.where(norm[:, None] > 1e-9, mean / np.maximum(norm, 1e-300)[:, None], [1.0, 0, 0])
    u = np.where(ok_s[..., None], u, rest)
    euler = _euler_xyz_deg(_align_rotations(rest[None], u))  # [F, S, 3]
    n_frames = pts.shape[0]
    for s, (i, j) in enumerate(pairs):
        frames = np.flatnonzero(ok_s[:, s])
        f0 = frames[0] if len(frames) else 0
        name = f"{labels[i]}-{labels[j]}"
        gid, geom = sc.obj("Geometry", name, "Geometry", "Mesh")
        _props70(geom)
        geom.add("GeometryVersion", _i(124))
        geom.add("Vertices", _arr("d", np.concatenate([np.zeros(3), rest[s]])))
        # A loose edge: a two-vertex polygon (last index stored as -(index + 1)) plus its
        # Edges entry, as Blender's exporter writes loose edges.
        geom.add("PolygonVertexIndex", _arr("i", np.array([0, -2])))
        geom.add("Edges", _arr("i", np.array([0])))
        mid, model = sc.obj("Model", name, "Model", "Mesh")
        model.add("Version", _i(232))
        mp = _props70(model)
        t0 = a[f0, s] if len(frames) else np.zeros(3)
        s0 = length[f0, s] if len(frames) else 1.0
        _p(mp, "Lcl Translation", "Lcl Translation", "", "A", *map(_d, t0))
        _p(mp, "Lcl Rotation", "Lcl Rotation", "", "A", *map(_d, euler[f0, s]))
        _p(mp, "Lcl Scaling", "Lcl Scaling", "", "A", *map(_d, (s0,) * 3))
        _p(mp, "DefaultAttributeIndex", "int", "Integer", "", _i(0))
        _p(mp, "InheritType", "enum", "", "", _i(1))
        model.add("Shading", _c(1))
        model.add("Culling", _s("CullingOff"))
        sc.oo(gid, mid)
        sc.oo(mid, parent)
        if len(frames) == 0:
            _p(mp, "Visibility", "Visibility", "", "A", _d(0.0))
            continue
        keys, src = _hold_keys(ok_s[:, s])
        key = np.packbits(ok_s[:, s]).tobytes()
        curves.curve_node(mid, "Lcl Translation", "XYZ", keys, a[src, s], cache_key=key)
        angles = np.unwrap(euler[src, s], period=360.0, axis=0)
        curves.curve_node(mid, "Lcl Rotation", "XYZ", keys, angles, cache_key=key)
        scale = np.repeat(length[src, s][:, None], 3, axis=1)
        curves.curve_node(mid, "Lcl Scaling", "XYZ", keys, scale, cache_key=key)
        if len(frames) < n_frames:
            _p(mp, "Visibility", "Visibility", "", "A", _d(1.0))
            vf, vv = _visibility_keys(ok_s[:, s])
            curves.curve_node(mid, "Visibility", ["Visibility"], vf, vv[:, None], _CONSTANT)


def _check_cameras(cameras: Mapping[str, Any], n_frames: int) -> dict[str, Any]:
    try:
        R = np.asarray(cameras["R"], dtype=np.float64)
        t = np.asarray(cameras["t"], dtype=np.float64)
        focal = np.asarray(cameras["focal_px"], dtype=np.float64)
        size = np.asarray(cameras["image_size"], dtype=np.float64)
    except KeyError as exc:
        raise ValueError(f"cameras is missing {exc.args[0]!r}") from None
    if R.ndim != 4 or R.shape[0] != n_frames or R.shape[2:] != (3, 3):
        raise ValueError(f"cameras['R'] must have shape ({n_frames}, C, 3, 3), got {R.shape}")
    n_cams = R.shape[1]
    if t.shape != (n_frames, n_cams, 3):
        raise ValueError(f"cameras['t'] must have shape ({n_frames}, {n_cams}, 3)")
    if focal.shape != (n_cams,) or size.shape != (n_cams, 2):
        raise ValueError("cameras['focal_px'] must be [C] and cameras['image_size'] [C, 2]")
    if not (np.all(focal > 0) and np.all(size > 0)):
        raise ValueError("camera focal lengths and image sizes must be positive")
    names = [str(s) for s in cameras.get("names", [f"camera{c + 1}" for c in range(n_cams)])]
    if len(names) != n_cams:
        raise ValueError(f"cameras['names'] must have {n_cams} entries")
    return {"R": R, "t": t, "focal_px": focal, "image_size": size, "names": names}


def _add_cameras(sc: _Scene, curves: _Curves, cams: dict, parent: int, axis: np.ndarray) -> None:
    R, t = cams["R"], cams["t"]
    centre = -np.einsum("fcji,fcj->fci", R, t)  # C = -R^T t
    world_from_fbx_cam = np.swapaxes(R, -1, -2) @ _FBX_CAM_IN_CV
    rot = axis @ world_from_fbx_cam
    pos = centre @ axis.T
    euler = _euler_xyz_deg(rot)
    ok = np.isfinite(euler).all(axis=2) & np.isfinite(pos).all(axis=2)
    for c, name in enumerate(cams["names"]):
        frames = np.flatnonzero(ok[:, c])
        width, height = cams["image_size"][c]
        focal_mm = cams["focal_px"][c] * _FILM_WIDTH_MM / width
        aid, attr = sc.obj("NodeAttribute", name, "NodeAttribute", "Camera")
        ap = _props70(attr)
        _p(ap, "AspectWidth", "double", "Number", "", _d(width))
        _p(ap, "AspectHeight", "double", "Number", "", _d(height))
        _p(ap, "FilmWidth", "double", "Number", "", _d(_FILM_WIDTH_MM / 25.4))
        _p(ap, "FilmHeight", "double", "Number", "", _d(_FILM_WIDTH_MM * height / width / 25.4))
        _p(ap, "ApertureMode", "enum", "", "", _i(3))  # focal length drives the FOV
        _p(ap, "GateFit", "enum", "", "", _i(2))  # horizontal
        _p(ap, "FocalLength", "Number", "", "A", _d(focal_mm))
        _p(ap, "AspectRatioMode", "enum", "", "", _i(2))  # fixed resolution
        attr.add("TypeFlags", _s("Camera"))
        attr.add("GeometryVersion", _i(124))
        attr.add("Position", _d(0), _d(0), _d(0))
        attr.add("Up", _d(0), _d(1), _d(0))
        attr.add("LookAt", _d(1), _d(0), _d(0))
        first = frames[0] if len(frames) else 0
        p0 = pos[first, c] if len(frames) else np.zeros(3)
        e0 = euler[first, c] if len(frames) else np.zeros(3)
        mid, _ = sc.model(name, "Camera", aid, parent, p0, e0)
        if len(frames) == 0:
            continue
        keys, src = _hold_keys(ok[:, c])
        key = np.packbits(ok[:, c]).tobytes()
        curves.curve_node(mid, "Lcl Translation", "XYZ", keys, pos[src, c], cache_key=key)
        # Unwrap so linear interpolation between frames never spins through +-180 degrees.
        angles = np.unwrap(euler[src, c], period=360.0, axis=0)
        curves.curve_node(mid, "Lcl Rotation", "XYZ", keys, angles, cache_key=key)


def _build_document(sc: _Scene, take: str, rate: float, up_axis: str, stop: int) -> list[_Node]:
    header = _Node("FBXHeaderExtension")
    header.add("FBXHeaderVersion", _i(1003))
    header.add("FBXVersion", _i(_VERSION))
    header.add("EncryptionType", _i(0))
    stamp = header.add("CreationTimeStamp")
    for key, val in (("Version", 1000), ("Year", 1970), ("Month", 1), ("Day", 1), ("Hour", 10)):
        stamp.add(key, _i(val))
    for key in ("Minute", "Second", "Millisecond"):
        stamp.add(key, _i(0))
    creator = f"carapost {__version__}"
    header.add("Creator", _s(creator))

    gs = _Node("GlobalSettings")
    gs.add("Version", _i(1000))
    gp = _props70(gs)
    if up_axis == "y":
        axes = (("UpAxis", 1), ("UpAxisSign", 1), ("FrontAxis", 2), ("FrontAxisSign", 1))
    else:
        axes = (("UpAxis", 2), ("UpAxisSign", 1), ("FrontAxis", 1), ("FrontAxisSign", -1))
    axes += (("CoordAxis", 0), ("CoordAxisSign", 1))
    for key, val in axes:
        _p(gp, key, "int", "Integer", "", _i(val))
    _p(gp, "OriginalUpAxis", "int", "Integer", "", _i(axes[0][1]))
    _p(gp, "OriginalUpAxisSign", "int", "Integer", "", _i(1))
    _p(gp, "UnitScaleFactor", "double", "Number", "", _d(0.1))  # mm (FBX unit is cm)
    _p(gp, "OriginalUnitScaleFactor", "double", "Number", "", _d(0.1))
    _p(gp, "DefaultCamera", "KString", "", "", _s("Producer Perspective"))
    _p(gp, "TimeMode", "enum", "", "", _i(fbx_time_mode(rate)))
    _p(gp, "TimeProtocol", "enum", "", "", _i(2))
    _p(gp, "SnapOnFrameMode", "enum", "", "", _i(0))
    _p(gp, "TimeSpanStart", "KTime", "Time", "", _l(0))
    _p(gp, "TimeSpanStop", "KTime", "Time", "", _l(stop))
    _p(gp, "CustomFrameRate", "double", "Number", "", _d(rate))

    docs = _Node("Documents")
    docs.add("Count", _i(1))
    doc = docs.add("Document", _l(sc.new_id()), _s("Scene"), _s("Scene"))
    dp = _props70(doc)
    _p(dp, "SourceObject", "object", "", "")
    _p(dp, "ActiveAnimStackName", "KString", "", "", _s(take))
    doc.add("RootNode", _l(0))

    defs = _Node("Definitions")
    defs.add("Version", _i(100))
    defs.add("Count", _i(1 + sum(sc.counts.values())))
    defs.add("ObjectType", _s("GlobalSettings")).add("Count", _i(1))
    for kind, n in sc.counts.items():
        defs.add("ObjectType", _s(kind)).add("Count", _i(n))

    takes = _Node("Takes")
    takes.add("Current", _s(take))
    tk = takes.add("Take", _s(take))
    tk.add("FileName", _s(f"{take}.tak"))
    tk.add("LocalTime", _l(0), _l(stop))
    tk.add("ReferenceTime", _l(0), _l(stop))

    return [
        header,
        _Node("FileId", b"R" + struct.pack("<I", 16) + _FILE_ID),
        _Node("CreationTime", _s(_CREATION_TIME)),
        _Node("Creator", _s(creator)),
        gs,
        docs,
        _Node("References", block=True),
        defs,
        sc.objects,
        sc.connections,
        takes,
    ]
