"""Batch throughput on Dask: ``carapost batch`` with 1 and 2 workers against ``carapost
process`` run on each take directly.

Metrics (one JSON object per line):

- ``batch_takes_per_min`` (with ``"workers": 1`` and ``2``): takes finished per minute
  by `carapost.batch.run` on the same takes (``force``, a new LocalCluster each run, so
  its start-up is included);
- ``batch_scaling_2w``: the 2-worker rate over the 1-worker rate (target >= 1.7 on a
  2-core machine);
- ``batch_scaling_bound``: what two workers on two cores can reach over one on the takes
  alone, with no start-up and no idle core: 2 x the wall over the CPU seconds of a take
  on the 1-worker batch (medians). A take alone keeps more than one core busy (its
  videos are decoded on the calling thread while the blobs of the previous images are
  detected), so this is below 2; ``with_fixed`` adds both batches' fixed parts. Only
  a measure on an idle machine: under load a take's wall time stretches past its CPU
  time and the figure passes 2;
- ``batch_scaling_takes``: the same ratio on the takes alone, measured: 2 x the median
  wall of a take on the 1-worker batch over the median wall of a take on the 2-worker
  batch (both workers busy), so what the ratio would be with no start-up, no tail and
  no idle worker. It is below ``batch_scaling_bound`` by what two takes at once cost
  each other (two takes' decoding and detection threads on two cores);
- ``batch_overhead_s``: (1-worker batch wall time - the sum of ``carapost process``
  wall times on the same takes, each a fresh process) / takes (target <= 1 s);
- ``batch_overhead_cpu_s``: the same difference in CPU seconds (driver, scheduler and
  workers against the ``carapost process`` processes and their detector processes);
- ``process_take_s``: median wall time of ``carapost process`` on one take (the
  reference), and the CPU seconds of every configuration (the workers' included: the
  fork server they are forked from is stopped and waited for at the end of each batch);
- with each ``batch_takes_per_min``: ``take_s_median`` / ``take_cpu_s_median``, the
  wall and CPU seconds of one take on its worker (from the report), and ``fixed_s``, the
  batch's wall time that is not its takes (start-up, scheduling, shutdown); where it
  goes: ``first_take_s`` (from the call of `run` to the first take starting on a
  worker), ``tail_s`` (from the last take's end to `run` returning) and
  ``imbalance_s`` (the rest: workers idle while another still runs a take, and takes
  started late); and the CPU by process: ``driver_cpu_s`` (the calling process: finding
  and hashing the takes, the scheduler, the nannies, the client; also ``driver_cpu_frac``,
  its share of a core while the takes run) and ``workers_cpu_s`` (the fork server and
  the workers, takes included).

Usage: ``python benchmarks/batch.py [--takes 6] [--frames 40] [--repeats 2]``.
Medians over the repeats; the configurations are interleaved, in alternating order
(1 then 2 workers, then 2 then 1), so that a change of the machine's load hits all of
them alike.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _self_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def make_takes(root: Path, n: int, frames: int) -> list[Path]:
    from carapost.synth import SynthConfig, generate_take

    return [Path(generate_take(root / f"take{i}", SynthConfig(
        frames=frames, seed=100 + i, size=(640, 360), take_name=f"Bench{i:02d}"),
        workers=2)) for i in range(n)]


def direct(takes: list[Path], out: Path) -> tuple[float, float, list[float]]:
    """``carapost process`` on each take in turn: (wall s, CPU s, per-take wall s)."""
    out.mkdir(exist_ok=True)
    per = []
    c0 = _children_cpu()
    t0 = time.perf_counter()
    for t in takes:
        s = time.perf_counter()
        subprocess.run([sys.executable, "-m", "carapost.cli", "process", str(t), "-o",
                        str(out / f"{t.stem}.cara")], check=True, capture_output=True)
        per.append(time.perf_counter() - s)
    return time.perf_counter() - t0, _children_cpu() - c0, per


def batch(takes: list[Path], out: Path, workers: int) -> tuple[float, float, dict]:
    """`carapost.batch.run` in a fresh process (so its CPU time is measurable): wall s,
    CPU s of the driver and its workers, and the per-take figures of its report (wall
    and CPU seconds of each take on its worker) with the timeline of the batch (when
    the first take started and the last ended, from a wrapper of the per-take task that
    appends its times to a file) and the CPU of the driver and of its workers."""
    times = out.parent / f"{out.name}.times.jsonl"
    times.unlink(missing_ok=True)
    code = ("import sys, json, os, time, resource\n"
            "from carapost.batch import process_one, run\n"
            "def timed(take, outputs, settings):\n"
            "    start = time.time()\n"
            "    row = process_one(take, outputs, settings)\n"
            f"    with open({str(times)!r}, 'a') as f:\n"
            "        f.write(json.dumps([start, time.time()]) + '\\n')\n"
            "    return row\n"
            "def cpu(who):\n"
            "    r = resource.getrusage(who)\n"
            "    return r.ru_utime + r.ru_stime\n"
            "ticks = []\n"
            "def progress(state):\n"  # the driver's CPU as each take ends
            "    if state['done'] + state['failed']:\n"
            "        ticks.append((time.perf_counter(), time.process_time()))\n"
            "if __name__ == '__main__':\n"
            "    t0 = time.time()\n"
            "    t = time.perf_counter()\n"
            f"    rep = run({[str(t) for t in takes]!r}, {str(out)!r}, workers={workers},"
            " force=True, task=timed, progress=progress)\n"
            "    wall = time.perf_counter() - t\n"
            "    t1 = time.time()\n"
            "    driver_cpu = cpu(resource.RUSAGE_SELF)\n"
            "    assert rep['summary']['done'] == len(rep['takes']), rep['takes']\n"
            # the workers are children of the fork server: stop it and wait for it, so
            # that their CPU time reaches this process's children's (private API,
            # as multiprocessing's own tests use it)
            "    from multiprocessing import forkserver\n"
            "    if getattr(forkserver._forkserver, '_forkserver_pid', None):\n"
            "        forkserver._forkserver._stop()\n"
            "    rows = rep['takes']\n"
            f"    spans = [json.loads(line) for line in open({str(times)!r})]\n"
            "    print(json.dumps({'wall': wall, 'take_s': [r['seconds'] for r in rows],"
            " 'take_cpu_s': [r['cpu_seconds'] for r in rows],"
            " 'first_take_s': min(s for s, _ in spans) - t0,"
            " 'last_take_end_s': max(e for _, e in spans) - t0,"
            " 'tail_s': t1 - max(e for _, e in spans),"
            " 'driver_cpu_frac': (ticks[-1][1] - ticks[0][1]) / (ticks[-1][0] - ticks[0][0]),"
            " 'driver_cpu_s': driver_cpu, 'workers_cpu_s': cpu(resource.RUSAGE_CHILDREN)}))\n")
    c0 = _children_cpu()
    res = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                         text=True)
    out_ = json.loads(res.stdout.strip().splitlines()[-1])
    return out_["wall"], _children_cpu() - c0, out_


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--takes", type=int, default=6)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        takes = make_takes(root / "takes", args.takes, args.frames)
        # warm the compiled kernels' cache and the OS file cache once, untimed
        direct(takes[:1], root / "warm")
        walls: dict[str, list[float]] = {"direct": [], "1": [], "2": []}
        cpus: dict[str, list[float]] = {"direct": [], "1": [], "2": []}
        per_take: list[float] = []
        take_s: dict[str, list[float]] = {"1": [], "2": []}
        take_cpu: dict[str, list[float]] = {"1": [], "2": []}
        # per batch: first_take_s, tail_s, driver_cpu_s, workers_cpu_s, driver_cpu_frac
        parts: dict[str, dict[str, list[float]]] = {"1": {}, "2": {}}
        for r in range(args.repeats):
            w, c, per = direct(takes, root / "direct")
            walls["direct"].append(w)
            cpus["direct"].append(c)
            per_take.extend(per)
            for n in ((1, 2) if r % 2 == 0 else (2, 1)):
                w, c, rep = batch(takes, root / f"batch{n}", n)
                walls[str(n)].append(w)
                cpus[str(n)].append(c)
                take_s[str(n)].extend(rep["take_s"])
                take_cpu[str(n)].extend(rep["take_cpu_s"])
                p = parts[str(n)]
                running = rep["last_take_end_s"] - rep["first_take_s"]
                for key, value in (("first_take_s", rep["first_take_s"]),
                                   ("tail_s", rep["tail_s"]),
                                   ("imbalance_s", running - sum(rep["take_s"]) / n),
                                   ("driver_cpu_s", rep["driver_cpu_s"]),
                                   ("driver_cpu_frac", rep["driver_cpu_frac"]),
                                   ("workers_cpu_s", rep["workers_cpu_s"])):
                    p.setdefault(key, []).append(value)
    med = {k: statistics.median(v) for k, v in walls.items()}
    cpu = {k: statistics.median(v) for k, v in cpus.items()}
    n = args.takes
    take1 = statistics.median(take_s["1"])
    bound = 2 * take1 / statistics.median(take_cpu["1"])
    fixed = {k: med[k] - sum(take_s[k]) / args.repeats / int(k) for k in ("1", "2")}
    common = {"takes": n, "frames": args.frames, "size": "640x360", "repeats": args.repeats,
              "loadavg_start": [round(v, 2) for v in load],
              "loadavg_end": [round(v, 2) for v in os.getloadavg()]}
    rows = [
        {"metric": "process_take_s", "value": round(statistics.median(per_take), 3),
         "unit": "s", "cpu_s_per_take": round(cpu["direct"] / n, 3), **common},
        *({"metric": "batch_takes_per_min", "value": round(60 * n / med[k], 2),
           "unit": "takes/min", "workers": int(k), "wall_s": round(med[k], 2),
           "cpu_s": round(cpu[k], 2),
           # each take on its worker: does the second worker slow the first one's takes?
           "take_s_median": round(statistics.median(take_s[k]), 3),
           "take_cpu_s_median": round(statistics.median(take_cpu[k]), 3),
           # what is not the takes: start-up, scheduling, shutdown (wall)
           "fixed_s": round(med[k] - sum(take_s[k]) / args.repeats / int(k), 2),
           **{key: round(statistics.median(v), 3) for key, v in parts[k].items()},
           **common} for k in ("1", "2")),
        {"metric": "batch_scaling_2w", "value": round(med["1"] / med["2"], 3),
         "unit": "ratio", "target": 1.7, **common},
        {"metric": "batch_scaling_takes",
         "value": round(2 * take1 / statistics.median(take_s["2"]), 3), "unit": "ratio",
         **common},
        {"metric": "batch_scaling_bound", "value": round(bound, 3), "unit": "ratio",
         "cores_per_take_1w": round(1 / (bound / 2), 3),
         "with_fixed": round((fixed["1"] + n * take1) / (fixed["2"] + n * take1 / bound), 3),
         **common},
        {"metric": "batch_overhead_s", "value": round((med["1"] - med["direct"]) / n, 3),
         "unit": "s", "target": 1.0, "direct_wall_s": round(med["direct"], 2), **common},
        # the same in CPU seconds: what a loaded machine cannot blur
        {"metric": "batch_overhead_cpu_s", "value": round((cpu["1"] - cpu["direct"]) / n, 3),
         "unit": "s", "direct_cpu_s": round(cpu["direct"], 2), **common},
    ]
    for r in rows:
        print(json.dumps(r))


if __name__ == "__main__":
    main()
