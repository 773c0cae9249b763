"""FBX export: load what we write with ufbx (and assimp / Blender when installed).

The tests that read with ufbx run in a forked child (`tests.ufbx_child`): the binding
can crash while it frees its wrappers."""

from __future__ import annotations

import importlib.util
import shutil
import struct
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import ufbx

from carapost.io.errors import CaraFileError
from carapost.io.fbx import KTIME_PER_SECOND, fbx_time_mode, write_fbx
from tests.ufbx_child import in_child

Y_UP = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # our Z-up -> file Y-up


class Loaded:
    """A ufbx scene plus every wrapper we touch, kept alive (the binding segfaults on a
    wrapper freed before another); only made in a test's child (`in_child`), which
    leaves without freeing them."""

    def __init__(self, path):
        self.scene = ufbx.load_file(str(path), strict=True)
        self.nodes = list(self.scene.nodes)
        self.by_name = {n.name: n for n in self.nodes}
        self.meshes = list(self.scene.meshes)
        self.keep = []

    def position(self, name, frame, rate):
        tr = ufbx.evaluate_transform(self.scene.anim, self.by_name[name], frame / rate)
        self.keep.append(tr)
        v = tr.translation
        return np.array([v.x, v.y, v.z])

    def rotation(self, name, frame, rate):
        tr = ufbx.evaluate_transform(self.scene.anim, self.by_name[name], frame / rate)
        self.keep.append(tr)
        q = tr.rotation
        x, y, z, w = q.x, q.y, q.z, q.w
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )

    def visible(self, name, frame, rate):
        evaluated = self.scene.evaluate(self.scene.anim, frame / rate)
        nodes = list(evaluated.nodes)
        self.keep += [evaluated, nodes]
        return next(n for n in nodes if n.name == name).visible

    def mesh_counts(self):
        """{mesh name: (vertices, faces, line faces, edges)} as plain Python data."""
        return {
            m.name: (m.num_vertices, m.num_faces, m.num_line_faces, m.num_edges)
            for m in self.meshes
        }

    def stick_ends(self, name, frame, rate):
        """World positions of a stick mesh's two vertices (its parents are static)."""
        mesh = next(m for m in self.meshes if m.name == name)
        verts = list(mesh.vertices)
        self.keep += [mesh, verts]
        v = np.array([[p.x, p.y, p.z] for p in verts])
        tr = ufbx.evaluate_transform(self.scene.anim, self.by_name[name], frame / rate)
        self.keep.append(tr)
        sc = np.array([tr.scale.x, tr.scale.y, tr.scale.z])
        rot = self.rotation(name, frame, rate)
        return self.position(name, frame, rate) + (v * sc) @ rot.T

    def parent_name(self, name):
        parent = self.by_name[name].parent
        self.keep.append(parent)
        return parent.name


def make_points(rng, n_frames=130, n_points=5):
    steps = rng.normal(0.0, 0.5, (n_frames, n_points, 3))
    return np.cumsum(steps, axis=0) + rng.normal(0.0, 60.0, (1, n_points, 3))


@in_child
def test_nodes_positions_units_y_up(tmp_path, rng):
    pos = make_points(rng)
    labels = ["nose", "lip_l", "lip_r", "brim_a", "brim_b"]
    kinds = np.array([0, 0, 0, 1, 1])
    path = tmp_path / "take.fbx"
    write_fbx(path, pos, labels=labels, rate=60, kinds=kinds, take_name="ROM_01")
    s = Loaded(path)
    assert {"ROM_01", "face", "brim", *labels} <= set(s.by_name)
    assert s.parent_name("face") == "ROM_01" and s.parent_name("brim") == "ROM_01"
    assert [s.parent_name(n) for n in labels] == ["face"] * 3 + ["brim"] * 2
    settings = s.scene.settings
    assert settings.unit_meters == pytest.approx(0.001)
    assert settings.frames_per_second == 60 and int(settings.time_mode) == fbx_time_mode(60)
    axes = settings.axes
    assert axes.up == ufbx.CoordinateAxis.POSITIVE_Y
    # Frames 7, 61 and 119 are not whole seconds at 60 fps.
    for frame in (0, 7, 61, 119, 129):
        for p, name in enumerate(labels):
            np.testing.assert_allclose(s.position(name, frame, 60), Y_UP @ pos[frame, p], atol=1e-4)


