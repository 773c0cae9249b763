"""Fuzz every file reader with thousands of seeded mutations (see tests/fuzz/harness.py).

Each input runs in a worker process with a time limit (10 s) and an address-space cap
(4 GB); a hang or a dead worker is recorded and the worker restarted. Prints JSON lines
per reader: ``fuzz_inputs``, ``fuzz_undocumented`` (an exception other than
CaraFileError), ``fuzz_hangs`` (over the time limit), ``fuzz_crashes`` (the worker died),
``fuzz_max_rss_mb`` (peak resident set of the worker), plus ``fuzz_internal`` (inputs
refused by a reader's last-resort net rather than a precise check) and
``fuzz_slowest_s``. Inputs that broke the contract are copied to ``--keep``.

Run from the repository root: ``python benchmarks/fuzz.py [--n 1000] [--reader NAME]``.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.fuzz.harness import READERS, run_fuzz


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000, help="inputs per reader")
    ap.add_argument("--reader", action="append", choices=sorted(READERS))
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=10.0)
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--verbose", action="store_true", help="print every contract breach")
    args = ap.parse_args()
    fixtures = os.environ.get("CARAPOST_FIXTURES")
    fixtures_dir = Path(fixtures) if fixtures else Path(__file__).resolve().parents[2] / \
        "shared" / "fixtures"
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)

    def show(o: object) -> None:
        if args.verbose and o.status in ("undocumented", "hang", "crash"):
            print(f"# {o.reader} case {o.case}: {o.status} {o.exc_type} {o.where} "
                  f"{o.message[:100]} | {o.mutation}", file=sys.stderr)

    for reader in args.reader or list(READERS):
        outs = run_fuzz([reader], args.n, timeout=args.timeout, seed=args.seed,
                        fixtures=fixtures_dir if fixtures_dir.is_dir() else None,
                        keep=args.keep, on_outcome=show)
        count = collections.Counter(o.status for o in outs)
        rows = {
            "fuzz_inputs": (len(outs), ""),
            "fuzz_undocumented": (count["undocumented"], ""),
            "fuzz_hangs": (count["hang"], ""),
            "fuzz_crashes": (count["crash"], ""),
            "fuzz_max_rss_mb": (round(max(o.rss_mb for o in outs), 1), "MB"),
            "fuzz_internal": (sum(o.internal for o in outs), ""),
            "fuzz_slowest_s": (round(max(o.seconds for o in outs), 3), "s"),
        }
        for metric, (value, unit) in rows.items():
            print(json.dumps({"metric": metric, "reader": reader, "value": value,
                              "unit": unit}), flush=True)


if __name__ == "__main__":
    main()
