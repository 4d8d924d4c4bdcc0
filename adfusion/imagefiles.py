"""Reading a frame file: the one place a frame image file is decoded (:func:`read_frame_file`).

Every reader of frame files goes through it — star detection
(:func:`adfusion.starid.detection.image.read_image`), the image folders of
:mod:`adfusion.logs` and the replay's inputs — so each of these holds for all of them
(issue 33):

* **paths of any bytes**: the file is opened by Python and only its bytes reach OpenCV
  (``cv2.imdecode``), so a name that is not UTF-8 (a ``str`` with surrogate escapes) is
  read like any other; messages show names with :func:`shown_path`, never raising
  ``UnicodeEncodeError``;
* **a pixel cap of our own**, checked on the size read from the file's header before
  anything is decoded (PNG, JPEG, TIFF, BMP, PNM/PAM, WebP, FITS): at most
  :func:`max_image_pixels` pixels, ``ADFUSION_MAX_IMAGE_PIXELS`` (default 100 000 000);
  a format whose header is not read here is refused rather than decoded blind;
* **half-there files** are refused, not decoded with their missing part grey: a PNG
  needs its ``IEND`` chunk, a JPEG its end marker (``FF D9``) after the last scan, a
  TIFF every strip or tile inside the file, a BMP, binary PNM, WebP or FITS its whole
  pixel data;
* **FITS** frames are read with astropy: the primary HDU, or the first image HDU when
  the primary holds no data, as a 2-D array in its own type (``uint16`` for the usual
  ``BZERO = 32768`` files, float kept float) in native byte order; rows are kept in file
  order (``ROWORDER = 'BOTTOM-UP'`` is flipped to top-down).

Every failure is an :class:`ImageFileError` (a ``ValueError``): one line naming the file.

A leaf below every layer (it imports nothing of ours), so ``starid``, ``logs`` and the
application share it without depending on each other.

Example:
    >>> import os, tempfile
    >>> import cv2, numpy as np
    >>> d = tempfile.mkdtemp()
    >>> path = os.path.join(d, "caf\\udce9.png")  # the name b"caf\\xe9.png", not UTF-8
    >>> _, png = cv2.imencode(".png", np.full((4, 6), 1000, np.uint16))
    >>> _ = open(path, "wb").write(png.tobytes())
    >>> a = read_frame_file(path); a.shape, a.dtype.name, int(a[0, 0])
    ((4, 6), 'uint16', 1000)
    >>> frame_size(path)
    (6, 4)
    >>> _ = open(path, "wb").write(png.tobytes()[:-12])  # the IEND chunk cut off
    >>> try:
    ...     read_frame_file(path)
    ... except ImageFileError as e:
    ...     print(str(e).replace(d, "D"))
    cannot read image file 'D/caf\\udce9.png': the file is truncated (a PNG without its IEND chunk)
"""

from __future__ import annotations

import io
import os
import re
import struct
import warnings
import zlib
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

__all__ = ["DEFAULT_MAX_PIXELS", "MAX_PIXELS_VARIABLE", "ImageFileError", "decode_frame_bytes",
           "frame_size", "max_image_pixels", "read_frame_file", "shown_path"]

MAX_PIXELS_VARIABLE = "ADFUSION_MAX_IMAGE_PIXELS"
DEFAULT_MAX_PIXELS = 100_000_000

_FORMATS = "PNG, JPEG, TIFF, BMP, PNM/PGM/PPM/PAM, WebP or FITS"
_HEAD = 1 << 16  # bytes read before the header is parsed (more are read when it needs them)


class ImageFileError(ValueError):
    """A frame file that cannot be used: missing pixels, too many, or not decodable.
    The message is one line naming the file (:func:`shown_path`-safe)."""


def shown_path(path: str | os.PathLike[str] | bytes) -> str:
    """``path`` as printable text: the name itself when it is UTF-8, else with its
    undecodable bytes as ``\\xNN`` (``b"caf\\xe9.png"`` → ``caf\\xe9.png``).

    >>> shown_path("caf\\udce9.png"), shown_path(b"caf\\xe9.png"), shown_path("café.png")
    ('caf\\\\xe9.png', 'caf\\\\xe9.png', 'café.png')
    """
    name = os.fsdecode(path)
    try:
        raw = name.encode("utf-8", "surrogateescape")
    except UnicodeEncodeError:  # a lone surrogate that is no escaped byte
        return name.encode("utf-8", "backslashreplace").decode("utf-8")
    return raw.decode("utf-8", "backslashreplace")