@in_child
def test_z_up_custom_rate(tmp_path, rng):
    pos = make_points(rng, n_frames=90, n_points=3)
    rate = 47.3  # not an FBX standard rate: custom time mode
    path = tmp_path / "take.fbx"
    write_fbx(path, pos, labels=["a", "b", "c"], rate=rate, up_axis="z")
    s = Loaded(path)
    assert int(s.scene.settings.time_mode) == 14 == fbx_time_mode(rate)
    assert s.scene.settings.frames_per_second == pytest.approx(rate)
    assert s.scene.settings.axes.up == ufbx.CoordinateAxis.POSITIVE_Z
    for frame in (0, 1, 33, 47, 89):
        np.testing.assert_allclose(s.position("b", frame, rate), pos[frame, 1], atol=1e-4)
    # Halfway between frames the keys interpolate linearly.
    np.testing.assert_allclose(
        s.position("a", 10.5, rate), (pos[10, 0] + pos[11, 0]) / 2, atol=1e-4
    )


def test_standard_rates_use_the_enum():
    assert fbx_time_mode(60) == 3 and fbx_time_mode(24) == 11 and fbx_time_mode(120) == 1
    assert fbx_time_mode(30000 / 1001) == 9 and fbx_time_mode(29.97) == 14


@in_child
def test_gaps_hold_still_and_hide(tmp_path, rng):
    pos = make_points(rng, n_frames=40, n_points=3)
    pos[10:15, 1] = np.nan  # a gap
    pos[:5, 2] = np.nan  # missing at the start
    valid = np.ones(pos.shape[:2], bool)
    valid[20:22, 0] = False  # caller-marked invalid samples
    path = tmp_path / "gaps.fbx"
    write_fbx(path, pos, labels=["a", "b", "c"], rate=24, valid=valid, up_axis="z")
    s = Loaded(path)
    for frame in (10, 12, 14):  # held at the last valid value, not interpolated
        np.testing.assert_allclose(s.position("b", frame, 24), pos[9, 1], atol=1e-4)
        assert not s.visible("b", frame, 24)
    for frame in (9, 15, 16):
        np.testing.assert_allclose(s.position("b", frame, 24), pos[frame, 1], atol=1e-4)
        assert s.visible("b", frame, 24)
    np.testing.assert_allclose(s.position("a", 21, 24), pos[19, 0], atol=1e-4)
    np.testing.assert_allclose(s.position("a", 22, 24), pos[22, 0], atol=1e-4)
    assert not s.visible("c", 2, 24) and s.visible("c", 5, 24)
    np.testing.assert_allclose(s.position("c", 7, 24), pos[7, 2], atol=1e-4)


@in_child
def test_point_without_data(tmp_path, rng):
    pos = make_points(rng, n_frames=10, n_points=2)
    pos[:, 1] = np.nan
    path = tmp_path / "empty.fbx"
    write_fbx(path, pos, labels=["a", "ghost"], rate=30)
    s = Loaded(path)
    assert "ghost" in s.by_name and not s.visible("ghost", 3, 30)
    np.testing.assert_allclose(s.position("a", 3, 30), Y_UP @ pos[3, 0], atol=1e-4)


def look_at(centre, target, up=(0.0, 0.0, 1.0)):
    """World->camera R, t for an OpenCV camera (z forward, y down) at centre."""
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


