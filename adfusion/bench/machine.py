"""What a benchmark ran on and which code it measured: one probe for every benchmark's JSON.

Example:
    >>> m = machine_info(extra={"opencv": "5.0"})
    >>> sorted(m)[:4], m["opencv"]
    (['cores', 'cpu', 'loadavg', 'numpy'], '5.0')
    >>> len(code_version()["sources_sha256"])
    16
"""

from __future__ import annotations

import contextlib
import os
import platform
import subprocess
from pathlib import Path
from typing import Any

import numpy as np

from adfusion.starid.catalog.cache import source_digest

__all__ = ["code_version", "machine_info"]


def machine_info(extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """CPU model, core count, OS, Python and numpy versions, the load average at the call,
    plus ``extra`` (a benchmark's own library versions)."""
    cpu = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    load = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    return {"cpu": cpu, "cores": os.cpu_count(), "system": platform.platform(),
            "python": platform.python_version(), "numpy": np.__version__, "loadavg": load,
            **(extra or {})}


def code_version() -> dict[str, Any]:
    """Git commit of the checkout (with a dirty flag) and a digest of the package's sources
    (the tree may be dirty, or not a checkout at all)."""
    import adfusion

    sources = source_digest("adfusion", "adfusion.starid", "adfusion.sensors", "adfusion.logs")
    out: dict[str, Any] = {"sources_sha256": sources, "git_commit": None, "git_dirty": None}
    root = Path(adfusion.__file__).resolve().parents[1]
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        git = ["git", "-C", str(root)]
        rev = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, timeout=5, check=False)
        if rev.returncode == 0:
            out["git_commit"] = rev.stdout.strip()
            st = subprocess.run([*git, "status", "--porcelain"], capture_output=True,
                                text=True, timeout=5, check=False)
            out["git_dirty"] = bool(st.stdout.strip())
    return out
