"""Frame files that lie (issue 33, items 2, 5 and 8): names that are not UTF-8, pixel bombs,
half-written files and FITS frames. Real files written in ``tmp_path``, no mocks; everything
that could crash the interpreter runs in a subprocess, so a segfault is a negative return
code, not a lost test run."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from adfusion.logs import ImageFolderSource, McapLogReader
from adfusion.starid.detection.detect import detect
from adfusion.starid.detection.image import read_image

from adfusion.app.cli import main

VAR = "ADFUSION_MAX_IMAGE_PIXELS"
ROOT = Path(__file__).resolve().parent.parent


def _frame(seed: int = 0, shape: tuple[int, int] = (120, 160)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = rng.normal(20.0, 3.0, shape)
    for x, y in rng.uniform(10, min(shape) - 10, (6, 2)):  # a few stars
        yy, xx = np.mgrid[: shape[0], : shape[1]]
        img += 180.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2.0)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _encoded(ext: str, img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, img)
    assert ok
    return buf.tobytes()


def _python(code: str, cwd: Path, env: dict[str, str] | None = None,
            timeout: float = 300) -> subprocess.CompletedProcess:
    """``code`` in a fresh interpreter (bytes out: a name that is not UTF-8 can be in it)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd,
                          capture_output=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


# --- paths of any bytes -------------------------------------------------------------------


def test_a_frame_whose_name_is_not_utf8_is_read(tmp_path: Path):
    img = _frame(1)
    folder = os.fsencode(tmp_path)
    with open(os.path.join(folder, b"caf\xe9.png"), "wb") as f:
        f.write(_encoded(".png", img))
    with open(os.path.join(folder, b"d\xff.jpg"), "wb") as f:  # and one cut in half
        f.write(_encoded(".jpg", img)[:1000])
    run = _python(f"""
        import os, warnings
        import numpy as np
        from adfusion.logs import ImageFolderSource
        from adfusion.starid.detection.image import read_image
        folder = {os.fsdecode(folder)!r}
        a = read_image(os.path.join(folder, "caf\\udce9.png"))
        print("read", a.shape, a.dtype, int(a.sum()))
        try:
            read_image(os.path.join(folder, "d\\udcff.jpg"))
        except ValueError as e:
            print("refused", str(e).encode("utf-8").decode("utf-8"))
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            src = ImageFolderSource(folder, fps=1.0)
            frames = [m.payload for m in src.frames()]
        print("folder", len(frames), [str(x.message) for x in w], src.problems)
        """, tmp_path)
    assert run.returncode == 0, run.stderr.decode("utf-8", "replace")
    out = run.stdout.decode("utf-8")  # all of it printable as UTF-8
    assert f"read (120, 160) uint8 {int(img.sum())}" in out
    assert "refused" in out and "truncated" in out and "d\\udcff.jpg" in out
    # the folder's frame is read; the cut one is named printably, with \xNN for its byte
    assert "folder 1 " in out and "d\\\\xff.jpg: unreadable image" in out


