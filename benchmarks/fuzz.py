"""The long fuzz run of issue 16: every family of :mod:`adfusion.app.fuzz` for N minutes.

Families, round robin: the MCAP reader (byte flips, zeroed and cut-out spans, truncation
of two logs, zstd and uncompressed), the solver (random attitudes, false stars, dropped
stars, centroid noise, right and wrong priors, three cameras), the sources (random CSV text
and bytes, broken images, odd frame rates) and the CLI (random command lines over a corpus
of damaged and foreign files). Prints JSON (and writes it with ``--out``): the cases run,
the counts of tracebacks, silent losses, wrong attitudes accepted and CLI violations
(all must be 0), per-family outcomes, and the first violations with their cases.

    python benchmarks/fuzz.py --minutes 30 [--seed 1] [--out benchmarks/results/fuzz.json]

One process (the machine is shared); exit code 1 when any violation was found.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=1.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--folder", help="work folder (default: a new temporary one)")
    p.add_argument("--out", help="also write the JSON here")
    args = p.parse_args(argv)
    from adfusion.app.fuzz import run

    warnings.simplefilter("ignore")
    from adfusion.bench.machine import code_version, machine_info

    version = code_version()  # before the run: the code that ran, not the code after it
    result = run(args.minutes, seed=args.seed, folder=args.folder)
    result["command"] = (f"python -P benchmarks/fuzz.py --minutes {args.minutes:g} "
                         f"--seed {args.seed}")
    result["commit"] = version["git_commit"] + ("+dirty" if version["git_dirty"] else "") \
        if version["git_commit"] else None
    result["machine"] = machine_info()
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    bad = (result["tracebacks"] + result["silent_losses"] + result["wrong_attitudes"]
           + result["cli_violations"])
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
