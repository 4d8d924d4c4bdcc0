"""``adfusion cache``: what the on-disk cache holds, and clearing it.
"""

from __future__ import annotations

import argparse
import json

from adfusion.app.errors import UsageError


def cmd_cache(args: argparse.Namespace) -> int:
    from adfusion.starid.catalog import cache

    root = cache.cache_dir()
    if args.action == "clear":
        kinds = sorted({e.kind for e in cache.cache_info()})
        if args.kind is not None and args.kind not in kinds:
            raise UsageError(f"--kind {args.kind!r}: no cache entries of that kind (kinds "
                             f"present: {', '.join(kinds) or 'none'})")
        n, size = cache.cache_clear(args.kind)
        msg = {"removed": n, "bytes": size, "dir": str(root) if root else None}
        print(json.dumps(msg) if args.json else
              f"removed {n} cache entr{'y' if n == 1 else 'ies'} ({size / 1e6:.1f} MB)"
              f" from {root}")
        return 0
    entries = cache.cache_info()
    total = sum(e.size for e in entries)
    limit = cache.cache_limit_bytes()
    if args.json:
        print(json.dumps({"dir": str(root) if root else None, "limit_bytes": limit,
                          "total_bytes": total,
                          "entries": [{"file": e.path.name, "kind": e.kind, "bytes": e.size,
                                       "last_used": e.last_used} for e in entries]}, indent=2))
        return 0
    if root is None:
        print("caching is off (ADFUSION_CACHE_DIR=off)")
        return 0
    print(f"{root}: {len(entries)} entries, {total / 1e6:.1f} MB of {limit / 1e6:.0f} MB "
          f"(ADFUSION_CACHE_MAX_MB); least recently used go first")
    import datetime as dt

    for e in entries:
        when = dt.datetime.fromtimestamp(e.last_used).strftime("%Y-%m-%d %H:%M")
        print(f"  {e.kind:16s} {e.size / 1e6:9.1f} MB  used {when}  {e.path.name}")
    return 0
