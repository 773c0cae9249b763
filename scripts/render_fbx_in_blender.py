"""Export a synthetic take to FBX, import it into headless Blender, check it and render it.

Run from the repository root with the project's Python (Blender must be on PATH)::

    python scripts/render_fbx_in_blender.py              # checks + docs/images/blender-import.png
    python scripts/render_fbx_in_blender.py --no-render  # checks only

The script has two halves. Outside Blender it builds a synthetic take with
`carapost.synth.build_scene` (face markers, brim dots, the four helmet cameras, sticks along a
Delaunay mesh of the face), writes it with `carapost.io.fbx.write_fbx` and starts
``blender -b --factory-startup --python <this file> -- <job.json>``. Inside Blender it imports
the FBX with Blender's own importer, reports node names, world positions of every marker and
stick vertex at a few frames and the cameras as JSON, and optionally renders a still (Cycles on
the CPU: Workbench and Eevee need an OpenGL context, which headless machines lack). Back
outside it compares the JSON with the model and prints one JSON summary line; the exit status
is 1 when a check fails.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_PNG = ROOT / "docs" / "images" / "blender-import.png"
CHECK_FRAMES = (0, 17, 45, 89)  # FBX frames; Blender shows frame f at f + 1
RENDER_FRAME = 45
TOLERANCE_M = 1e-5  # Blender works in metres; float32 keys of mm values


# --------------------------------------------------------------------------------------
# Outside Blender: build, export, run Blender, compare
# --------------------------------------------------------------------------------------


def make_take(frames: int = 90, seed: int = 0) -> dict[str, Any]:
    """A synthetic take in the Z-up brim frame (mm), ready for `write_fbx`.

    Returns a dict with ``positions`` [F, P, 3] (NaN where fewer than two cameras see a
    face marker), ``labels``, ``kinds``, ``sticks`` (Delaunay edges of the face markers),
    ``cameras`` (the `write_fbx` mapping) and ``rate``.
    """
    import numpy as np
    from scipy.spatial import Delaunay

    from carapost.synth import SynthConfig, build_scene

    sc = build_scene(SynthConfig(preset="speech", markers="standard", frames=frames, seed=seed))
    # Helmet frame (x actor's left, y up, z forward) -> Z-up brim frame; a proper rotation.
    to_brim = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    face = sc.points3d @ to_brim.T
    # Triangulated points need two views: keying only those gives real gaps (blinks).
    face[sc.visible.sum(axis=2) < 2] = np.nan
    brim = np.broadcast_to(sc.brim3d @ to_brim.T, (frames, len(sc.brim3d), 3))
    positions = np.concatenate([face, brim], axis=1)
    labels = list(sc.labels) + list(sc.brim_labels)
    kinds = np.r_[np.zeros(len(sc.labels), int), np.ones(len(sc.brim_labels), int)]
    # Sticks as the app's Create Stick Mesh makes them: Delaunay edges seen from the front.
    rest = (sc.points3d[0] @ to_brim.T)[:, [0, 2]]
    edges = set()
    for tri in Delaunay(rest).simplices:
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[0], tri[2])):
            edges.add((int(min(a, b)), int(max(a, b))))
    cameras = {
        "R": sc.cam_R @ to_brim.T,  # x_cam = R X_helmet + t = (R A^T) X_brim + t
        "t": sc.cam_t,
        "focal_px": sc.intrinsics.focal,
        "image_size": sc.intrinsics.image_size,
        "names": [f"cam{c + 1}" for c in range(sc.cam_R.shape[1])],
    }
    return {
        "positions": positions,
        "labels": labels,
        "kinds": kinds,
        "sticks": sorted(edges),
        "cameras": cameras,
        "rate": float(sc.config.fps),
    }


def write_take(path: str | os.PathLike[str], take: dict[str, Any], take_name: str = "ROM") -> None:
    """Write ``take`` (from `make_take`) as FBX with sticks and cameras, Y-up."""
    from carapost.io.fbx import write_fbx

    write_fbx(
        path,
        take["positions"],
        labels=take["labels"],
        rate=take["rate"],
        kinds=take["kinds"],
        take_name=take_name,
        cameras=take["cameras"],
        sticks=take["sticks"],
        up_axis="y",
    )


def run_blender(
    fbx: str | os.PathLike[str],
    frames: tuple[int, ...] = CHECK_FRAMES,
    png: str | os.PathLike[str] | None = None,
    render_frame: int = RENDER_FRAME,
    blender: str = "blender",
    timeout: float = 600.0,
) -> dict[str, Any]:
    """Import ``fbx`` in headless Blender; return what it reports (see `_blender_main`)."""
    with tempfile.TemporaryDirectory() as tmp:
        job = Path(tmp) / "job.json"
        out = Path(tmp) / "result.json"
        job.write_text(json.dumps({
            "fbx": str(Path(fbx).resolve()), "frames": list(frames), "out": str(out),
            "png": None if png is None else str(Path(png).resolve()),
            "render_frame": render_frame,
        }))  # fmt: skip
        cmd = [blender, "-b", "--factory-startup", "--python", str(Path(__file__).resolve()),
               "--", str(job)]  # fmt: skip
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        if proc.returncode != 0 or not out.exists():
            raise RuntimeError(
                f"blender failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n"
                f"{proc.stderr[-3000:]}"
            )
        return json.loads(out.read_text())


def compare(result: dict[str, Any], take: dict[str, Any], take_name: str = "ROM") -> list[str]:
    """Differences between what Blender reports and the model (empty list = all good).

    Blender converts the file's Y-up millimetres back to Z-up metres, so a marker's world
    position must equal its brim-frame position / 1000; held gap frames repeat the last
    valid value before the gap.
    """
    import numpy as np

    pos = np.asarray(take["positions"], dtype=np.float64)
    labels = take["labels"]
    problems: list[str] = []
    objs = result["objects"]
    for name in (take_name, "face", "brim", "sticks", *labels):
        if objs.get(name) != "EMPTY":
            problems.append(f"{name}: expected an EMPTY, got {objs.get(name)}")
    for name in take["cameras"]["names"]:
        if objs.get(name) != "CAMERA":
            problems.append(f"{name}: expected a CAMERA, got {objs.get(name)}")
    stick_names = [f"{labels[i]}-{labels[j]}" for i, j in take["sticks"]]
    for name in stick_names:
        if objs.get(name) != "MESH":
            problems.append(f"{name}: expected a MESH, got {objs.get(name)}")

    def held(p: int, f: int) -> np.ndarray:
        ok = np.flatnonzero(np.isfinite(pos[: f + 1, p]).all(axis=1))
        return pos[ok[-1], p] if len(ok) else pos[f, p] * np.nan

    worst = 0.0
    for key, got in result["markers"].items():
        f, name = key.split(":", 1)
        p = labels.index(name)
        want = held(p, int(f)) / 1000.0
        if np.isnan(want).any():
            continue  # never seen yet: nothing to compare
        err = float(np.abs(np.asarray(got) - want).max())
        worst = max(worst, err)
        if err > TOLERANCE_M:
            problems.append(f"marker {name} frame {f}: blender {got}, model {want.tolist()}")
    for key, (v0, v1) in result["sticks"].items():
        f, name = key.split(":", 1)
        i, j = take["sticks"][stick_names.index(name)]
        if not (np.isfinite(pos[int(f), i]).all() and np.isfinite(pos[int(f), j]).all()):
            continue  # a held stick is hidden elsewhere; Blender ignores Visibility
        err = max(np.abs(np.asarray(v0) - pos[int(f), i] / 1000).max(),
                  np.abs(np.asarray(v1) - pos[int(f), j] / 1000).max())  # fmt: skip
        worst = max(worst, float(err))
        if err > TOLERANCE_M:
            problems.append(f"stick {name} frame {f}: ends {v0}, {v1}")
    result["worst_error_m"] = worst
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--png", default=str(DEFAULT_PNG), help="output image")
    parser.add_argument("--no-render", action="store_true", help="checks only")
    parser.add_argument("--fbx", help="keep the exported FBX here (default: temporary)")
    args = parser.parse_args(argv)
    if shutil.which("blender") is None:
        print(json.dumps({"error": "blender is not on PATH"}))
        return 2
    take = make_take()
    with tempfile.TemporaryDirectory() as tmp:
        fbx = Path(args.fbx) if args.fbx else Path(tmp) / "ROM.fbx"
        write_take(fbx, take)
        png = None if args.no_render else args.png
        result = run_blender(fbx, png=png)
    problems = compare(result, take)
    print(json.dumps({
        "blender": result["version"], "objects": len(result["objects"]),
        "markers_checked": len(result["markers"]), "sticks_checked": len(result["sticks"]),
        "worst_error_m": result["worst_error_m"], "problems": problems[:20], "png": png,
    }))  # fmt: skip
    return 1 if problems else 0


# --------------------------------------------------------------------------------------
# Inside Blender
# --------------------------------------------------------------------------------------


def _blender_main(job_path: str) -> None:
    """Import the FBX, report names and world positions, optionally render a still."""
    import bpy

    job = json.loads(Path(job_path).read_text())
    for obj in list(bpy.data.objects):  # factory startup: cube, light, camera
        bpy.data.objects.remove(obj, do_unlink=True)
    bpy.ops.import_scene.fbx(filepath=job["fbx"])
    scene = bpy.context.scene
    objs = {o.name: o.type for o in bpy.data.objects}
    markers: dict[str, list[float]] = {}
    sticks: dict[str, list[list[float]]] = {}
    point_objs = [o for o in bpy.data.objects if o.type == "EMPTY" and not o.children]
    stick_objs = [o for o in bpy.data.objects if o.type == "MESH"]
    for f in job["frames"]:
        scene.frame_set(f + 1)  # the importer puts FBX time 0 on frame 1
        for o in point_objs:
            markers[f"{f}:{o.name}"] = list(o.matrix_world.translation)
        for o in stick_objs:
            sticks[f"{f}:{o.name}"] = [list(o.matrix_world @ v.co) for v in o.data.vertices]
    cams = {o.name: o.data.lens for o in bpy.data.objects if o.type == "CAMERA"}
    result = {
        "version": bpy.app.version_string,
        "objects": objs,
        "markers": markers,
        "sticks": sticks,
        "cameras": cams,
        "fps": scene.render.fps / scene.render.fps_base,
    }
    Path(job["out"]).write_text(json.dumps(result))
    if job["png"]:
        _render(job["png"], job["render_frame"] + 1, point_objs, stick_objs)


def _render(png: str, frame: int, point_objs: list, stick_objs: list) -> None:
    """Spheres on the marker empties, tubes on the stick edges, a camera framing the face."""
    import bmesh
    import bpy
    from mathutils import Vector

    scene = bpy.context.scene
    scene.frame_set(frame)

    def material(name: str, rgb: tuple[float, float, float], rough: float = 0.45) -> Any:
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*rgb, 1.0)
        bsdf.inputs["Roughness"].default_value = rough
        return mat

    face_mat = material("marker", (0.92, 0.92, 0.88))
    brim_mat = material("brim", (1.0, 0.45, 0.08))
    stick_mat = material("stick", (0.05, 0.55, 0.85), 0.6)

    sphere = bpy.data.meshes.new("marker_sphere")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=16, v_segments=8, radius=1.0)
    bm.to_mesh(sphere)
    bm.free()
    for poly in sphere.polygons:
        poly.use_smooth = True
    brim_names = {o.name for o in point_objs if o.parent and o.parent.name == "brim"}
    for o in point_objs:
        ball = bpy.data.objects.new(f"{o.name}_ball", sphere)
        ball.parent = o  # follows the imported empty; its local unit is the file's mm
        ball.scale = (2.2, 2.2, 2.2) if o.name in brim_names else (1.8, 1.8, 1.8)
        ball.active_material = brim_mat if o.name in brim_names else face_mat
        ball.material_slots[0].link = "OBJECT"
        ball.material_slots[0].material = brim_mat if o.name in brim_names else face_mat
        scene.collection.objects.link(ball)
    for o in stick_objs:
        # Lines do not render: a skin modifier turns each loose edge into a tube. The
        # object is scaled by the stick length (mm), so the radius is in units of length.
        length = o.matrix_world.to_scale()[0] * 1000.0
        o.modifiers.new("tube", "SKIN")
        for sv in o.data.skin_vertices[0].data:
            sv.radius = (0.32 / length, 0.32 / length)
        o.data.materials.append(stick_mat)

    bpy.context.view_layer.update()
    pts = [o.matrix_world.translation for o in point_objs]
    lo = Vector([min(p[k] for p in pts) for k in range(3)])
    hi = Vector([max(p[k] for p in pts) for k in range(3)])
    centre = (lo + hi) / 2
    # The face looks down -Y (brim frame): view it from the front, a little from its left
    # and above so its depth shows.
    cam_data = bpy.data.cameras.new("render_cam")
    cam_data.lens = 70.0
    cam = bpy.data.objects.new("render_cam", cam_data)
    scene.collection.objects.link(cam)
    direction = Vector((0.3, -1.0, 0.12)).normalized()
    cam.location = centre + direction * 0.62
    cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.9, 0.2, -0.5)
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.16, 0.17, 0.2, 1)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 1.0
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 48
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = 1200, 900
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 90
    scene.render.filepath = png
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    try:
        import bpy  # noqa: F401
    except ImportError:
        sys.exit(main())
    else:
        _blender_main(sys.argv[sys.argv.index("--") + 1])