@pytest.mark.parametrize("up_axis", ["y", "z"])
@in_child
def test_cameras(tmp_path, rng, up_axis):
    n_frames, rate = 50, 60
    pos = make_points(rng, n_frames=n_frames, n_points=2)
    R = np.zeros((n_frames, 2, 3, 3))
    t = np.zeros((n_frames, 2, 3))
    for f in range(n_frames):
        ang = np.radians(9.0 * f)  # orbits more than a full turn: tests angle unwrapping
        for c in range(2):
            centre = np.array([300 * np.cos(ang + c), 300 * np.sin(ang + c), 40.0 + c])
            R[f, c], t[f, c] = look_at(centre, np.array([0.0, 0.0, 20.0]))
    R[30, 1] = np.nan  # camera 1 not solved at frame 30
    cams = {
        "R": R,
        "t": t,
        "focal_px": np.array([900.0, 1200.0]),
        "image_size": np.array([[1280, 720], [1920, 1080]]),
        "names": ["caddyL_cam1", "caddyR_cam2"],
    }
    path = tmp_path / "cams.fbx"
    write_fbx(path, pos, labels=["a", "b"], rate=rate, cameras=cams, up_axis=up_axis)
    s = Loaded(path)
    axis = Y_UP if up_axis == "y" else np.eye(3)
    cameras = list(s.scene.cameras)
    by_name = {c.name: c for c in cameras}
    for c, name in enumerate(cams["names"]):
        cam = by_name[name]
        w, h = cams["image_size"][c]
        fov = cam.field_of_view_deg
        assert fov.x == pytest.approx(np.degrees(2 * np.arctan(w / 2 / cams["focal_px"][c])))
        assert fov.y == pytest.approx(np.degrees(2 * np.arctan(h / 2 / cams["focal_px"][c])))
        for f in (0, 7, 25, 41, 49):
            M = s.rotation(name, f, rate)
            forward, up = M[:, 0], M[:, 1]  # FBX cameras look down +X with +Y up
            np.testing.assert_allclose(forward, axis @ R[f, c].T @ [0, 0, 1], atol=1e-6)
            np.testing.assert_allclose(up, axis @ R[f, c].T @ [0, -1, 0], atol=1e-6)
            centre = -R[f, c].T @ t[f, c]
            np.testing.assert_allclose(s.position(name, f, rate), axis @ centre, atol=1e-6)
    # The unsolved frame holds the previous pose.
    np.testing.assert_allclose(
        s.rotation("caddyR_cam2", 30, rate), s.rotation("caddyR_cam2", 29, rate), atol=1e-9
    )