def max_image_pixels() -> int:
    """The pixel cap: ``ADFUSION_MAX_IMAGE_PIXELS`` (a positive whole number; unset or
    empty: 100 000 000). Anything else (``inf``, ``1e8``, ``-1``, junk) is a one-line
    :class:`ValueError` naming the variable.

    >>> os.environ["ADFUSION_MAX_IMAGE_PIXELS"] = "inf"
    >>> try:
    ...     max_image_pixels()
    ... except ValueError as e:
    ...     print(e)
    ADFUSION_MAX_IMAGE_PIXELS='inf': not a positive whole number of pixels (unset: 100000000)
    >>> del os.environ["ADFUSION_MAX_IMAGE_PIXELS"]; max_image_pixels()
    100000000
    """
    text = os.environ.get(MAX_PIXELS_VARIABLE, "").strip()
    if not text:
        return DEFAULT_MAX_PIXELS
    if re.fullmatch(r"[0-9]+(_[0-9]+)*", text, re.ASCII) and int(text) > 0:
        return int(text)
    raise ValueError(f"{MAX_PIXELS_VARIABLE}={text[:40]!r}: not a positive whole number of "
                     f"pixels (unset: {DEFAULT_MAX_PIXELS})")


# --- headers: (format, width, height) without decoding -----------------------------------


class _Truncated(Exception):
    """The header or the data ends early (the reason in ``args[0]``)."""


class _Bytes:
    """Random access to a file's bytes: what was read so far, more on demand."""

    def __init__(self, f: Any, size: int) -> None:
        self.f, self.size = f, size
        self.data = f.read(min(size, _HEAD))

    def at(self, offset: int, n: int) -> bytes:
        end = offset + n
        if end > len(self.data) and len(self.data) < self.size:
            if end - len(self.data) > (1 << 20):  # far away (TIFF directory): seek there
                self.f.seek(offset)
                return self.f.read(n)
            self.f.seek(len(self.data))
            self.data += self.f.read(end - len(self.data))
        return self.data[offset:end]

    def need(self, offset: int, n: int, what: str) -> bytes:
        out = self.at(offset, n)
        if len(out) < n:
            raise _Truncated(what)
        return out

    def everything(self) -> bytes:
        if len(self.data) < self.size:
            self.f.seek(len(self.data))
            self.data += self.f.read()
        return self.data


def _png_size(b: _Bytes) -> tuple[int, int]:
    head = b.need(8, 16, "a PNG without its IHDR chunk")
    if head[4:8] != b"IHDR":
        raise ImageFileError("a PNG whose first chunk is not IHDR")
    return struct.unpack(">II", head[8:16])


_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def _jpeg_size(b: _Bytes) -> tuple[int, int]:
    pos, cut = 2, "a JPEG that ends in its header"
    while True:
        if b.need(pos, 1, cut) != b"\xff":
            raise ImageFileError("a JPEG with junk between its header segments")
        while b.need(pos, 1, cut) == b"\xff":
            pos += 1  # a marker, after any fill bytes
        marker = b.need(pos, 1, cut)[0]
        pos += 1
        if marker in (0x01, *range(0xD0, 0xD8)):
            continue
        if marker in (0xD9, 0xDA):
            raise ImageFileError("a JPEG without a frame header (SOF) before its image data")
        length = struct.unpack(">H", b.need(pos, 2, cut))[0]
        if marker in _SOF:
            seg = b.need(pos, 8, "a JPEG that ends in its frame header")
            height, width = struct.unpack(">HH", seg[3:7])
            if height == 0:
                raise ImageFileError("a JPEG whose height is not in its frame header (DNL)")
            return width, height
        pos += length


_TIFF_TYPES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8,
               13: 4, 16: 8, 17: 8, 18: 8}
_TIFF_INT = {1: "B", 3: "H", 4: "I", 13: "I", 16: "Q", 6: "b", 8: "h", 9: "i", 17: "q"}


