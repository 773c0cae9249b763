"""``carapost batch`` / `carapost.batch.run` on small synthetic takes and a 2-worker
LocalCluster: failure isolation, the report, resuming, --force, a worker that dies, and
bad input refused before any work."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np
import pytest

from carapost.batch import (
    MANIFEST_NAME,
    REPORT_FIELDS,
    BatchError,
    BatchSettings,
    discover_takes,
    plan,
    process_one,
    read_manifest,
    run,
)
from carapost.batch_cluster import LOCAL_CLUSTER_CONFIG
from carapost.cli import main
from tests.small_takes import copy_take, render_take


@pytest.fixture(scope="module")
def source_take(tmp_path_factory) -> Path:
    return render_take(tmp_path_factory.mktemp("source") / "Take00", frames=6)


@pytest.fixture(scope="module")
def shoot(tmp_path_factory, source_take) -> Path:
    """8 takes in nested folders; Take05's camera 2 video is garbage."""
    root = tmp_path_factory.mktemp("shoot")
    for i in range(8):
        day = root / ("day1" if i < 4 else "day2/late")
        copy_take(source_take, day / f"Take{i:02d}", f"Take{i:02d}")
    bad = root / "day2/late/Take05/Take05_cam2.mkv"
    bad.write_bytes(b"not a video" * 100)
    return root


@pytest.fixture(scope="module")
def client():
    """One 2-worker LocalCluster, set up as `run` sets up its own, for the module."""
    global _FORK_SERVER_IS_OURS
    from carapost.batch import local_cluster, start_fork_server

    _FORK_SERVER_IS_OURS = start_fork_server()
    with local_cluster(2) as client:
        client.wait_for_workers(2, timeout=120)
        yield client


def _worker_state() -> dict:
    import sys

    import dask
    import numba

    from carapost.batch_cluster import WORKER_PRELOAD

    return {"pipeline": all(m in sys.modules for m in WORKER_PRELOAD),
            "threads": (os.environ.get("OMP_NUM_THREADS"),
                        os.environ.get("OPENBLAS_NUM_THREADS"),
                        numba.config.NUMBA_NUM_THREADS),
            "config": {k: dask.config.get(k) for k in LOCAL_CLUSTER_CONFIG}}


def test_workers_start_with_the_pipeline_imported_and_one_thread_each(client):
    state = client.run(_worker_state)
    assert len(state) == 2
    for s in state.values():
        assert s["threads"][:2] == ("1", "1")
        # forked from the fork server that imported the take's modules once, with one
        # numba thread (unless a detector pool of an earlier test started the program's
        # fork server first: then numba keeps its own count; no kernel is parallel)
        assert (s["pipeline"] and s["threads"][2] == 1) or not _FORK_SERVER_IS_OURS
        # no profiler sampling the take's stack, slow monitors: the settings reached the
        # worker processes, not only the scheduler's
        assert s["config"] == LOCAL_CLUSTER_CONFIG


def _profiler_running(dask_worker) -> bool:
    return any(pc.is_running() for name, pc in dask_worker.periodic_callbacks.items()
               if "profile" in name)


def test_workers_keep_no_profiler_running(client):
    assert set(client.run(_profiler_running).values()) == {False}


_FORK_SERVER_IS_OURS = False


def _mtimes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in folder.glob("*.cara")}