def test_binary_layout(tmp_path, rng):
    pos = make_points(rng, n_frames=300, n_points=4)
    path = tmp_path / "take.fbx"
    write_fbx(path, pos, labels=list("abcd"), rate=100)
    data = path.read_bytes()
    assert data[:23] == b"Kaydara FBX Binary  \x00\x1a\x00"
    assert struct.unpack_from("<I", data, 23)[0] == 7400
    # Walk the top-level nodes by their end offsets: the chain must end in a null record
    # followed by the SDK footer, and the file length is a multiple of 16.
    pos_ = 27
    names = []
    while True:
        end, nprops, plen, nlen = struct.unpack_from("<IIIB", data, pos_)
        if end == 0:
            assert (nprops, plen, nlen) == (0, 0, 0)
            pos_ += 13
            break
        names.append(data[pos_ + 13 : pos_ + 13 + nlen].decode())
        assert end > pos_
        pos_ = end
    assert names[0] == "FBXHeaderExtension" and {"GlobalSettings", "Objects"} <= set(names)
    assert names[-2:] == ["Connections", "Takes"]
    assert len(data) % 16 == 0 and data.endswith(bytes.fromhex("f85a8c6adef5d97eece90ce3758f290b"))
    assert data[pos_ : pos_ + 16] == bytes.fromhex("fabcab09d0c8d466b176fb831cf7267e")
    # Key times of frame f are f * KTIME_PER_SECOND / rate ticks; the 100 fps curves hold
    # frames 0..299 so the last key is 299 / 100 s.
    stop = struct.pack("<q", 299 * KTIME_PER_SECOND // 100)
    assert stop in data  # TimeSpanStop / LocalStop


def test_bad_input(tmp_path, rng):
    pos = make_points(rng, n_frames=5, n_points=2)
    path = tmp_path / "x.fbx"
    with pytest.raises(ValueError, match="positions"):
        write_fbx(path, pos[..., :2], labels=["a", "b"], rate=30)
    with pytest.raises(ValueError, match="unique"):
        write_fbx(path, pos, labels=["a", "a"], rate=30)
    with pytest.raises(ValueError, match="rate"):
        write_fbx(path, pos, labels=["a", "b"], rate=-1)
    with pytest.raises(ValueError, match="up_axis"):
        write_fbx(path, pos, labels=["a", "b"], rate=30, up_axis="x")
    with pytest.raises(ValueError, match="kinds"):
        write_fbx(path, pos, labels=["a", "b"], rate=30, kinds=np.array([0, 2]))
    with pytest.raises(ValueError, match="cameras"):
        write_fbx(path, pos, labels=["a", "b"], rate=30, cameras={"R": np.eye(3)})
    for sticks, msg in (([(0, 2)], "outside"), ([(1, 1)], "different"),
                        ([(0, 1), (1, 0)], "twice"), ([(0, 1, 2)], "pairs")):  # fmt: skip
        with pytest.raises(ValueError, match=msg):
            write_fbx(path, pos, labels=["a", "b"], rate=30, sticks=sticks)
    assert not list(tmp_path.iterdir())
    with pytest.raises(CaraFileError, match="does not exist"):
        write_fbx(tmp_path / "missing" / "x.fbx", pos, labels=["a", "b"], rate=30)


@pytest.mark.skipif(shutil.which("assimp") is None, reason="assimp CLI not installed")
def test_assimp_reads_animation(tmp_path, rng):
    pos = make_points(rng, n_frames=20, n_points=2)
    path = tmp_path / "take.fbx"
    write_fbx(path, pos, labels=["a", "b"], rate=60)
    out = subprocess.run(["assimp", "info", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "a" in out.stdout and "Animations" in out.stdout


@pytest.mark.skipif(shutil.which("blender") is None, reason="blender not installed")
def test_blender_imports(tmp_path, rng):
    pos = make_points(rng, n_frames=20, n_points=2)
    path = tmp_path / "take.fbx"
    write_fbx(path, pos, labels=["a", "b"], rate=60, up_axis="z")
    script = (
        "import bpy, sys\n"
        f"bpy.ops.import_scene.fbx(filepath={str(path)!r})\n"
        "o = bpy.data.objects['b']\n"
        "bpy.context.scene.frame_set(8)\n"
        "print('POS', *tuple(o.matrix_world.translation))\n"
    )
    out = subprocess.run(
        ["blender", "-b", "--factory-startup", "--python-expr", script],
        capture_output=True,
        text=True,
        timeout=300,
    )
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("POS"))
    got = np.array([float(v) for v in line.split()[1:]])
    # Blender frame 8 = FBX time 7 / rate (its time 0 is frame 1); metres.
    np.testing.assert_allclose(got, pos[7, 1] / 1000.0, atol=1e-6)


STICKS = [(0, 1), (1, 2), (3, 0), (2, 4)]


def stick_take(rng):
    pos = make_points(rng, n_frames=60, n_points=5)
    pos[20:26, 2] = np.nan  # gap in one end of two sticks
    pos[40, 2] = pos[40, 1]  # zero-length stick 1-2 at frame 40: held like a gap
    return pos


@pytest.mark.parametrize("up_axis", ["y", "z"])
@in_child
def test_sticks_follow_markers(tmp_path, rng, up_axis):
    pos = stick_take(rng)
    labels = ["a", "b", "c", "d", "e"]
    path = tmp_path / "sticks.fbx"
    write_fbx(path, pos, labels=labels, rate=50, sticks=STICKS, up_axis=up_axis, take_name="T")
    s = Loaded(path)
    axis = Y_UP if up_axis == "y" else np.eye(3)
    names = [f"{labels[i]}-{labels[j]}" for i, j in STICKS]
    assert s.parent_name("sticks") == "T" and all(s.parent_name(n) == "sticks" for n in names)
    # One loose edge each: (vertices, faces, line faces, edges).
    assert s.mesh_counts() == {n: (2, 1, 1, 1) for n in names}
    for (i, j), name in zip(STICKS, names, strict=True):
        ok = np.isfinite(pos[:, [i, j]]).all(axis=(1, 2))
        ok &= np.linalg.norm(pos[:, i] - pos[:, j], axis=1) > 0
        for f in (0, 13, 19, 22, 25, 26, 40, 41, 59):
            ends = s.stick_ends(name, f, 50)
            src = f if ok[f] else np.flatnonzero(ok[:f])[-1]  # held through gaps
            np.testing.assert_allclose(ends[0], axis @ pos[src, i], atol=2e-4)
            np.testing.assert_allclose(ends[1], axis @ pos[src, j], atol=2e-4)
            assert s.visible(name, f, 50) == ok[f]


@in_child
def test_stick_never_valid(tmp_path, rng):
    pos = make_points(rng, n_frames=8, n_points=3)
    pos[:, 2] = np.nan
    path = tmp_path / "s.fbx"
    write_fbx(path, pos, labels=["a", "b", "c"], rate=30, sticks=[(0, 2), (0, 1)])
    s = Loaded(path)
    assert not s.visible("a-c", 3, 30) and s.visible("a-b", 3, 30)
    np.testing.assert_allclose(s.stick_ends("a-b", 5, 30), pos[5, :2] @ Y_UP.T, atol=2e-4)


def assimp_dump(path):
    out = path.with_suffix(".assxml")
    run = subprocess.run(["assimp", "dump", str(path), str(out)], capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr
    return ET.parse(out).getroot()


def assimp_floats(el):
    return np.array(el.text.split(), dtype=np.float64)


def quat_xyzw_matrix(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


@pytest.mark.skipif(shutil.which("assimp") is None, reason="assimp CLI not installed")
def test_assimp_reads_sticks(tmp_path, rng):
    pos = make_points(rng, n_frames=30, n_points=5)
    labels = ["a", "b", "c", "d", "e"]
    path = tmp_path / "sticks.fbx"
    write_fbx(path, pos, labels=labels, rate=30, sticks=STICKS, up_axis="z")
    root = assimp_dump(path)
    meshes = root.findall(".//MeshList/Mesh")
    assert len(meshes) == len(STICKS) and all("lines" in m.get("types") for m in meshes)
    nodes = {n.get("name"): n for n in root.iter("Node")}
    anims = {a.get("node"): a for a in root.iter("NodeAnim")}
    for i, j in STICKS:
        name = f"{labels[i]}-{labels[j]}"
        mesh = meshes[int(nodes[name].find("MeshRefs").text.split()[0])]
        verts = assimp_floats(mesh.find("Positions")).reshape(2, 3)
        anim = anims[name]
        for f in (0, 11, 29):  # one key per frame, ticks = frames
            t = assimp_floats(anim.findall(".//PositionKey")[f])
            q = assimp_floats(anim.findall(".//RotationKey")[f])
            sc = assimp_floats(anim.findall(".//ScalingKey")[f])
            ends = t + (verts * sc) @ quat_xyzw_matrix(q).T  # the dump writes x, y, z, w
            np.testing.assert_allclose(ends, pos[f, [i, j]], atol=1e-3)


def load_render_script():
    path = Path(__file__).resolve().parents[2] / "scripts" / "render_fbx_in_blender.py"
    spec = importlib.util.spec_from_file_location("render_fbx_in_blender", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(shutil.which("blender") is None, reason="blender not installed")
def test_blender_imports_synthetic_take(tmp_path):
    """The docs screenshot's checks: every node, marker and stick end as the model says."""
    script = load_render_script()
    take = script.make_take()
    path = tmp_path / "ROM.fbx"
    script.write_take(path, take)
    result = script.run_blender(path)
    assert script.compare(result, take) == []
    n_labels = len(take["labels"])
    assert len(result["markers"]) == n_labels * len(script.CHECK_FRAMES)
    assert len(result["sticks"]) == len(take["sticks"]) * len(script.CHECK_FRAMES)
    assert result["fps"] == pytest.approx(take["rate"])
    assert sorted(result["cameras"]) == take["cameras"]["names"]
