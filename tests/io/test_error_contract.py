"""The error contract of readers and writers: one error type naming the file, no hangs,
no debris, bounded memory, linear time, and projects that survive their file changing."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from carapost.io.atomic import atomic_write_bytes, clean_stale_parts
from carapost.io.cara import load_project, save_project
from carapost.io.errors import CaraFileError
from carapost.io.labels import write_label_file
from carapost.io.take_import import read_brim_csv
from tests.fuzz.damaged import damaged_files
from tests.fuzz.harness import REPO, _small_project
from tests.fuzz.worker import _readers

READERS = _readers()


@pytest.fixture(scope="module")
def damaged(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, Path]]:
    return damaged_files(tmp_path_factory.mktemp("damaged"))


def test_every_damaged_file_is_a_precise_cara_file_error(damaged) -> None:
    assert len(damaged) >= 25
    for name, (reader, path) in damaged.items():
        tracemalloc.start()
        with pytest.raises(CaraFileError) as info:
            READERS[reader](path)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert info.value.path == path, name
        assert not info.value.internal, (name, str(info.value))
        assert str(path) in str(info.value)
        # ZIP bombs and the C3D dimension overflow are refused before any allocation
        assert peak < 64 << 20, (name, peak)


def test_zip_bombs_say_why(damaged) -> None:
    for name, pattern in (("cara_manifest_bomb", "claims 2,147,483,648 bytes"),
                          ("cara_array_bomb", "ZIP bomb"),
                          ("cara_array_encrypted", "encrypted"),
                          ("cara_manifest_method_99", "method 99"),
                          ("cara_nested_manifest", "nested")):
        with pytest.raises(CaraFileError, match=pattern):
            load_project(damaged[name][1])


def test_a_deflated_project_still_opens(tmp_path: Path) -> None:
    import zipfile

    project = _small_project()
    src = save_project(project, tmp_path / "p.cara")
    re_zipped = tmp_path / "z.cara"
    with zipfile.ZipFile(src) as a, zipfile.ZipFile(re_zipped, "w", zipfile.ZIP_DEFLATED) as b:
        for info in a.infolist():
            b.writestr(info.filename, a.read(info.filename))
    back = load_project(re_zipped)
    np.testing.assert_array_equal(back.points.positions, project.points.positions)
    assert back.labels == project.labels


# --------------------------------------------------------------------------------------
# linear time (the timings are in benchmarks/error_contract.py)
# --------------------------------------------------------------------------------------
def test_large_brim_csv_and_svg_load(tmp_path: Path) -> None:
    from carapost.io.brim_svg import read_brim_svg

    csv = tmp_path / "brim.csv"
    csv.write_text("label,x,y,z\n" + "".join(f"B{i},{i},1,2\n" for i in range(80_000)))
    labels, xyz = read_brim_csv(csv)
    assert len(labels) == 80_000 and xyz[-1, 0] == 79_999
    circles = "".join(f'<g transform="translate({i},0)"><circle id="D{i}" cx="0" cy="1" r="1"/>'
                      f"</g>" for i in range(20_000))
    svg = tmp_path / "brim.svg"
    svg.write_text(f'<svg xmlns="http://www.w3.org/2000/svg">{circles}</svg>')
    labels, xyz = read_brim_svg(svg)
    assert len(labels) == 20_000 and xyz[-1, 0] == pytest.approx(19_999 * 25.4 / 96)
    dup = tmp_path / "dup.svg"
    dup.write_text('<svg xmlns="http://www.w3.org/2000/svg">'
                   + '<circle id="A" r="1"/>' * 20_000 + "</svg>")
    with pytest.raises(CaraFileError, match="repeat: A$"):
        read_brim_svg(dup)


# --------------------------------------------------------------------------------------
# saves: path problems, symbolic links, long names, temporary files
# --------------------------------------------------------------------------------------
def _writers(project):
    from carapost.export import export_c3d, export_fbx, export_xcp

    return {
        "cara": lambda p: save_project(project, p),
        "c3d": lambda p: export_c3d(project, p),
        "fbx": lambda p: export_fbx(project, p),
        "xcp": lambda p: export_xcp(project, p),
        "labels": lambda p: write_label_file(p, ["A", "B"]),
    }


@pytest.mark.parametrize("problem", ["empty", "nul", "too_long", "folder", "no_folder"])
def test_every_writer_refuses_bad_paths_with_the_path(tmp_path: Path, problem: str) -> None:
    project = _small_project()
    (tmp_path / "folder.cara").mkdir()
    path = {"empty": "", "nul": str(tmp_path / "a\0b.cara"),
            "too_long": str(tmp_path / ("x" * 300 + ".cara")),
            "folder": str(tmp_path / "folder.cara"),
            "no_folder": str(tmp_path / "missing" / "p.cara")}[problem]
    for kind, write in _writers(project).items():
        with pytest.raises(CaraFileError) as info:
            write(path)
        shown = str(info.value)
        assert (path.replace("\0", "\\0")[:40] in shown) if path else "empty" in shown, kind
        assert sorted(os.listdir(tmp_path)) == ["folder.cara"], kind  # nothing written
    assert not (tmp_path / "folder.cara.cara").exists()


def test_saving_onto_a_symlink_writes_its_target(tmp_path: Path) -> None:
    project = _small_project()
    real = tmp_path / "real" / "take.cara"
    real.parent.mkdir()
    save_project(project, real)
    link = tmp_path / "link.cara"
    link.symlink_to(real)
    project.labels = ["Changed"]
    save_project(project, link)
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert load_project(real).labels == ["Changed"]
    assert not [n for n in os.listdir(real.parent) if n.endswith(".part")]


@pytest.mark.parametrize("length", [237, 250, 255])
def test_names_up_to_the_file_system_limit_save(tmp_path: Path, length: int) -> None:
    project = _small_project()
    path = tmp_path / ("n" * (length - 5) + ".cara")
    assert len(path.name) == length
    save_project(project, path)
    assert load_project(path).labels == project.labels
    assert os.listdir(tmp_path) == [path.name]


def test_only_our_dead_temporary_files_are_cleaned(tmp_path: Path) -> None:
    target = tmp_path / "take.cara"
    save_project(_small_project(), target)
    dead = tmp_path / ".take.cara.0123456789ab.part"
    dead.write_bytes(b"x" * 100)
    foreign = [tmp_path / ".take.cara.mine.part", tmp_path / "take.cara.part",
               tmp_path / ".other.cara.0123456789ab.part"]
    for f in foreign:
        f.write_bytes(b"y")
    # a live writer (another process) holds its file locked: never touched
    live = tmp_path / ".take.cara.abcdefabcdef.part"
    live.write_bytes(b"z")
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import fcntl, os, sys, time
            fd = os.open({str(live)!r}, os.O_RDWR)
            fcntl.flock(fd, fcntl.LOCK_EX)
            print("locked", flush=True)
            time.sleep(60)
        """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        load_project(target)  # opening cleans up
        assert not dead.exists()
        assert live.exists() and all(f.exists() for f in foreign)
        dead.write_bytes(b"x")
        save_project(_small_project(), target)  # so does saving
        assert not dead.exists() and live.exists()
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    assert clean_stale_parts(target) == [live]  # its writer died