def test_batch_isolates_failures_reports_resumes_and_forces(shoot, client, tmp_path,
                                                           capsys):
    out = tmp_path / "out"
    states = []
    rep = run([shoot], out, client, progress=states.append)
    s = rep["summary"]
    assert (s["total"], s["done"], s["failed"], s["skipped"]) == (8, 7, 1, 0)
    rows = {Path(r["take"]).stem: r for r in rep["takes"]}
    assert rows["Take05"]["status"] == "failed"
    assert "Take05_cam2.mkv" in rows["Take05"]["error"]
    assert not (out / "Take05.cara").exists()
    assert rep["workers"] == 2
    # every processed take: its project on disk holds what the report says
    from carapost.io.cara import load_project
    from carapost.model.project import KIND_FACE

    for name, row in rows.items():
        if name == "Take05":
            continue
        assert row["status"] == "done" and row["error"] == "" and row["attempts"] == 1
        project = load_project(out / f"{name}.cara")
        face = project.points.kind == KIND_FACE
        has = np.isfinite(project.points.positions[:, face, 0])
        assert row["points"] == int(face.sum()) > 20
        assert row["frames"] == project.n_frames == 6
        assert row["tracked_fraction"] == pytest.approx(has.mean(), abs=1e-6)
        assert row["tracked_fraction"] > 0.8
        assert 0 < row["mean_residual"] < 1.0  # mm, noise-level reprojection
        assert row["project"] == str(out / f"{name}.cara")
        assert row["seconds"] > 0 and 0 < row["cpu_seconds"] < 10 * row["seconds"]
    # the report files: the JSON equals the returned report, the CSV has every row
    assert json.loads((out / "batch_report.json").read_text())["takes"] == rep["takes"]
    with open(out / "batch_report.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == REPORT_FIELDS and len(table) == 8
    assert {r["status"] for r in table} == {"done", "failed"}
    assert [r["take"] for r in table] == [r["take"] for r in rep["takes"]]
    # progress: once at the start, then after every take; the last one says all ended
    assert states[0]["done"] == 0 and len(states) == 9
    assert (states[-1]["done"], states[-1]["failed"], states[-1]["eta_s"]) == (7, 1, 0.0)
    assert len(read_manifest(out)) == 7
    assert not list(out.glob(".*.part"))

    # rerun: the 7 are skipped (same rows, 0 s), the failed take is tried again
    before = _mtimes(out)
    rep2 = run([shoot], out, client)
    assert {r["status"] for r in rep2["takes"] if "Take05" not in r["take"]} == {"skipped"}
    assert rep2["summary"]["failed"] == 1 and rep2["summary"]["skipped"] == 7
    assert _mtimes(out) == before
    skipped = [r for r in rep2["takes"] if r["status"] == "skipped"]
    assert all(r["points"] and r["project"] for r in skipped)

    # force redoes all of them
    rep3 = run([shoot], out, client, force=True)
    after = _mtimes(out)
    assert set(after) == set(before) and all(after[k] > before[k] for k in before)
    assert rep3["summary"]["done"] == 7 and rep3["summary"]["skipped"] == 0

    # the command line on the 4 takes of day1, all up to date: no cluster, exit 0
    assert main(["batch", str(shoot / "day1"), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert "0 done, 0 failed, 4 skipped of 4 takes" in captured.out
    assert "4/4 takes" in captured.err  # the progress line


def test_changed_input_or_settings_make_a_take_stale(shoot, tmp_path):
    """The manifest's hash covers each take's files and the settings (no cluster)."""
    tasks = plan([shoot / "day1"], tmp_path)
    again = plan([shoot / "day1"], tmp_path)
    assert [t.digest for t in tasks] == [t.digest for t in again]
    other = plan([shoot / "day1"], tmp_path, BatchSettings(c3d=True))
    assert all(a.digest != b.digest for a, b in zip(tasks, other, strict=True))
    stab = plan([shoot / "day1"], tmp_path, BatchSettings(stabilize="auto"))
    assert all(a.digest != b.digest for a, b in zip(tasks, stab, strict=True))
    assert other[0].outputs["c3d"] == tmp_path.absolute() / "Take00.c3d"
    video = shoot / "day1/Take01/Take01_cam0.mkv"
    st = video.stat()
    try:
        os.utime(video, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
        touched = plan([shoot / "day1"], tmp_path)
    finally:
        os.utime(video, ns=(st.st_atime_ns, st.st_mtime_ns))
    changed = [a.name for a, b in zip(tasks, touched, strict=True) if a.digest != b.digest]
    assert changed == ["Take01"]


def kill_worker_once(take: str, outputs: dict[str, str], settings: BatchSettings) -> dict:
    """A batch task whose first run kills its own worker process (as an out-of-memory
    kill would)."""
    marker = Path(outputs["project"]).with_suffix(".killed")
    if not marker.exists():
        marker.write_text("killed")
        os._exit(9)
    return process_one(take, outputs, settings)


def test_a_task_that_kills_its_worker_is_retried(shoot, tmp_path):
    """On the batch's own LocalCluster (the default path of ``carapost batch``): the
    worker is killed mid-task, started again, and the take is run again on it."""
    out = tmp_path / "out"
    rep = run([shoot / "day1/Take00"], out, workers=2, task=kill_worker_once)
    assert rep["summary"]["done"] == 1 and rep["workers"] == 1  # one take, one worker
    assert [r["attempts"] for r in rep["takes"]] == [2]
    assert (out / "Take00.cara").is_file() and (out / "Take00.killed").is_file()


def test_without_retries_a_dead_worker_fails_only_its_take(shoot, client, tmp_path):
    out = tmp_path / "out"
    (out).mkdir()
    (out / "Take01.killed").write_text("already")  # Take01 runs normally
    rep = run([shoot / "day1/Take00", shoot / "day1/Take01"], out, client, retries=0,
              task=kill_worker_once)
    rows = {Path(r["take"]).stem: r for r in rep["takes"]}
    assert rows["Take00"]["status"] == "failed"
    assert "worker running it died 1 time" in rows["Take00"]["error"]
    assert rows["Take01"]["status"] == "done"


def test_takes_are_submitted_longest_first(tmp_path):
    """The biggest takes start first (ties keep the input order), so that a long take
    does not end the batch alone on one worker."""
    from carapost.batch import TakeTask, _longest_first

    tasks = []
    for i, size in enumerate([10, 300, 10, 5000, 300]):
        f = tmp_path / f"T{i}_cam0.mkv"
        f.write_bytes(b"x" * size)
        tasks.append(TakeTask(take=f, name=f"T{i}", outputs={}, files=[f]))
    tasks.append(TakeTask(take=tmp_path / "gone", name="gone", outputs={},
                          files=[tmp_path / "gone_cam0.mkv"]))  # unreadable: last
    assert _longest_first(tasks, [0, 1, 2, 3, 4, 5]) == [3, 1, 4, 0, 2, 5]
    assert _longest_first(tasks, [2, 0]) == [2, 0]


def test_discovery_of_files_folders_and_wildcards(shoot):
    every = discover_takes([shoot])
    assert [p.stem for p in every] == [f"Take{i:02d}" for i in range(8)]
    # each camera file of one take is the same take; a wildcard over cameras finds it once
    one = discover_takes([str(shoot / "day1/Take02/*.mkv"),
                          shoot / "day1/Take02/Take02.xcp"])
    assert [p.name for p in one] == ["Take02.json"]
    late = discover_takes([str(shoot / "**/late/*/*.json")])
    assert [p.stem for p in late] == ["Take04", "Take05", "Take06", "Take07"]


@pytest.mark.parametrize("inputs, match", [
    (["nothing*.mkv"], "matches no file"),
    (["missing_folder"], "matches no file"),
    (["empty"], "holds no take"),
    (["notes.txt"], "not a camera file"),
])
def test_bad_inputs_are_refused_before_any_work(shoot, tmp_path, inputs, match):
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(BatchError, match=match):
        run([tmp_path / i if "*" not in i else str(tmp_path / i) for i in inputs],
            tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_bad_outdir_rom_and_scheduler_are_refused_before_any_work(shoot, tmp_path):
    take = shoot / "day1/Take00"
    (tmp_path / "file").write_text("x")
    with pytest.raises(BatchError, match="is a file"):
        run([take], tmp_path / "file")
    with pytest.raises(BatchError, match="does not exist"):
        run([take], tmp_path / "no/such/out")
    with pytest.raises(BatchError, match="cannot create the output folder"):
        run([take], "/proc/carapost-batch-out")  # unwritable even for root
    with pytest.raises(BatchError, match="ROM project not found"):
        run([take], tmp_path / "out", rom=tmp_path / "rom.cara")
    with pytest.raises(BatchError, match="no Dask scheduler answers"):
        run([take], tmp_path / "out", scheduler="tcp://127.0.0.1:9", connect_timeout=1)
    with pytest.raises(BatchError, match="retries must be >= 0"):
        run([take], tmp_path / "out", retries=-1)
    with pytest.raises(BatchError, match="stabilize must be"):
        run([take], tmp_path / "out", stabilize="sideways")
    assert not (tmp_path / "out").exists() and not list(shoot.rglob("*.cara"))
    # the same take twice under one name would overwrite itself: refused
    copy_take(take / "Take00.json", tmp_path / "dup", "Take00")
    with pytest.raises(BatchError, match="take names must be unique"):
        run([take, tmp_path / "dup"], tmp_path / "out")


def test_a_second_batch_into_the_same_outdir_is_refused(shoot, tmp_path, monkeypatch):
    """Two batches writing one OUTDIR would interleave their manifests: the second is
    refused in one line naming the first's process, before any work; once the first
    ends, the folder is free again."""
    import subprocess
    import sys

    import carapost.batch as batch

    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, carapost.batch as b; from pathlib import Path; "
         "fd = b._lock_outdir(Path(sys.argv[1])); print('held', flush=True); "
         "sys.stdin.read()", str(out)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        monkeypatch.setattr(batch, "_local_cluster", None)  # would raise if called
        with pytest.raises(BatchError, match=f"another batch \\(process {holder.pid}\\)"):
            run([shoot / "day1/Take03"], out)
        assert sorted(p.name for p in out.iterdir()) == [".batch.lock"]
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
        holder.stdout.close()
    fd = batch._lock_outdir(out)  # free again
    os.close(fd)


def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["batch", str(tmp_path / "nope*"), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("carapost batch: error:")
    assert "matches no file" in err[0]


def test_an_up_to_date_batch_starts_no_cluster(shoot, tmp_path, monkeypatch):
    """Manifest written by hand as a finished run would: nothing to do, no cluster."""
    import carapost.batch as batch

    out = tmp_path / "out"
    out.mkdir()
    tasks = plan([shoot / "day1/Take03"], out)
    t = tasks[0]
    t.outputs["project"].write_bytes(b"")  # newer than the inputs
    (out / MANIFEST_NAME).write_text(json.dumps({"takes": {t.key(out.absolute()): {
        "digest": t.digest, "row": {"take": str(t.take), "points": 31}}}}))
    monkeypatch.setattr(batch, "_local_cluster", None)  # would raise if called
    rep = run([shoot / "day1/Take03"], out)
    assert rep["takes"][0]["status"] == "skipped" and rep["takes"][0]["points"] == 31


def test_module_examples():
    import doctest

    import carapost.batch

    assert doctest.testmod(carapost.batch).failed == 0


@pytest.mark.slow
def test_ctrl_c_keeps_finished_takes_and_leaves_nothing_half_written(shoot, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "carapost.cli", "batch", str(shoot / "day1"),
                             "-o", str(out), "--workers", "1"], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    start = time.monotonic()
    while not (out / MANIFEST_NAME).exists() and time.monotonic() - start < 300:
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=120)
    assert proc.returncode == 130, text
    rep = json.loads((out / "batch_report.json").read_text())
    statuses = [r["status"] for r in rep["takes"]]
    assert statuses.count("done") >= 1 and "cancelled" in statuses
    done = {Path(r["project"]).name for r in rep["takes"] if r["status"] == "done"}
    assert set(read_manifest(out)) == done
    assert not list(out.glob(".*.part"))  # no temporary file of a killed writer
    from carapost.io.cara import load_project

    for name in (p.name for p in out.glob("*.cara")):
        load_project(out / name)  # every project there is whole
    # the next run does the rest
    rep2 = run([shoot / "day1"], out, workers=2)
    assert rep2["summary"]["skipped"] == len(done)
    assert rep2["summary"]["done"] == 4 - len(done)


def test_a_running_scheduler_by_address(shoot, client, tmp_path):
    """--scheduler ADDRESS: the batch connects to a running cluster and leaves it up."""
    address = client.scheduler.address
    rep = run([shoot / "day1/Take02"], tmp_path / "out", scheduler=address)
    assert rep["summary"]["done"] == 1 and rep["workers"] == 2
    assert client.submit(sum, [1, 2]).result() == 3  # still running


def _in_fresh_python(code: str, *args: str) -> dict:
    """Run ``code`` in a new interpreter (this tree's package); its last stdout line,
    parsed as JSON."""
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(Path(__file__).resolve().parents[1] / "src"), os.environ.get("PYTHONPATH", "")])}
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True,
                         text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_a_take_imports_no_library_its_workers_fork_server_has_not(source_take, tmp_path):
    """Every scipy module a default take uses is imported once by the fork server the
    workers are forked from (`WORKER_PRELOAD`), and none it does not use: scipy.signal
    and scipy.stats (with the scipy.integrate and scipy.interpolate they import) cost
    0.3-0.5 s of CPU on the start-up's critical path and no stage needs them."""
    code = (
        "import importlib, json, sys\n"
        "from carapost.batch_cluster import WORKER_PRELOAD\n"
        "for m in WORKER_PRELOAD: importlib.import_module(m)\n"
        "from carapost.batch import BatchSettings, process_one\n"
        "before = set(sys.modules)\n"
        "row = process_one(sys.argv[1], {'project': sys.argv[2]}, BatchSettings())\n"
        # (numba fills its typing registries on a process's first kernel call, PyAV
        # its subtitle types on the first open: parts of libraries already imported)
        "libs = {'scipy', 'numpy', 'cv2', 'lxml', 'dask', 'distributed', 'threadpoolctl'}\n"
        "new = sorted(m for m in set(sys.modules) - before if m.split('.')[0] in libs)\n"
        "print(json.dumps({'status': row['status'], 'error': row['error'], 'new': new,\n"
        "                  'signal': 'scipy.signal' in sys.modules,\n"
        "                  'stats': 'scipy.stats' in sys.modules}))\n")
    got = _in_fresh_python(code, str(source_take), str(tmp_path / "t.cara"))
    assert got["status"] == "done", got["error"]
    assert got["new"] == []
    assert not got["signal"] and not got["stats"]


def test_bad_input_or_nothing_to_do_leaves_no_fork_server(source_take, tmp_path):
    """`run` starts the workers' fork server before it plans (its imports overlap the
    planning), and stops it at once when the plan refuses the input or every take is
    up to date: no process goes on importing after the error or the report."""
    code = (
        "import json, sys, time\n"
        "from multiprocessing import forkserver\n"
        "from carapost.batch import BatchError, run\n"
        "t = time.perf_counter()\n"
        "try:\n"
        "    run([sys.argv[1] + '/nothing*.mkv'], sys.argv[1] + '/out')\n"
        "except BatchError as exc:\n"
        "    error = str(exc)\n"
        "after_error = forkserver._forkserver._forkserver_pid\n"
        "print(json.dumps({'error': error, 'pid': after_error,\n"
        "                  'out': __import__('os').path.exists(sys.argv[1] + '/out')}))\n")
    got = _in_fresh_python(code, str(tmp_path))
    assert "matches no file" in got["error"]
    assert got["pid"] is None and not got["out"]
    # a rerun with every take up to date (in a new program): the report, no cluster, no
    # fork server left
    out = tmp_path / "done"
    code = (
        "import json, sys\n"
        "from multiprocessing import forkserver\n"
        "import carapost.batch as batch\n"
        "if len(sys.argv) > 3:\n"
        "    batch._local_cluster = None  # would raise if a cluster were started\n"
        "rep = batch.run([sys.argv[1]], sys.argv[2], workers=1)\n"
        "print(json.dumps({'summary': rep['summary'],\n"
        "                  'pid': forkserver._forkserver._forkserver_pid}))\n")
    got = _in_fresh_python(code, str(source_take), str(out))
    assert got["summary"]["done"] == 1 and got["pid"] is not None  # the batch's own
    got = _in_fresh_python(code, str(source_take), str(out), "rerun")
    assert (got["summary"]["skipped"], got["pid"]) == (1, None)
    # an error after planning and before any worker (here: reading the manifest) also
    # stops it
    code = (
        "import json, sys\n"
        "from multiprocessing import forkserver\n"
        "import carapost.batch as batch\n"
        "def broken(outdir):\n"
        "    raise RuntimeError('manifest reader broke')\n"
        "batch.read_manifest = broken\n"
        "try:\n"
        "    batch.run([sys.argv[1]], sys.argv[2], workers=1)\n"
        "except RuntimeError as exc:\n"
        "    error = str(exc)\n"
        "print(json.dumps({'error': error, 'pid': forkserver._forkserver._forkserver_pid}))\n")
    got = _in_fresh_python(code, str(source_take), str(tmp_path / "broken"))
    assert got == {"error": "manifest reader broke", "pid": None}
