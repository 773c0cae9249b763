"""Label From Template benchmark: rendered takes labelled from a template of another seed.

    python benchmarks/labelling.py [--frames 60] [--cases speech,fast,dense156,...]
        [--cache DIR] [--runs 5]

Each case renders two takes of the same marker set and rig with different seeds (so a
different expression and helmet slip): a ROM template and a target take. Both are
processed end to end without labels (`carapost.pipeline.process_take`: blob detection,
brim solve, automatic Initialize 3D, tracking); the template is labelled from its truth
(as an artist labels a ROM), then Label From Template labels the target, and each label
is checked against the target's truth (points matched to markers by geometry,
`carapost.synth.evaluation.truth_labels`).

Prints JSON lines per case (``case`` names it):

- ``label_template_correct``: fraction of the target's face points that match a truth
  marker the template has a label for and got that marker's label
  (``correct_of_all_matched`` also counts the points whose marker the template never
  tracked, which no template-based method can label);
- ``label_template_wrong``: labelled points whose label is not their marker's (a
  spurious point labelled counts as wrong);
- ``label_template_s``: seconds of Label From Template (prepare + compute, median of
  ``--runs``) on the ``dense156`` case (about 150 points), with ``cpu_s``.

Cases: ``speech`` and ``fast`` (standard 89 markers), ``dense156``, ``sparse35``, and
``heldout`` (speech on rig variant 3 with a template of variant 3: never tuned on).
Rendered takes are cached in ``--cache`` (default: a folder in the temporary directory).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

CASES = {
    # name: (target preset, markers, variant)
    "speech": ("speech", "standard", 0),
    "fast": ("fast", "standard", 0),
    "dense156": ("speech", "dense156", 0),
    "sparse35": ("speech", "sparse35", 0),
    "heldout": ("speech", "standard", 3),
}


def emit(metric: str, value: float | int | None, unit: str, **extra: object) -> None:
    print(json.dumps({"metric": metric, "value": value, "unit": unit, **extra}), flush=True)


def _take(cache: Path, preset: str, markers: str, variant: int, seed: int,
          frames: int) -> tuple[Path, Path]:
    """Render (or reuse) a take and process it; returns (project, truth)."""
    from carapost.pipeline import process_take
    from carapost.synth import SynthConfig, generate_take

    name = f"{preset}-{markers}-v{variant}-s{seed}-{frames}"
    folder = cache / name
    done = folder / "processed.cara"
    if not done.is_file():
        config = SynthConfig(preset=preset, markers=markers, frames=frames, seed=seed,
                             variant=variant, take_name="t")
        take = generate_take(folder / "take", config)
        process_take(take, output=done)
    return done, next((folder / "take").rglob("truth.npz"))


def _label_template(project_path: Path, truth: Path, out: Path) -> Path:
    from carapost.session import Session
    from carapost.synth.evaluation import truth_labels

    with Session.open(project_path) as s:
        s.set_point_labels(truth_labels(s.project, truth), description="Label from truth")
        return Path(s.save(out))


def run_case(name: str, cache: Path, frames: int, runs: int) -> None:
    from carapost.model.project import KIND_FACE
    from carapost.session import Session
    from carapost.synth.evaluation import truth_labels

    preset, markers, variant = CASES[name]
    tpl_project, tpl_truth = _take(cache, "rom", markers, variant, 21, frames)
    template = _label_template(tpl_project, tpl_truth, cache / f"template-{name}.cara")
    tgt_project, tgt_truth = _take(cache, preset, markers, variant, 4, frames)
    session = Session.open(tgt_project)
    times, cpus = [], []
    for _ in range(max(1, runs)):
        t0, c0 = time.perf_counter(), time.process_time()
        job = session.prepare_label_from_template(template)
        result = job.compute()
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    session.apply(result)
    p = session.project
    expected = truth_labels(p, tgt_truth)
    face = np.flatnonzero(p.points.kind == KIND_FACE)
    face = [int(c) for c in face if np.isfinite(p.points.positions[:, c, 0]).any()]
    real = [c for c in face if int(p.points.ids[c]) in expected]
    # a marker the template never tracked has no label there to give
    known = set(job.template_labels)
    labelable = [c for c in real if expected[int(p.points.ids[c])] in known]
    correct = sum(1 for c in labelable
                  if p.points.labels[c] == expected[int(p.points.ids[c])])
    wrong = sum(1 for c in face if p.points.labels[c]
                and p.points.labels[c] != expected.get(int(p.points.ids[c])))
    extra = {"case": name, "markers": markers, "preset": preset, "variant": variant,
             "points": len(face), "matched_points": len(real),
             "labelable_points": len(labelable),
             "correct_of_all_matched": round(correct / max(len(real), 1), 4),
             "unassigned": result.unassigned}
    emit("label_template_correct", round(correct / max(len(labelable), 1), 4), "fraction",
         **extra)
    emit("label_template_wrong", wrong, "labels", case=name)
    if name == "dense156":
        emit("label_template_s", round(statistics.median(times), 4), "s", case=name,
             points=len(face), cpu_s=round(statistics.median(cpus), 4),
             load_average=round(os.getloadavg()[0], 2))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--frames", type=int, default=60, help="frames per rendered take")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated cases")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "carapost-bench-label"),
                    help="folder of the rendered takes (reused)")
    ap.add_argument("--runs", type=int, default=5, help="timed repetitions")
    args = ap.parse_args()
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    for name in args.cases.split(","):
        run_case(name.strip(), cache, args.frames, args.runs)


if __name__ == "__main__":
    main()