def _tiff_tags(b: _Bytes) -> dict[int, list[int]]:
    """The integer tags of a TIFF's first directory (classic or BigTIFF)."""
    e = "<" if b.at(0, 2) == b"II" else ">"
    version = struct.unpack(e + "H", b.need(2, 2, "a TIFF header"))[0]
    big = version == 43
    if big:
        ifd = struct.unpack(e + "Q", b.need(8, 8, "a TIFF header"))[0]
        n = struct.unpack(e + "Q", b.need(ifd, 8, "a TIFF without its directory"))[0]
        first, entry, inline, count_fmt = ifd + 8, 20, 8, "Q"
    elif version == 42:
        ifd = struct.unpack(e + "I", b.need(4, 4, "a TIFF header"))[0]
        n = struct.unpack(e + "H", b.need(ifd, 2, "a TIFF without its directory"))[0]
        first, entry, inline, count_fmt = ifd + 2, 12, 4, "I"
    else:
        raise ImageFileError(f"a TIFF of unknown version {version}")
    if n > 4096:
        raise ImageFileError(f"a TIFF directory of {n} entries")
    raw = b.need(first, n * entry, "a TIFF whose directory is cut")
    tags: dict[int, list[int]] = {}
    for k in range(n):
        rec = raw[k * entry:(k + 1) * entry]
        tag, typ = struct.unpack(e + "HH", rec[:4])
        count = struct.unpack(e + count_fmt, rec[4:4 + inline])[0]
        if typ not in _TIFF_INT or count > (1 << 24):
            continue
        size = _TIFF_TYPES[typ] * count
        if size <= inline:
            values = rec[4 + inline:4 + inline + size]
        else:
            where = struct.unpack(e + ("Q" if big else "I"), rec[4 + inline:])[0]
            values = b.need(where, size, "a TIFF whose tag values lie outside the file")
        tags[tag] = list(struct.unpack(f"{e}{count}{_TIFF_INT[typ]}", values))
    return tags


def _tiff_size(b: _Bytes) -> tuple[int, int]:
    tags = _tiff_tags(b)
    if 256 not in tags or 257 not in tags:
        raise ImageFileError("a TIFF without its ImageWidth or ImageLength")
    return tags[256][0], tags[257][0]


def _tiff_complete(b: _Bytes, size: int) -> None:
    tags = _tiff_tags(b)
    for offsets, counts in ((273, 279), (324, 325)):  # strips, tiles
        if offsets in tags and counts in tags:
            ends = [o + c for o, c in zip(tags[offsets], tags[counts], strict=False) if c]
            if ends and max(ends) > size:
                raise _Truncated(f"a TIFF whose pixel data end at byte {max(ends)}, "
                                 f"the file at {size}")


def _bmp_layout(b: _Bytes) -> tuple[int, int, int, int, int]:
    head = b.need(0, 30, "a BMP header")
    offset, dib = struct.unpack("<II", head[10:18])
    if dib == 12:
        width, height, _, bpp = struct.unpack("<hhHH", head[18:26])
        compression = 0
    else:
        width, height = struct.unpack("<ii", head[18:26])
        bpp = struct.unpack("<H", head[28:30])[0]
        compression = struct.unpack("<I", b.need(30, 4, "a BMP header"))[0]
    return abs(width), abs(height), bpp, compression, offset


def _bmp_size(b: _Bytes) -> tuple[int, int]:
    return _bmp_layout(b)[:2]


