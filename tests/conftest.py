"""Shared fixtures. Tests that need ``../shared`` (real frames, BSC5) skip cleanly without it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def find_shared() -> Path | None:
    """``$ADFUSION_SHARED`` or the ``shared/`` folder beside the checkout, if present."""
    env = os.environ.get("ADFUSION_SHARED")
    candidates = [Path(env)] if env else []
    candidates.append(REPO.parent / "shared")
    for c in candidates:
        if (c / "data").is_dir():
            return c
    return None


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """Path to ``shared/``; skips the test when it is absent (a bare clone)."""
    d = find_shared()
    if d is None:
        pytest.skip("../shared is not beside the checkout (set ADFUSION_SHARED to the "
                    "shared folder, the one that holds data/)")
    return d


@pytest.fixture(autouse=True, scope="session")
def _isolated_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Keep the on-disk cache of a test run inside the run unless the caller chose one."""
    if "ADFUSION_CACHE_DIR" not in os.environ:
        os.environ["ADFUSION_CACHE_DIR"] = str(tmp_path_factory.mktemp("adfusion-cache"))