def test_a_replay_of_a_folder_with_a_name_not_utf8_does_not_crash(tmp_path: Path):
    folder = tmp_path / "frames"
    folder.mkdir()
    names = [b"a.png", b"caf\xe9.png", b"c\xff.png", b"d.png"]
    for i, name in enumerate(names):
        data = _encoded(".png", _frame(i))
        with open(os.path.join(os.fsencode(folder), name), "wb") as f:
            f.write(data[: len(data) // 2] if name == b"c\xff.png" else data)
    run = _python(f"""
        import sys
        from adfusion.app.cli import main
        sys.exit(main(["replay", {str(folder)!r}, "--fps", "1", "--fov", "10",
                       "-o", {str(tmp_path / "out.mcap")!r}]))
        """, tmp_path)
    err = run.stderr.decode("utf-8")  # printable: no surrogate reached the terminal
    assert run.returncode in (0, 1), (run.returncode, err[-2000:])
    assert "Traceback" not in err and "c\\xff.png" in err
    meta = McapLogReader(tmp_path / "out.mcap").metadata
    assert any("1 of 4 frame file(s) dropped unread" in p for p in meta["problems"]["input"])


# --- a pixel cap of our own ---------------------------------------------------------------


def test_a_pixel_bomb_is_refused_before_decoding(tmp_path: Path):
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(_encoded(".png", np.zeros((16000, 16000), np.uint8)))
    assert bomb.stat().st_size < 1_000_000  # 256 megapixels in a few hundred kB
    with pytest.raises(ValueError) as info:
        read_image(bomb)
    text = str(info.value)
    assert "\n" not in text and "bomb.png" in text and "16000×16000" in text
    assert VAR in text and "CV_IO" not in text
    # in a fresh process: fast, and the memory does not grow by the 256 MB a decode takes
    run = _python(f"""
        import resource, time
        from adfusion.starid.detection.image import read_image
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t = time.perf_counter()
        try:
            read_image({str(bomb)!r})
        except ValueError:
            pass
        grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
        print(time.perf_counter() - t, grown)
        """, tmp_path)
    assert run.returncode == 0, run.stderr.decode()
    seconds, grown_kb = map(float, run.stdout.split())
    assert seconds < 0.5 and grown_kb < 32_000
    assert not run.stderr  # nothing of OpenCV's on stderr


def test_the_cap_is_configurable(tmp_path: Path, monkeypatch):
    path = tmp_path / "f.png"
    img = _frame(2)
    path.write_bytes(_encoded(".png", img))
    monkeypatch.setenv(VAR, str(img.size - 1))
    with pytest.raises(ValueError, match=rf"160×120 px.*{VAR}"):
        read_image(path)
    monkeypatch.setenv(VAR, str(img.size))
    np.testing.assert_array_equal(read_image(path), img)


@pytest.mark.parametrize("value", ["inf", "nan", "1e8", "-5", "0", "lots", "10 000"])
def test_a_cap_that_is_not_a_positive_integer_is_refused_naming_the_variable(
        tmp_path: Path, monkeypatch, value):
    path = tmp_path / "f.png"
    path.write_bytes(_encoded(".png", _frame(3)))
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames" / "f.png").write_bytes(path.read_bytes())
    monkeypatch.setenv(VAR, value)
    with pytest.raises(ValueError) as info:
        read_image(path)
    assert type(info.value) is ValueError  # not an OverflowError, not a frame problem
    text = str(info.value)
    assert text.startswith(f"{VAR}=") and "\n" not in text and "positive whole number" in text
    with pytest.raises(ValueError, match=VAR):  # a folder says it once, up front
        ImageFolderSource(tmp_path / "frames", fps=1.0)


# --- half-there files ---------------------------------------------------------------------


@pytest.mark.parametrize("ext, what", [(".jpg", "FF D9"), (".png", "IEND")])
@pytest.mark.parametrize("cut", [0.5, 0.95])
@pytest.mark.parametrize("padding", [0, 4096])
def test_a_truncated_frame_is_refused(tmp_path: Path, ext, what, cut, padding):
    img = _frame(4)
    data = _encoded(ext, img)
    path = tmp_path / f"cut{ext}"
    path.write_bytes(data[: int(len(data) * cut)] + b"\0" * padding)  # a preallocated file
    with pytest.raises(ValueError) as info:
        read_image(path)
    text = str(info.value)
    assert "\n" not in text and f"cut{ext}" in text
    assert "the file is truncated" in text and what in text
    # whole, with the same padding after it, it is read
    path.write_bytes(data + b"\0" * padding)
    back = read_image(path)
    assert back.shape == img.shape
    if ext == ".png":
        np.testing.assert_array_equal(back, img)


@pytest.mark.parametrize("ext", [".tiff", ".bmp", ".pgm", ".webp"])
def test_other_truncated_formats_are_refused(tmp_path: Path, ext):
    data = _encoded(ext, _frame(5).astype(np.uint16) * 200 if ext == ".tiff" else _frame(5))
    path = tmp_path / f"cut{ext}"
    path.write_bytes(data[: len(data) * 3 // 4])
    with pytest.raises(ValueError, match="truncated"):
        read_image(path)


def test_a_replay_counts_a_truncated_frame(tmp_path: Path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        data = _encoded(".jpg", _frame(10 + i))
        (folder / f"f{i}.jpg").write_bytes(data[: len(data) // 2] if i == 2 else data)
    out = tmp_path / "out.mcap"
    rc = main(["replay", str(folder), "--fps", "1", "--fov", "10", "-o", str(out)])
    assert rc in (0, 1)
    captured = capsys.readouterr()
    text = captured.out
    assert "f2.jpg: unreadable image at t = 2.0 s; skipped" in captured.err
    assert "frames 3," in text
    dropped = ("1 of 4 frame file(s) dropped unread (first: cannot read image file "
               f"'{folder / 'f2.jpg'}': the file is truncated")
    assert f"input problem: {dropped}" in text
    problems = McapLogReader(out).metadata["problems"]["input"]
    assert any(p.startswith(dropped) for p in problems), problems
    assert sum("f2.jpg" in p for p in problems) == 2  # its skip, then the count


# --- FITS ---------------------------------------------------------------------------------


def test_fits_frames_are_read(tmp_path: Path):
    from astropy.io import fits

    img16 = _frame(20).astype(np.uint16) * 250
    fits.PrimaryHDU(img16).writeto(tmp_path / "a.fits")
    back = read_image(tmp_path / "a.fits")
    assert back.dtype == np.uint16 and back.dtype.isnative
    np.testing.assert_array_equal(back, img16)
    # float data in the first image extension (an empty primary, as many cameras write)
    f32 = _frame(21).astype(np.float32) / 7.0
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(f32)]).writeto(tmp_path / "b.fits")
    back = read_image(tmp_path / "b.fits")
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, f32)
    np.testing.assert_array_equal(detect(tmp_path / "a.fits").xy, detect(img16).xy)
    # a folder of FITS frames, as IMAGE_SUFFIXES documents
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(2):
        fits.PrimaryHDU(img16 + i).writeto(folder / f"f{i}.fits")
    frames = list(ImageFolderSource(folder, fps=1.0).frames())
    assert [m.t_s for m in frames] == [0.0, 1.0]
    np.testing.assert_array_equal(frames[1].payload, img16 + 1)
    # cut, a cube, over the cap: one-line refusals naming the file
    data = (tmp_path / "a.fits").read_bytes()
    (tmp_path / "cut.fits").write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"cut\.fits.*truncated"):
        read_image(tmp_path / "cut.fits")
    fits.PrimaryHDU(np.zeros((3, 8, 8), np.uint16)).writeto(tmp_path / "cube.fits")
    with pytest.raises(ValueError, match=r"cube\.fits.*\(3, 8, 8\)"):
        read_image(tmp_path / "cube.fits")


def test_fits_bomb_is_refused_from_its_header(tmp_path: Path, monkeypatch):
    from astropy.io import fits

    fits.PrimaryHDU(np.zeros((40, 50), np.int16)).writeto(tmp_path / "a.fits")
    monkeypatch.setenv(VAR, "1000")
    t = time.perf_counter()
    with pytest.raises(ValueError, match=rf"a\.fits.*50×40 px.*{VAR}"):
        read_image(tmp_path / "a.fits")
    assert time.perf_counter() - t < 5


def test_the_reader_is_the_one_used_everywhere():
    """No frame is decoded outside adfusion.imagefiles (a path given to OpenCV is the
    crash of a name that is not UTF-8)."""
    found = []
    for folder in ("starid", "logs", "adfusion/app"):
        for path in (ROOT / folder).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            if "cv2.imread(" in text or "cv2.imdecode(" in text:
                found.append(str(path.relative_to(ROOT)))
    assert not found, found


def test_a_damaged_png_is_refused_in_our_words_not_libpngs(tmp_path, capfd):
    """The stream fuzz run met "libpng error: PNG input buffer is incomplete" on stderr: a
    PNG with a damaged chunk reached libpng, which spoke in its own words. Every chunk's
    CRC is checked before decoding."""
    from adfusion.imagefiles import ImageFileError, read_frame_file

    _, enc = cv2.imencode(".png", (np.arange(64 * 48).reshape(48, 64) % 251).astype(np.uint8))
    data = bytearray(enc.tobytes())
    data[60] ^= 0xFF  # inside IDAT
    bad = tmp_path / "damaged.png"
    bad.write_bytes(bytes(data))
    capfd.readouterr()
    with pytest.raises(ImageFileError, match=r"damaged \(its PNG chunk IDAT at byte 33 "
                                             r"fails its CRC\)"):
        read_frame_file(bad)
    assert capfd.readouterr().err == ""
    good = tmp_path / "good.png"
    good.write_bytes(enc.tobytes())
    assert read_frame_file(good).shape == (48, 64)