def _bmp_complete(b: _Bytes, size: int) -> None:
    width, height, bpp, compression, offset = _bmp_layout(b)
    if compression in (0, 3, 6):  # rows stored as they are
        need = offset + ((width * bpp + 31) // 32) * 4 * height
    else:  # run-length coded: the size the header announces
        need = struct.unpack("<I", b.at(2, 4))[0]
    if size < need:
        raise _Truncated(f"a BMP of {size} bytes whose pixels need {need}")


_PNM_TOKEN = re.compile(rb"(?:\s|#[^\n\r]*[\n\r])*([^\s#]+)")


def _pnm_layout(b: _Bytes) -> tuple[int, int, int, int]:
    """(width, height, bytes of pixel data or 0 if text, offset of the data)."""
    head = b.at(0, 4096)
    kind = head[:2]
    if kind == b"P7":
        end = head.find(b"ENDHDR")
        if end < 0:
            raise _Truncated("a PAM without its ENDHDR line")
        fields = dict(line.split(None, 1) for line in head[3:end].decode("latin-1")
                      .splitlines() if line.strip() and not line.startswith("#")
                      and len(line.split(None, 1)) == 2)
        try:
            w, h = int(fields["WIDTH"]), int(fields["HEIGHT"])
            depth, top = int(fields.get("DEPTH", "1")), int(fields.get("MAXVAL", "255"))
        except (KeyError, ValueError):
            raise ImageFileError("a PAM without a WIDTH, HEIGHT, DEPTH or MAXVAL it reads") \
                from None
        return w, h, w * h * depth * (2 if top > 255 else 1), end + 7
    tokens, pos = [], 2
    for _ in range(2 if kind in (b"P1", b"P4") else 3):
        m = _PNM_TOKEN.match(head, pos)
        if m is None and len(head) == b.size:
            raise _Truncated("a PNM that ends in its header")
        if m is None or (m.end() >= len(head) and len(head) < b.size):
            raise ImageFileError("a PNM header too long to read")
        if not m.group(1).isdigit():
            raise ImageFileError(f"a PNM header with {m.group(1)[:20]!r} for a number")
        tokens.append(int(m.group(1)))
        pos = m.end()
    w, h = tokens[:2]
    wide = 2 if len(tokens) == 3 and tokens[2] > 255 else 1
    data = {b"P4": (w + 7) // 8 * h, b"P5": w * h * wide, b"P6": 3 * w * h * wide}
    return w, h, data.get(kind, 0), pos + 1


def _pnm_size(b: _Bytes) -> tuple[int, int]:
    return _pnm_layout(b)[:2]


def _pnm_complete(b: _Bytes, size: int) -> None:
    _, _, data, start = _pnm_layout(b)
    if data and size < start + data:
        raise _Truncated(f"a PNM of {size} bytes whose pixels need {start + data}")


def _webp_size(b: _Bytes) -> tuple[int, int]:
    head = b.need(12, 18, "a WebP that ends in its header")
    chunk = head[:4]
    if chunk == b"VP8X":
        return (1 + int.from_bytes(head[12:15], "little"),
                1 + int.from_bytes(head[15:18], "little"))
    if chunk == b"VP8L" and head[8] == 0x2F:
        bits = int.from_bytes(head[9:13], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if chunk == b"VP8 " and head[11:14] == b"\x9d\x01\x2a":
        w, h = struct.unpack("<HH", b.need(26, 4, "a WebP that ends in its header"))
        return w & 0x3FFF, h & 0x3FFF
    raise ImageFileError(f"a WebP with a {chunk!r} chunk first")


def _webp_complete(b: _Bytes, size: int) -> None:
    need = 8 + struct.unpack("<I", b.at(4, 4))[0]
    if size < need:
        raise _Truncated(f"a WebP of {size} bytes whose RIFF header says {need}")


def _png_complete(b: _Bytes, size: int) -> None:
    """Every chunk whole and matching its CRC, up to ``IEND``: a damaged chunk would
    otherwise reach libpng, which says so on stderr in its own words and decodes what it
    can (the fuzz run met "libpng error: PNG input buffer is incomplete")."""
    data, pos = b.everything(), 8
    while pos + 8 <= len(data):
        length = struct.unpack(">I", data[pos:pos + 4])[0]
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(data):
            break  # the chunk runs past the end: truncated
        (crc,) = struct.unpack(">I", data[end - 4:end])
        if zlib.crc32(data[pos + 4:end - 4]) != crc:
            if data.find(b"IEND", pos) < 0:  # cut short (and padded, say with zeros)
                break
            name = kind.decode("latin-1") if kind.isalpha() else repr(kind)
            raise ImageFileError(f"the file is damaged (its PNG chunk {name} at byte {pos} "
                                 "fails its CRC)")
        if kind == b"IEND":
            return
        pos = end
    raise _Truncated("a PNG without its IEND chunk")


_JPEG_MARKER = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


def _jpeg_complete(b: _Bytes, size: int) -> None:
    """After the first scan (SOS), the entropy-coded data run to the next marker; segments
    between progressive scans are skipped by their length; the file must reach EOI."""
    data = b.everything()
    pos = 2
    while pos < len(data):  # the header segments, to the first SOS
        m = _JPEG_MARKER.search(data, pos)
        if m is None:
            break
        marker, pos = data[m.start() + 1], m.end()
        if marker == 0xD9:
            return
        if marker == 0x01:
            continue
        if pos + 2 > len(data):
            break
        pos += struct.unpack(">H", data[pos:pos + 2])[0]
        if marker == 0xDA:  # entropy-coded data follow: the next marker ends them
            continue
    raise _Truncated("a JPEG without its end marker FF D9")


def _fits_size(b: _Bytes) -> tuple[int, int]:
    return -1, -1  # read with astropy (:func:`_read_fits`), which checks the cap itself


_SIGNATURES: list[tuple[bytes, str, Callable[[_Bytes], tuple[int, int]],
                        Callable[[_Bytes, int], None] | None]] = [
    (b"\x89PNG\r\n\x1a\n", "PNG", _png_size, _png_complete),
    (b"\xff\xd8\xff", "JPEG", _jpeg_size, _jpeg_complete),
    (b"II*\x00", "TIFF", _tiff_size, _tiff_complete),
    (b"MM\x00*", "TIFF", _tiff_size, _tiff_complete),
    (b"II+\x00", "TIFF", _tiff_size, _tiff_complete),
    (b"MM\x00+", "TIFF", _tiff_size, _tiff_complete),
    (b"BM", "BMP", _bmp_size, _bmp_complete),
    (b"SIMPLE  =", "FITS", _fits_size, None),
    *[(f"P{k}".encode(), "PNM", _pnm_size, _pnm_complete) for k in range(1, 8)],
]


def _kind(b: _Bytes) -> tuple[str, Any, Any]:
    head = b.at(0, 16)
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "WebP", _webp_size, _webp_complete
    for magic, name, size, complete in _SIGNATURES:
        if head.startswith(magic):
            return name, size, complete
    raise ImageFileError(f"not a {_FORMATS} image" if head else "the file is empty")


def _over_cap(width: int, height: int) -> str | None:
    cap = max_image_pixels()
    if width * height <= cap:
        return None
    return (f"{width}×{height} px ({width * height / 1e6:.4g} megapixels) is over the limit "
            f"of {cap / 1e6:.4g} megapixels; set {MAX_PIXELS_VARIABLE} (pixels) to read it")


# --- reading ------------------------------------------------------------------------------


def _open(path: str | os.PathLike[str]) -> tuple[Any, int, str]:
    name = os.fspath(path)
    shown = repr(os.fsdecode(name))
    if not os.path.exists(name):
        raise FileNotFoundError(f"image file not found: {shown}")
    if not os.path.isfile(name):
        raise ImageFileError(f"image path is not a file: {shown}")
    try:
        f = open(name, "rb")  # closed by the caller
    except OSError as exc:
        raise ImageFileError(f"cannot read image file {shown}: {exc.strerror}") from None
    return f, os.fstat(f.fileno()).st_size, shown


def frame_size(path: str | os.PathLike[str]) -> tuple[int, int]:
    """``(width, height)`` of a frame file from its header alone (nothing decoded); an
    :class:`ImageFileError` if the format is not read or the header is cut."""
    f, size, shown = _open(path)
    with f:
        b = _Bytes(f, size)
        try:
            kind, size_of, _ = _kind(b)
            if kind == "FITS":
                shape = _read_fits(b, header_only=True).shape
                return shape[1], shape[0]
            return size_of(b)
        except _Truncated as exc:
            raise ImageFileError(f"cannot read image file {shown}: the file is truncated "
                                 f"({exc.args[0]})") from None
        except (ImageFileError, struct.error) as exc:
            raise ImageFileError(f"cannot read image file {shown}: {exc or 'bad header'}") \
                from None


def read_frame_file(path: str | os.PathLike[str]) -> np.ndarray:
    """A frame file as a 2-D grey array in its own bit depth (8/16-bit, float).

    Colour files become grey (BGR/BGRA → grey; grey + alpha → the grey plane). Raises
    :class:`FileNotFoundError` for a missing file and :class:`ImageFileError` (a
    ``ValueError``, one line naming the file) for everything else: a format not read, a
    header or pixel data cut short, more than :func:`max_image_pixels` pixels, data the
    decoder refuses; a :class:`ValueError` naming ``ADFUSION_MAX_IMAGE_PIXELS`` when that
    variable is not a positive whole number.
    """
    f, size, shown = _open(path)
    what = f"image file {shown}"
    with f:
        return _grey(_read(_Bytes(f, size), size, what), what)


def decode_frame_bytes(data: bytes, what: str, *, grey: bool = True) -> np.ndarray:
    """An encoded image held in memory (a log's ``CompressedImage``) with the checks of
    :func:`read_frame_file`: the pixel cap before decoding, truncation refused. ``what``
    names it in the one-line :class:`ImageFileError` (``"a 'png' CompressedImage at t =
    3 s"``); ``grey=False`` keeps colour as decoded (BGR)."""
    data = bytes(data)
    img = _read(_Bytes(io.BytesIO(data), len(data)), len(data), what)
    return _grey(img, what) if grey else img


def _read(b: _Bytes, size: int, what: str) -> np.ndarray:
    """Check the header, the cap and completeness of ``b``, then decode it."""
    kind = "image"
    try:
        kind, size_of, complete = _kind(b)
        if kind == "FITS":
            return _read_fits(b, header_only=False)
        width, height = size_of(b)
        if width <= 0 or height <= 0:
            raise ImageFileError(f"a {kind} of {width}×{height} px")
        too_big = _over_cap(width, height)
        if too_big:
            raise ImageFileError(too_big)
        complete(b, size)
        data = b.everything()
    except _Truncated as exc:
        raise ImageFileError(f"cannot read {what}: the file is truncated "
                             f"({exc.args[0]})") from None
    except struct.error:
        raise ImageFileError(f"cannot read {what}: a {kind} header it cannot parse") \
            from None
    except ImageFileError as exc:
        raise ImageFileError(f"cannot read {what}: {exc}") from None
    img = _decode(data)
    if img is None:
        raise ImageFileError(f"cannot read {what}: OpenCV could not decode this {kind}")
    if img.shape[0] * img.shape[1] > width * height:
        raise ImageFileError(f"cannot read {what}: decoded {img.shape[1]}×{img.shape[0]} "
                             f"px, its header says {width}×{height}")
    return img


def _decode(data: bytes) -> np.ndarray | None:
    """``cv2.imdecode`` with OpenCV's own log lines kept off stderr (the error said here
    names the file instead)."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    previous = log.setLogLevel(log.LOG_LEVEL_SILENT) if log is not None else None
    try:
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        return None
    finally:
        if log is not None:
            log.setLogLevel(previous)


def _grey(img: np.ndarray, what: str) -> np.ndarray:
    if img.ndim == 3:
        codes = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}
        if img.shape[2] in (1, 2):  # grey, grey + alpha
            img = np.ascontiguousarray(img[:, :, 0])
        elif img.shape[2] in codes:
            img = cv2.cvtColor(img, codes[img.shape[2]])
        else:
            raise ImageFileError(f"{what} has {img.shape[2]} channels")
    return img


def _read_fits(b: _Bytes, *, header_only: bool) -> np.ndarray:
    """The primary HDU's image, or the first image extension's when the primary holds
    none; the cap is checked on the header's shape before the data are read."""
    from astropy.io import fits

    def bad(why: str) -> ImageFileError:  # the caller adds the file's name
        return ImageFileError(why)

    data = b.everything()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # astropy's "may have been truncated": checked below
        try:
            hdul = fits.open(io.BytesIO(data), memmap=False, lazy_load_hdus=True)
        except (OSError, ValueError, TypeError, IndexError, KeyError) as exc:
            raise bad(f"not a FITS file astropy reads ({type(exc).__name__}: "
                      f"{str(exc)[:80]})") from None
        with hdul:
            hdu = None
            try:
                for candidate in hdul:
                    if candidate.is_image and candidate.header.get("NAXIS", 0) > 0:
                        hdu = candidate
                        break
            except (OSError, ValueError, TypeError, IndexError, KeyError):
                pass  # a cut extension: an image before it is still read
            if hdu is None:
                raise bad("a FITS file without an image HDU")
            shape = tuple(int(n) for n in hdu.shape)
            planes = [n for n in shape[:-2] if n != 1]
            if len(shape) < 2 or planes:
                raise bad(f"a FITS image of shape {shape}, not one 2-D frame")
            height, width = shape[-2:]
            too_big = _over_cap(width, height)
            if too_big:
                raise bad(too_big)
            if header_only:
                return np.empty((height, width, 0))
            info = hdu.fileinfo() or {}
            bitpix = abs(int(hdu.header.get("ZBITPIX", hdu.header.get("BITPIX", 8))))
            need = info.get("datLoc", 0) + int(np.prod(shape)) * bitpix // 8
            if not isinstance(hdu, fits.CompImageHDU) and len(data) < need:
                raise bad(f"the file is truncated (a FITS of {len(data)} bytes whose image "
                          f"needs {need})")
            try:
                img = np.asarray(hdu.data)
            except (OSError, ValueError, TypeError) as exc:
                raise bad(f"astropy could not read its image ({str(exc)[:80]})") from None
            bottom_up = str(hdu.header.get("ROWORDER", "")).strip().upper() == "BOTTOM-UP"
    img = img.reshape(height, width)
    if bottom_up:
        img = img[::-1]
    if not img.dtype.isnative:
        img = img.astype(img.dtype.newbyteorder("="))
    return np.ascontiguousarray(img)