def test_a_full_disk_leaves_no_debris_and_names_the_path(tmp_path: Path) -> None:
    target = tmp_path / "take.cara"
    save_project(_small_project(), target)
    original = target.read_bytes()
    # RLIMIT_FSIZE makes every write past 1 kB fail with EFBIG, as a full disk would
    code = textwrap.dedent(f"""
        import resource, signal, sys
        sys.path[:0] = [{str(REPO)!r}, {str(REPO / "src")!r}]
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        from tests.fuzz.harness import _small_project
        from carapost.io.cara import save_project
        from carapost.io.errors import CaraFileError
        from carapost.export import export_c3d
        project = _small_project()
        resource.setrlimit(resource.RLIMIT_FSIZE, (1_024, 1_024))
        for write in (lambda: save_project(project, {str(target)!r}),
                      lambda: export_c3d(project, {str(tmp_path / "x.c3d")!r})):
            try:
                write()
                print("written")
            except CaraFileError as exc:
                print("refused", exc)
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    lines = out.stdout.splitlines()
    assert len(lines) == 2 and all(line.startswith("refused") for line in lines), out
    assert str(target) in lines[0] and "File too large" in lines[0]
    assert target.read_bytes() == original
    assert os.listdir(tmp_path) == ["take.cara"]


def test_atomic_write_removes_its_temporary_file_on_any_failure(tmp_path: Path) -> None:
    from carapost.io.atomic import atomic_output

    with pytest.raises(KeyError), atomic_output(tmp_path / "f.bin") as fh:
        fh.write(b"partial")
        raise KeyError("interrupted")
    assert os.listdir(tmp_path) == []
    atomic_write_bytes(tmp_path / "f.bin", b"ok")
    assert os.listdir(tmp_path) == ["f.bin"]


# --------------------------------------------------------------------------------------
# an open project survives its file being truncated or overwritten
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("change", ["truncate", "overwrite", "delete"])
def test_open_project_survives_its_file_changing(tmp_path: Path, change: str) -> None:
    path = tmp_path / "take.cara"
    save_project(_small_project(), path)
    code = textwrap.dedent(f"""
        import os, sys
        sys.path[:0] = [{str(REPO)!r}, {str(REPO / "src")!r}]
        import numpy as np
        from carapost.io.autosave import autosave_project
        from carapost.io.cara import load_project, save_project
        path = {str(path)!r}
        project = load_project(path)
        before = {{k: a.copy() for k, a in project.points.arrays.items()}}
        size = os.path.getsize(path)
        if {change!r} == "truncate":
            os.truncate(path, 100)
        elif {change!r} == "overwrite":
            with open(path, "r+b") as fh:
                fh.write(os.urandom(size))
        else:
            os.unlink(path)
        for k, a in project.points.arrays.items():
            assert np.array_equal(a, before[k], equal_nan=True), k
        for a in project.detections.arrays.values():
            a.sum()
        project.calibration.R.sum()
        autosave_project(project)
        save_project(project, path)
        back = load_project(path)
        assert np.array_equal(back.points.positions, before["positions"], equal_nan=True)
        print("intact")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "intact", out


def test_a_mapped_project_refuses_to_save_from_a_changed_file(tmp_path: Path) -> None:
    path = tmp_path / "take.cara"
    save_project(_small_project(), path)
    project = load_project(path, private=False)  # as projects over the copy limit are
    save_project(project, path)  # our own save replaces the file: the mapping stays valid
    save_project(project, tmp_path / "other.cara")  # Save As: the file stays guarded
    project = load_project(path, private=False)
    with open(path, "r+b") as fh:  # another program rewrites it in place
        fh.write(b"\0" * 64)
    with pytest.raises(CaraFileError, match="changed or removed by another program") as info:
        save_project(project, tmp_path / "copy.cara")
    assert info.value.path == path
    assert not (tmp_path / "copy.cara").exists()


# --------------------------------------------------------------------------------------
# kill -9 during saves (slow set)
# --------------------------------------------------------------------------------------
@pytest.mark.slow
def test_kill_9_during_saves_keeps_the_original_and_leaves_no_debris(tmp_path: Path) -> None:
    import random

    path = tmp_path / "take.cara"
    code = textwrap.dedent(f"""
        import sys, time
        sys.path[:0] = [{str(REPO)!r}, {str(REPO / "src")!r}]
        import numpy as np
        from carapost.io.cara import save_project
        from carapost.model.project import new_project
        project = new_project(12000, 4)
        project.points.append(200)
        project.points.positions[:] = float(sys.argv[1])
        project.points.obs[:] = 2.5
        project.labels = [sys.argv[2]]
        if sys.argv[2] == "original":
            save_project(project, {str(path)!r})
            sys.exit(0)
        print("saving", flush=True)
        t0 = time.perf_counter()
        save_project(project, {str(path)!r})
        print("saved", time.perf_counter() - t0, flush=True)
    """)
    subprocess.run([sys.executable, "-c", code, "1.5", "original"], check=True, timeout=300)
    original = path.read_bytes()
    assert len(original) > 150 << 20
    rng = random.Random(7)
    save_s, interrupted = 1.0, 0
    for k in range(20):
        proc = subprocess.Popen([sys.executable, "-c", code, str(k), f"new{k}"],
                                stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "saving"
        time.sleep(rng.uniform(0.0, 1.2 * save_s))
        proc.kill()
        proc.wait()
        rest = proc.stdout.read()
        proc.stdout.close()
        if rest.startswith("saved"):
            save_s = float(rest.split()[1])
        # either the original, bit-identical, or (the kill came after the rename) the
        # whole new project: never anything in between
        if path.read_bytes() == original:
            interrupted += 1
        else:
            back = load_project(path)
            assert back.labels == [f"new{k}"] and float(back.points.positions[0, 0, 0]) == k
            atomic_write_bytes(path, original)
        load_project(path)  # the next open removes what the killed save left
        assert os.listdir(tmp_path) == ["take.cara"]
    assert interrupted >= 10


# --------------------------------------------------------------------------------------
# recovery: a newer autosave is never silently ignored
# --------------------------------------------------------------------------------------
def _crashed(tmp_path: Path) -> Path:
    from carapost.io.autosave import autosave_project

    path = tmp_path / "take.cara"
    project = _small_project()
    save_project(project, path)
    project.labels = ["Recovered"]
    time.sleep(0.01)
    auto = autosave_project(project)
    os.utime(auto, (time.time() + 5, time.time() + 5))
    return path


def test_api_reports_a_newer_autosave(tmp_path: Path) -> None:
    from carapost import api
    from carapost.session.recovery import NewerAutosaveWarning

    path = _crashed(tmp_path)
    with pytest.warns(NewerAutosaveWarning, match="autosave"):
        project = api.open_project(path)
    assert project.labels == ["Nose_Tip", "Chin", "Brow_L"]
    assert project.newer_autosave == Path(str(path) + ".autosave")
    recovered = api.open_project(path, recover=True)
    assert recovered.labels == ["Recovered"] and recovered.path == str(path)
    assert api.open_project(path, recover=False).newer_autosave is None


def test_cli_reports_a_newer_autosave_and_takes_recover(tmp_path: Path) -> None:
    from carapost.cli import main

    path = _crashed(tmp_path)
    env_code = (f"import sys; sys.path[:0] = [{str(REPO / 'src')!r}]; "
                "from carapost.cli import main; sys.exit(main(sys.argv[1:]))")
    out = subprocess.run([sys.executable, "-c", env_code, "export-xcp", str(path),
                          str(tmp_path / "o.xcp")], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0
    assert "newer autosave" in out.stderr and "--recover" in out.stderr
    assert main(["export-xcp", "--recover", str(path), str(tmp_path / "r.xcp")]) == 0


def test_save_as_and_untitled_autosaves_are_moved(tmp_path: Path, monkeypatch) -> None:
    from carapost.io.autosave import autosave_path, autosave_project

    monkeypatch.setenv("CARAPOST_AUTOSAVE_DIR", str(tmp_path / "auto"))
    project = _small_project()
    untitled = autosave_project(project)  # never saved: autosaved all the same
    assert untitled is not None and untitled.parent == tmp_path / "auto"
    assert load_project(untitled).labels == project.labels
    first = save_project(project, tmp_path / "a.cara")
    assert not untitled.exists()
    autosave_project(project)
    assert autosave_path(first).exists()
    save_project(project, tmp_path / "b.cara")  # Save As
    assert not autosave_path(first).exists()


# --------------------------------------------------------------------------------------
# the command line: one line and exit 2 for every failure
# --------------------------------------------------------------------------------------
def test_cli_failures_are_one_line_exit_2(tmp_path: Path, damaged, capsys) -> None:
    from carapost.cli import main

    good = save_project(_small_project(), tmp_path / "good.cara")
    (tmp_path / "dir.c3d").mkdir()
    cases = [["export-c3d", str(damaged[n][1]), str(tmp_path / "o.c3d")]
             for n in damaged if damaged[n][0] == "cara_open"]
    cases += [["export-c3d", str(good), out] for out in
              ("", str(tmp_path / "a\0.c3d"), str(tmp_path / ("y" * 300 + ".c3d")),
               str(tmp_path / "dir.c3d"), str(tmp_path / "no" / "o.c3d"))]
    cases += [["export-xcp", str(tmp_path / "missing.cara"), str(tmp_path / "o.xcp")],
              ["export-fbx", str(tmp_path), str(tmp_path / "o.fbx")]]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith(f"carapost {argv[0]}: error: "), err
        assert "Traceback" not in err


def test_xcp_unknown_content_survives_import_save_reopen_export(tmp_path: Path) -> None:
    from carapost.commands import file as file_commands
    from carapost.commands.stack import CommandStack
    from carapost.export import export_xcp
    from carapost.io.xcp import write_xcp

    project = _small_project()
    src = tmp_path / "in.xcp"
    from carapost.io.xcp import XcpCalibration

    cal = project.calibration
    write_xcp(src, XcpCalibration.from_arrays(cal.intrinsics, cal.R[0], cal.t[0]))
    text = src.read_text()
    text = text.replace("<Cameras ", '<?vicon-tool keep="1"?>\n<!-- before the root -->\n'
                        '<Cameras SITE="lab 3" ', 1)
    text = text.replace("<KeyFrames>", '<!-- a camera note --><Lens MAKER="X">'
                        '<?lens-pi data?><Serial>42</Serial></Lens><KeyFrames>', 1)
    text = text.replace("</Cameras>", "<!-- the end --><Extra A='1'/></Cameras>")
    src.write_text(text)
    stack = CommandStack(project)
    stack.push(file_commands.ImportXcp(project, src))
    saved = save_project(project, tmp_path / "p.cara")
    reopened = load_project(saved)
    out = tmp_path / "out.xcp"
    export_xcp(reopened, out)
    written = out.read_text()
    for piece in ('<?vicon-tool keep="1"?>', "<!-- before the root -->", 'SITE="lab 3"',
                  "<!-- a camera note -->", '<Lens MAKER="X">', "<?lens-pi data?>",
                  "<Serial>42</Serial>", "<!-- the end -->", '<Extra A="1"/>'):
        assert piece in written, piece
    assert json.loads(json.dumps(reopened.calibration.xcp_extras)) == \
        project.calibration.xcp_extras


def test_a_fifo_given_as_any_file_is_refused_not_waited_on(tmp_path: Path) -> None:
    from tests.fuzz.harness import Worker

    worker = Worker(timeout=10.0)
    try:
        for reader, name in (("cara_open", "p.cara"), ("cara_labels", "l.cara"),
                             ("label_file", "l.txt"), ("brim_csv", "b.csv"),
                             ("brim_svg", "b.svg"), ("xcp", "t.xcp"), ("take_json", "t.json"),
                             ("c3d", "p.c3d"), ("video", "take_cam0.mkv")):
            fifo = tmp_path / name
            os.mkfifo(fifo)
            res = worker.run(reader, fifo)
            assert res["status"] == "documented", (reader, res)
            assert "not a regular file" in res["message"], (reader, res)
    finally:
        worker.stop()


def test_no_permission_is_a_cara_file_error_with_the_path(tmp_path: Path, monkeypatch) -> None:
    import errno

    import carapost.io.atomic as atomic

    folder = tmp_path / "locked"
    folder.mkdir()
    if os.geteuid() != 0:
        folder.chmod(0o555)
    else:  # root writes anywhere: make the folder refuse new files as it would for a user
        real_open = os.open

        def refuse(path, flags, *args):
            if str(path).startswith(str(folder)) and flags & os.O_CREAT:
                raise PermissionError(errno.EACCES, "Permission denied", str(path))
            return real_open(path, flags, *args)

        monkeypatch.setattr(atomic.os, "open", refuse)
    try:
        for kind, write in _writers(_small_project()).items():
            target = folder / f"out.{kind if kind != 'labels' else 'txt'}"
            with pytest.raises(CaraFileError, match="Permission denied") as info:
                write(target)
            assert str(target) in str(info.value), kind
        assert os.listdir(folder) == []
    finally:
        folder.chmod(0o755)
