"""``adfusion catalog``: the star catalogue a solve would use.
"""

from __future__ import annotations

import argparse
import json


def cmd_catalog(args: argparse.Namespace) -> int:
    from adfusion.starid.identify.renken import renken_count_table

    rows = [dict(zip(("limit", "sao", "ours_V", "ours_Hp"), r, strict=True))
            for r in renken_count_table()]
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    print("Full-sky star counts: Renken Tab. A.2 (SAO, mag < L) vs Hipparcos (this catalogue)")
    print(f"{'limit':>6} {'SAO':>6} {'Hip V':>7} {'Hip Hp':>7}")
    for r in rows:
        print(f"{r['limit']:>6.1f} {r['sao']:>6} {r['ours_V']:>7} {r['ours_Hp']:>7}")
    print("Hp (Hipparcos' own broad band) tracks SAO's counts within 15 % from 4.0 on; the\n"
          "estimated V counts are ~20 % higher at 4–5: SAO magnitudes run ~0.15–0.2 mag\n"
          "fainter than Johnson V and are rounded to 0.1 mag.")
    return 0
