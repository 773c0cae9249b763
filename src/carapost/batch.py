"""Batch processing of many takes on Dask: ``carapost batch INPUTS... -o OUTDIR``.

Every take found in the inputs (take files, folders searched recursively, wildcards) is
one task that runs the headless pipeline (`carapost.pipeline.process_take`) on a Dask
worker and writes ``OUTDIR/<take>.cara`` (and ``.c3d``/``.fbx`` when asked). By default
the tasks run on an in-process ``LocalCluster`` with one single-threaded worker process
per core (on Linux forked from a fork server that has imported the pipeline once);
``scheduler="tcp://host:8786"`` (or a ``dask.distributed.Client``) uses an existing
cluster, whose workers need the package and read access to the take paths and write
access to OUTDIR.

- A take that fails is reported with its error; the others go on.
- A worker that dies mid-task has its task run again (``retries`` times) on a worker
  that is alive.
- ``OUTDIR/batch_manifest.json`` records, per take, a hash of its input files (names,
  sizes, modification times) and of the settings: a take whose record matches and whose
  outputs exist and are newer than its inputs is skipped unless ``force``.
- Every output file is written atomically and a take enters the manifest only once all
  of its outputs are written, so an interrupted batch (Ctrl+C) keeps the finished takes
  and leaves nothing half-written; the next run does the rest.
- ``OUTDIR/.batch.lock`` (an exclusive ``flock``, released when the batch ends, also
  when it is killed) keeps a second batch from writing the same OUTDIR at the same time:
  it is refused before any work, naming the first one's process.
- ``OUTDIR/batch_report.json`` and ``batch_report.csv``: one row per take (status,
  error, seconds, points, tracked fraction, mean residual, outputs).

Examples
--------
>>> from carapost.batch import BatchSettings
>>> BatchSettings(c3d=True).output_suffixes()
('.cara', '.c3d')
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import json
import logging
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from carapost import __version__
from carapost.batch_cluster import (
    WORKER_PRELOAD,
    WORKER_THREADS_ENV,
    _close,
    _local_cluster,
    local_cluster,
    start_fork_server,
    stop_fork_server,
    wait_for_first_worker,
)
from carapost.io.atomic import atomic_output
from carapost.io.errors import CaraFileError
from carapost.progress import format_progress, terminal_progress

log = logging.getLogger("carapost.batch")

__all__ = [
    "MANIFEST_NAME",
    "REPORT_FIELDS",
    "WORKER_PRELOAD",
    "WORKER_THREADS_ENV",
    "BatchError",
    "BatchSettings",
    "TakeTask",
    "discover_takes",
    "format_progress",
    "local_cluster",
    "plan",
    "process_one",
    "run",
    "start_fork_server",
    "terminal_progress",
]

#: The manifest of finished takes, in OUTDIR.
MANIFEST_NAME = "batch_manifest.json"
#: The columns of ``batch_report.csv`` (and the keys of each take in the JSON report).
REPORT_FIELDS = ("take", "status", "error", "seconds", "cpu_seconds", "frames", "points",
                 "tracked_fraction", "mean_residual", "attempts", "project", "c3d", "fbx")

_WILDCARD = frozenset("*?[")


class BatchError(ValueError):
    """Bad batch input found before any work: nothing matched, OUTDIR not writable, no
    scheduler at the address, a missing ROM or brim file."""


@dataclass(frozen=True)
class BatchSettings:
    """What every take of a batch is processed with (part of each take's hash).

    Attributes
    ----------
    rom : str or None
        ROM ``.cara`` project every take is initialised from.
    brim : str or None
        Brim model (``.csv`` or ``.svg``) for every take.
    c3d, fbx : bool
        Also export ``<take>.c3d`` / ``<take>.fbx`` (face points, every frame).
    patch_tracking : bool
        Patch track point-cameras without a blob (see `carapost.pipeline.process_take`).
    stabilize : {"auto", "assisted"} or None
        Stabilise every tracked take; its exports are then stabilised coordinates.
    """

    rom: str | None = None
    brim: str | None = None
    c3d: bool = False
    fbx: bool = False
    patch_tracking: bool = False
    stabilize: str | None = None

    def output_suffixes(self) -> tuple[str, ...]:
        """The extensions each take writes, project first."""
        return (".cara",) + ((".c3d",) if self.c3d else ()) + ((".fbx",) if self.fbx else ())


@dataclass
class TakeTask:
    """One take of a batch: where it is, what it writes, and its hash."""

    take: Path
    name: str
    outputs: dict[str, Path]
    files: list[Path] = field(default_factory=list)
    digest: str = ""

    def key(self, outdir: Path) -> str:
        """The take's name in the manifest: its project file, relative to OUTDIR."""
        return self.outputs["project"].relative_to(outdir).as_posix()


# ======================================================================================
# finding takes
# ======================================================================================
def _take_in_folder(folder: Path) -> dict[str, Path]:
    """take name -> one file of that take, for the takes directly in ``folder``."""
    from carapost.io.take_import import VIDEO_EXTENSIONS
    from carapost.io.video import image_sequence_files

    found: dict[str, Path] = {}
    try:
        entries = sorted(folder.iterdir())
    except OSError:
        return found
    for entry in entries:
        if entry.name.startswith("."):  # hidden, and a writer's partial files
            continue
        if entry.is_file() and entry.suffix.lower() in VIDEO_EXTENSIONS:
            stem = entry.stem
        elif entry.is_dir() and image_sequence_files(entry):
            stem = entry.name
        else:
            continue
        take, sep, channel = stem.rpartition("_")
        if not sep or not take or not channel:
            continue
        json_file = folder / f"{take}.json"
        found.setdefault(take, json_file if json_file.is_file() else entry)
    return found


def _takes_under(root: Path) -> list[Path]:
    """One file per take in ``root`` and every folder below it (hidden ones skipped)."""
    out: list[Path] = []
    for dirpath, dirnames, _ in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        out.extend(_take_in_folder(Path(dirpath)).values())
    return out


def discover_takes(inputs: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """The takes named by ``inputs``: one path per take, in input order, no repeats.

    Parameters
    ----------
    inputs : iterable of str or PathLike
        Take files (a camera file, ``<take>.json`` or ``.xcp``), folders (searched
        recursively for takes) or wildcards (``shoot/ROM*.mkv``, ``shoot/**/*.json``).

    Raises
    ------
    BatchError
        An input that matches no take (the message names it).
    """
    from carapost.io.take_import import find_take_files

    seen: set[tuple[Path, str]] = set()
    takes: list[Path] = []
    for raw in inputs:
        text = os.fspath(raw)
        wildcard = bool(_WILDCARD & set(text))
        if wildcard:
            matches = [Path(m) for m in sorted(glob.glob(text, recursive=True))]
        else:
            matches = [Path(text)] if Path(text).exists() else []
        found = 0
        for m in matches:
            folder = m.is_dir() and not _is_take_file(m)
            for c in _takes_under(m) if folder else [m]:
                try:
                    files = find_take_files(c)
                except CaraFileError as exc:
                    if not wildcard and not folder:  # a file named on its own: say why
                        raise BatchError(str(exc)) from None
                    continue  # a wildcard also matches files that are not takes
                found += 1
                ident = (files.folder, files.name)
                if ident not in seen:
                    seen.add(ident)
                    takes.append(files.json or c)
        if not found:
            what = "matches no file" if not matches else "holds no take"
            raise BatchError(f"{text}: {what} (give take files, folders of takes or "
                             "wildcards)")
    return takes


def _is_take_file(path: Path) -> bool:
    """An image-sequence folder is a camera of a take, not a folder of takes."""
    from carapost.io.video import image_sequence_files

    return path.is_dir() and bool(image_sequence_files(path)) and "_" in path.name


# ======================================================================================
# hashes, the manifest and the plan
# ======================================================================================
def _stat_entries(path: Path) -> list[tuple[str, int, int]]:
    if path.is_dir():
        return [(str(p), p.stat().st_size, p.stat().st_mtime_ns)
                for p in sorted(path.iterdir()) if p.is_file()]
    st = path.stat()
    return [(str(path), st.st_size, st.st_mtime_ns)]


def _settings_record(settings: BatchSettings) -> dict[str, Any]:
    rec: dict[str, Any] = asdict(settings)
    for key in ("rom", "brim"):  # a changed ROM or brim file redoes the takes
        if rec[key]:
            p = Path(rec[key]).absolute()
            rec[key] = _stat_entries(p)
    rec["carapost"] = __version__
    return rec


def take_digest(files: Sequence[Path], settings: BatchSettings) -> str:
    """SHA-256 of the take's files (names, sizes, modification times) and the settings.

    Contents are not read: a take's videos are gigabytes, and a file rewritten in place
    gets a new modification time.
    """
    h = hashlib.sha256()
    for f in sorted(files):
        h.update(json.dumps(_stat_entries(f)).encode())
    h.update(json.dumps(_settings_record(settings), sort_keys=True).encode())
    return h.hexdigest()


def _take_files(take: Path) -> tuple[str, list[Path]]:
    from carapost.io.take_import import find_take_files

    tf = find_take_files(take)
    files = [*tf.videos, *(p for p in (tf.json, tf.xcp, tf.labels, tf.brim_csv) if p)]
    return tf.name, files


def read_manifest(outdir: Path) -> dict[str, Any]:
    """The manifest of ``outdir`` (empty when there is none or it is unreadable)."""
    path = outdir / MANIFEST_NAME
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        log.warning("%s is unreadable (%s); every take is processed again", path, exc)
        return {}
    takes = data.get("takes") if isinstance(data, dict) else None
    return takes if isinstance(takes, dict) else {}


def _write_json(path: Path, data: Any) -> None:
    with atomic_output(path) as f:
        f.write(json.dumps(data, indent=1, allow_nan=False, default=str).encode())


def _is_current(task: TakeTask, entry: Any) -> bool:
    """The manifest entry is this take with these settings and its outputs are there,
    newer than every input."""
    if not isinstance(entry, dict) or entry.get("digest") != task.digest:
        return False
    try:
        newest_input = max((m for f in task.files for _, _, m in _stat_entries(f)),
                           default=0)
        return all(p.is_file() and p.stat().st_mtime_ns >= newest_input
                   for p in task.outputs.values())
    except OSError:
        return False


def plan(inputs: Iterable[str | os.PathLike[str]], out: str | os.PathLike[str],
         settings: BatchSettings | None = None) -> list[TakeTask]:
    """Find the takes and check everything before any work.

    Each take writes ``OUTDIR/<take>.cara`` (and ``.c3d``/``.fbx``), so take names
    must be unique within one batch (checked here: two takes of one name are refused
    rather than one overwriting the other).

    Raises
    ------
    BatchError
        No take matched, OUTDIR cannot be created or written, a missing ROM/brim file.
    CaraFileError
        A take file that exists but is not part of a take.
    """
    from carapost.pipeline import check_take_inputs

    settings = settings or BatchSettings()
    takes = discover_takes(inputs)
    outdir = _check_outdir(Path(out))
    # the ROM and brim are the same for every take: a bad one stops the batch here
    try:
        check_take_inputs(takes[0], output=outdir.parent / "check.cara", rom=settings.rom,
                          brim=settings.brim)
    except CaraFileError as exc:
        raise BatchError(str(exc)) from None
    named = [(t, *_take_files(t)) for t in takes]
    by_name: dict[str, list[tuple[str, Path]]] = {}
    for take, name, _ in named:  # case-insensitive: some file systems are
        by_name.setdefault(name.lower(), []).append((name, take))
    same = [both for both in by_name.values() if len(both) > 1]
    if same:
        raise BatchError(f"two takes would write {outdir / same[0][0][0]}.cara: "
                         + " and ".join(str(t) for _, t in same[0][:2])
                         + " (take names must be unique in one batch; process them into "
                         "different output folders)")
    tasks = [TakeTask(take=take, name=name, files=files,
                      outputs={k: outdir / f"{name}{suffix}"
                               for k, suffix in _output_kinds(settings)},
                      digest=take_digest(files, settings))
             for take, name, files in named]
    return tasks


def _output_kinds(settings: BatchSettings) -> list[tuple[str, str]]:
    kinds = [("project", ".cara")]
    if settings.c3d:
        kinds.append(("c3d", ".c3d"))
    if settings.fbx:
        kinds.append(("fbx", ".fbx"))
    return kinds


def _check_outdir(outdir: Path) -> Path:
    """Check that OUTDIR is a folder where files can be made (or that it can be
    created: its parent exists and is writable); creates nothing."""
    outdir = outdir.absolute()
    if outdir.exists() and not outdir.is_dir():
        raise BatchError(f"{outdir}: the output folder is a file")
    if not outdir.exists():
        if not outdir.parent.is_dir():
            raise BatchError(f"{outdir}: cannot create the output folder: "
                             f"{outdir.parent} does not exist")
        try:  # made and removed again: the batch creates it once its cluster is up
            outdir.mkdir()
            outdir.rmdir()
        except OSError as exc:
            raise BatchError(f"{outdir}: cannot create the output folder "
                             f"({exc.strerror or exc})") from None
        return outdir
    probe = outdir / f".carapost-batch-{os.getpid()}.probe"
    try:
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise BatchError(f"{outdir}: the output folder is not writable "
                         f"({exc.strerror or exc})") from None
    return outdir


# ======================================================================================
# one take (runs on a worker)
# ======================================================================================
def process_one(take: str, outputs: dict[str, str], settings: BatchSettings) -> dict[str, Any]:
    """Process one take on this process and return its report row.

    Any error of the take (a bad file, no markers, nothing initialised) is caught and
    reported in the row (``status`` "failed", ``error`` the message): a bad take never
    stops the batch. Runs single-threaded: the parallelism of a batch is its takes.
    """
    import cv2
    from threadpoolctl import threadpool_limits

    from carapost.pipeline import process_take

    cv2.setNumThreads(1)
    t0 = time.perf_counter()
    c0 = time.process_time()
    row: dict[str, Any] = {"take": take, "status": "done", "error": ""}
    for kind in outputs:
        Path(outputs[kind]).parent.mkdir(parents=True, exist_ok=True)
    try:
        # one BLAS/OpenMP thread whatever the worker was started with (a worker of an
        # external cluster, a fork server started by someone else)
        with threadpool_limits(1):
            result = process_take(take, output=outputs["project"], rom=settings.rom,
                                  brim=settings.brim, c3d=outputs.get("c3d"),
                                  fbx=outputs.get("fbx"),
                                  patch_tracking=settings.patch_tracking,
                                  stabilize=settings.stabilize, workers=1)
    except Exception as exc:  # every failure of a take is a report row
        row.update(status="failed", error=_message(exc))
        log.info("%s failed: %s", take, row["error"])
    else:
        row.update(frames=result["frames"], points=result["points"],
                   tracked_fraction=round(float(result["tracked_fraction"]), 6),
                   mean_residual=_finite(result.get("mean_residual")),
                   project=result["project"], c3d=result["c3d"], fbx=result["fbx"])
    row["seconds"] = round(time.perf_counter() - t0, 3)
    row["cpu_seconds"] = round(time.process_time() - c0, 3)
    return row


def _message(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    if not isinstance(exc, CaraFileError | ValueError | RuntimeError | OSError):
        text = f"{type(exc).__name__}: {text}"
    return " ".join(text.split())  # one line in the report and the CSV


def _finite(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return round(v, 6) if v == v and abs(v) != float("inf") else None


# ======================================================================================
# the batch
# ======================================================================================
#: ``progress(state)``: called after every take with a dict of ``total``, ``done``,
#: ``failed``, ``skipped``, ``running``, ``elapsed_s`` and ``eta_s`` (None until a take
#: has finished).
BatchProgress = Callable[[dict[str, Any]], None]


def _connect(scheduler: str, timeout: float) -> Any:
    from distributed import Client

    try:
        return Client(scheduler, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise BatchError(f"{scheduler}: no Dask scheduler answers at this address "
                         f"({' '.join(str(exc).split()) or type(exc).__name__})") from None



def _worker_died(exc: BaseException | None) -> bool:
    from distributed import KilledWorker
    from distributed.comm.core import CommClosedError

    return isinstance(exc, KilledWorker | CommClosedError)


def _remove_partials(task: TakeTask) -> None:
    """Remove the temporary files an output writer killed mid-write leaves."""
    for path in task.outputs.values():
        for part in path.parent.glob(f".{glob.escape(path.name)}.*.part"):
            part.unlink(missing_ok=True)


def run(inputs: Iterable[str | os.PathLike[str]] | str | os.PathLike[str],
        out: str | os.PathLike[str], client: Any = None, *,
        rom: str | os.PathLike[str] | None = None, brim: str | os.PathLike[str] | None = None,
        c3d: bool = False, fbx: bool = False, patch_tracking: bool = False,
        stabilize: str | None = None, scheduler: str | None = None,
        workers: int | None = None, retries: int = 1,
        force: bool = False, progress: BatchProgress | None = None,
        task: Callable[[str, dict[str, str], BatchSettings], dict[str, Any]] = process_one,
        connect_timeout: float = 10.0) -> dict[str, Any]:
    """Process every take of ``inputs`` into ``out`` on Dask; returns the batch report.

    Parameters
    ----------
    inputs : path, wildcard, or iterable of them
        Take files, folders (searched recursively) or wildcards; each take is one task.
    out : str or PathLike
        OUTDIR (created when its parent exists): ``<take>.cara`` (``.c3d``, ``.fbx``),
        ``batch_manifest.json``, ``batch_report.json`` and ``batch_report.csv``.
    client : dask.distributed.Client, optional
        Run on this client's cluster (left open).
    rom, brim, c3d, fbx, patch_tracking, stabilize
        The settings of every take (`BatchSettings`).
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``) when no client is given.
        Default: a ``LocalCluster`` with ``workers`` single-threaded worker processes.
    workers : int, optional
        Workers of the LocalCluster (default: one per core, at most one per take).
    retries : int
        Times a take is run again when the worker running it dies (default 1).
    force : bool
        Process every take, also those the manifest says are up to date.
    progress : callable, optional
        ``progress(state)`` after every finished take (see `BatchProgress`).
    task : callable
        The per-take function, ``task(take, outputs, settings) -> row`` (default
        `process_one`); a replacement must be importable on the workers.
    connect_timeout : float
        Seconds to wait for ``scheduler``.

    Returns
    -------
    dict
        ``outdir``, ``settings``, ``workers``, ``seconds``, ``summary`` (``total``,
        ``done``, ``failed``, ``skipped``, ``cancelled``) and ``takes``: one row per take
        with the keys of `REPORT_FIELDS` (also written to ``batch_report.json``/``.csv``).

    Raises
    ------
    BatchError
        Bad input, found before any work (see `plan`), a bad ``retries``/``workers``,
        or a ``scheduler`` that does not answer.
    KeyboardInterrupt
        Interrupted: the finished takes are kept (manifest and report written), the
        running ones are stopped and leave no file behind.
    """
    if isinstance(inputs, str | os.PathLike):
        inputs = [inputs]
    if int(retries) < 0:
        raise BatchError(f"retries must be >= 0, got {retries}")
    if workers is not None and int(workers) < 1:
        raise BatchError(f"workers must be >= 1, got {workers}")
    if stabilize not in (None, "auto", "assisted"):
        raise BatchError(f"stabilize must be 'auto' or 'assisted', got {stabilize!r}")
    settings = BatchSettings(rom=os.fspath(rom) if rom else None,
                             brim=os.fspath(brim) if brim else None, c3d=bool(c3d),
                             fbx=bool(fbx), patch_tracking=bool(patch_tracking),
                             stabilize=stabilize)
    started = time.perf_counter()
    # The fork server of a local cluster imports the take's modules (~1.2 s CPU, the
    # start-up's longest wait: the first worker is forked from it) on the other core
    # while this process plans (whose imports of the pipeline and scipy are ~0.4 s of
    # CPU), reads the manifest and starts the scheduler.
    forked = client is None and not scheduler and start_fork_server()
    # stopped on every way out before a worker was forked from it (bad input, a
    # locked OUTDIR, nothing to do, an error): its preload is then no use
    workers_forked = False
    try:
        tasks = plan(inputs, out, settings)
        outdir = Path(out).absolute()
        own: tuple[Any, ...] | None = None
        if client is None and scheduler:
            client = _connect(scheduler, connect_timeout)
            own = (None, client)
        outdir.mkdir(exist_ok=True)
        try:
            # one batch per OUTDIR at a time: two would interleave their manifests
            lock = _lock_outdir(outdir)
        except BatchError:
            _close(own)
            raise
        try:
            manifest = read_manifest(outdir)
            rows: dict[int, dict[str, Any]] = {}
            todo: list[int] = []
            for i, t in enumerate(tasks):
                entry = manifest.get(t.key(outdir))
                if not force and _is_current(t, entry):
                    rows[i] = {**entry.get("row", {}), "status": "skipped", "error": "",
                               "seconds": 0.0, "attempts": 0}
                else:
                    todo.append(i)
            state = {"total": len(tasks), "done": 0, "failed": 0, "skipped": len(rows),
                     "running": 0, "elapsed_s": 0.0, "eta_s": None}
            n_workers = 0

            def report(cancelled: bool = False) -> dict[str, Any]:
                all_rows = []
                for i, t in enumerate(tasks):
                    row = rows.get(i) or {
                        "take": str(t.take), "status": "cancelled" if cancelled else "pending",
                        "error": "interrupted" if cancelled else ""}
                    all_rows.append({k: row.get(k) for k in REPORT_FIELDS})
                counts = {s: sum(r["status"] == s for r in all_rows)
                          for s in ("done", "failed", "skipped", "cancelled")}
                rep = {"carapost": __version__, "outdir": str(outdir),
                       "settings": asdict(settings), "workers": n_workers,
                       "seconds": round(time.perf_counter() - started, 3),
                       "summary": {"total": len(tasks), **counts}, "takes": all_rows}
                _write_report(outdir, rep)
                return rep

            if progress is not None:
                progress(dict(state))
            if not todo:  # every take is up to date: no worker is needed
                return report()
            try:
                if client is None:
                    n = min(int(workers or os.cpu_count() or 1), len(todo))
                    workers_forked = True   # from here its workers fork from the server
                    own = _local_cluster(n, wait=False)  # waited for once the takes are queued
                    client = own[1]
                    n_workers = n  # they join while the takes are queued
                else:
                    n_workers = len(client.scheduler_info().get("workers", {}))
                _run_tasks(client, tasks, _longest_first(tasks, todo), settings, outdir,
                           manifest, rows, state, retries, task, progress, started,
                           first_worker=own is not None)
                # every take has ended: the report is written before the cluster is shut down
                rep = report()
            except KeyboardInterrupt:
                log.warning("Batch interrupted: %d of %d takes finished", state["done"] +
                            state["failed"], len(todo))
                _close(own)
                own = None
                for i in todo:
                    if i not in rows:
                        _remove_partials(tasks[i])
                report(cancelled=True)
                raise
            finally:
                _close(own)
            return rep
        finally:
            os.close(lock)  # closing releases the lock
    finally:
        if forked and not workers_forked:
            stop_fork_server()

LOCK_NAME = ".batch.lock"


def _longest_first(tasks: list[TakeTask], todo: list[int]) -> list[int]:
    """``todo`` with the takes of most input bytes first (ties in input order).

    The scheduler hands the takes out in submission order, so the long takes start
    first and the short ones fill in at the end, instead of one long take finishing
    alone on one worker while the others are idle (longest processing time first).
    A take's size (its videos' bytes) stands for its cost; a file that cannot be read
    counts as empty (its take fails quickly).
    """
    def size(i: int) -> int:
        total = 0
        for f in tasks[i].files:
            try:
                total += sum(n for _, n, _ in _stat_entries(f))
            except OSError:
                pass
        return total

    return sorted(todo, key=lambda i: -size(i))


def _lock_outdir(outdir: Path) -> int:
    """Take ``OUTDIR/.batch.lock`` (an exclusive ``flock``) for a batch writing there;
    returns the descriptor whose closing releases it (of the null device where there is no flock).

    Raises
    ------
    BatchError
        Another batch holds it (its process id is in the message).
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no flock on this platform: no lock
        return os.open(os.devnull, os.O_RDONLY)
    path = outdir / LOCK_NAME
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise BatchError(f"{path}: cannot be created ({exc.strerror or exc})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        other = os.pread(fd, 32, 0).decode("ascii", "replace").strip() or "?"
        os.close(fd)
        raise BatchError(f"{outdir}: another batch (process {other}) is writing there; "
                         "wait for it to end or choose another output folder") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd

def _run_tasks(client: Any, tasks: list[TakeTask], todo: list[int], settings: BatchSettings,
               outdir: Path, manifest: dict[str, Any], rows: dict[int, dict[str, Any]],
               state: dict[str, Any], retries: int, task: Callable[..., dict[str, Any]],
               progress: BatchProgress | None, started: float, first_worker: bool = False
               ) -> None:
    """Submit the takes (in the order of ``todo``), resubmit those whose worker died,
    record each as it ends. ``first_worker``: the cluster is still starting; wait for
    its first worker (`wait_for_first_worker`) once the takes are queued."""
    from distributed import as_completed

    token = os.urandom(4).hex()
    meta: dict[str, tuple[int, int]] = {}

    def submit(i: int, attempt: int) -> Any:
        t = tasks[i]
        key = f"carapost-batch-{token}-{i}-{attempt}"
        meta[key] = (i, attempt)
        return client.submit(task, str(t.take), {k: str(v) for k, v in t.outputs.items()},
                             settings, key=key, pure=False, retries=0)

    futures = [submit(i, 1) for i in todo]
    state["running"] = len(futures)
    finished_seconds: list[float] = []
    queue = as_completed(futures, loop=client.loop)
    try:
        if first_worker:
            wait_for_first_worker(client)
        for fut in queue:
            i, attempt = meta[fut.key]
            t = tasks[i]
            if fut.status == "finished":
                row = dict(fut.result())
            else:
                exc = fut.exception() if fut.status == "error" else None
                if _worker_died(exc) and attempt <= retries:
                    log.warning("%s: its worker died; running it again (attempt %d of %d)",
                                t.take, attempt + 1, retries + 1)
                    queue.add(submit(i, attempt + 1))
                    fut.release()
                    continue
                why = (f"the worker running it died {attempt} time(s)" if _worker_died(exc)
                       else _message(exc) if exc is not None else f"task {fut.status}")
                row = {"take": str(t.take), "status": "failed", "error": why}
                _remove_partials(t)
            fut.release()
            row["attempts"] = attempt
            row["take"] = str(t.take)
            rows[i] = row
            state["running"] -= 1
            if row.get("status") == "done":
                state["done"] += 1
                finished_seconds.append(float(row.get("seconds") or 0.0))
                manifest[t.key(outdir)] = {"digest": t.digest, "take": str(t.take),
                                           "row": {k: row.get(k) for k in REPORT_FIELDS}}
                _write_json(outdir / MANIFEST_NAME, {"carapost": __version__,
                                                     "takes": manifest})
            else:
                state["failed"] += 1
            elapsed = time.perf_counter() - started
            ended = state["done"] + state["failed"]
            left = len(todo) - ended
            state["elapsed_s"] = round(elapsed, 1)
            state["eta_s"] = round(elapsed / ended * left, 1) if ended else None
            if progress is not None:
                progress(dict(state))
    except BaseException:
        client.cancel([f for f in futures if not f.done()])
        raise


def _write_report(outdir: Path, rep: dict[str, Any]) -> None:
    """``batch_report.json`` and ``batch_report.csv`` (each atomically)."""
    _write_json(outdir / "batch_report.json", rep)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=REPORT_FIELDS, lineterminator="\n")
    w.writeheader()
    for row in rep["takes"]:
        w.writerow({k: "" if row.get(k) is None else row[k] for k in REPORT_FIELDS})
    with atomic_output(outdir / "batch_report.csv") as f:
        f.write(buf.getvalue().encode())
