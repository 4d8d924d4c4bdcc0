"""One import root: nothing generic of ours in site-packages, nothing a user's file can shadow."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_a_users_logs_sensors_starid_files_do_not_shadow_ours(tmp_path: Path) -> None:
    # A script folder with modules named like our subpackages: Python puts the script's
    # folder first on sys.path, so a generic top-level name of ours would be shadowed.
    for name in ("logs", "sensors", "starid"):
        (tmp_path / f"{name}.py").write_text(f"raise ImportError('the user\\'s own {name}.py')\n")
    script = tmp_path / "user_script.py"
    script.write_text(
        "import adfusion.app.pipeline, adfusion.logs, adfusion.sensors, adfusion.starid\n"
        "from adfusion.logs import LogWriter\n"
        "from adfusion.starid import Camera\n"
        "print(adfusion.logs.__name__, adfusion.sensors.__name__, adfusion.starid.__name__)\n")
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120, check=False)
    assert p.returncode == 0, p.stderr
    assert p.stdout.split() == ["adfusion.logs", "adfusion.sensors", "adfusion.starid"]


def test_the_wheel_installs_one_top_level_name(tmp_path: Path) -> None:
    # the layout, not the compiled kernels a wheel ships (tests/test_first_use.py)
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                        "-q", "-w", str(tmp_path), str(REPO)],
                       capture_output=True, text=True, timeout=300, check=False,
                       env={**os.environ, "ADFUSION_BUILD_KERNELS": "0"})
    assert p.returncode == 0, p.stderr
    (wheel,) = tmp_path.glob("adfusion-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"adfusion"}, top
    # every package folder of the checkout is in the wheel (an unlisted subpackage would
    # work in an editable install and be missing from a real one)
    mapping = {"adfusion": "adfusion", "starid": "adfusion/starid", "sensors": "adfusion/sensors",
               "logs": "adfusion/logs"}
    for folder, installed in mapping.items():
        for init in (REPO / folder).rglob("__init__.py"):
            rel = init.relative_to(REPO / folder).as_posix()
            assert f"{installed}/{rel}" in names, f"{folder}/{rel} is not in the wheel"
    entry = zipfile.ZipFile(wheel).read(
        next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "adfusion = adfusion.app.cli:main" in entry
