"""Foxglove well-known messages (protobuf) ⇄ numpy/dict payloads: the quaternion-order boundary.

Inside adfusion quaternions are Hamilton ``[w, x, y, z]``; Foxglove stores ``x, y, z, w``.
This module is the only place that reorders them. Every ``encode_*`` returns a protobuf
message from ``foxglove-schemas-protobuf``; :func:`decode` turns one back into the payload the
reader yields (image → ``numpy`` array, everything else → ``dict`` with ``q_wxyz`` arrays).

Example:
    >>> import numpy as np
    >>> from adfusion.logs import foxglove as fg
    >>> msg = fg.encode_pose(1_500_000_000, np.array([0.6, 0.8, 0.0, 0.0]), "icrs")
    >>> (msg.pose.orientation.x, msg.pose.orientation.w)
    (0.8, 0.6)
    >>> fg.decode("foxglove.PoseInFrame", msg.SerializeToString())["q_wxyz"].tolist()
    [0.6, 0.8, 0.0, 0.0]
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Iterable, Sequence
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from google.protobuf.timestamp_pb2 import Timestamp

from adfusion.imagefiles import decode_frame_bytes

ArrayLike = Any

# Colours of the annotation layers (RGBA, 0..1) and the ``role`` tag that the reader keys on.
DETECTION_COLOR = (1.0, 0.85, 0.0, 1.0)
IDENTIFIED_COLOR = (0.2, 1.0, 0.2, 1.0)
PREDICTED_COLOR = (0.0, 0.8, 1.0, 1.0)
OCCUPIED_COLOR = (1.0, 0.25, 0.25, 1.0)
IDENTIFIED_DIAMETER_PX = 14.0

MESSAGE_TYPES: dict[str, type] = {
    cls.DESCRIPTOR.full_name: cls
    for cls in (
        RawImage,
        CompressedImage,
        ImageAnnotations,
        PoseInFrame,
        FrameTransforms,
        CameraCalibration,
    )
}
"""Foxglove schema name → protobuf class, for the types this project writes and decodes."""


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(seconds=t_ns // 1_000_000_000, nanos=t_ns % 1_000_000_000)


def _color(rgba: Sequence[float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _meta(**kv: str) -> list[KeyValuePair]:
    return [KeyValuePair(key=k, value=v) for k, v in kv.items()]


def _points(xy: ArrayLike) -> list[Point2]:
    arr = np.asarray(xy, dtype=float).reshape(-1, 2)
    return [Point2(x=x, y=y) for x, y in arr.tolist()]


def _quat_xyzw(q_wxyz: ArrayLike) -> dict[str, float]:
    w, x, y, z = (float(v) for v in np.asarray(q_wxyz, dtype=float).reshape(4))
    return {"x": x, "y": y, "z": z, "w": w}


def _q_wxyz(q: Any) -> np.ndarray:
    return np.array([q.w, q.x, q.y, q.z], dtype=float)


def encode_raw_image(t_ns: int, image: np.ndarray, frame_id: str) -> RawImage:
    """``foxglove.RawImage``: uint8 → ``mono8``, uint16 → ``mono16`` (little-endian),
    (H, W, 3) uint8 → ``bgr8`` (OpenCV order)."""
    encoding, data = _image_layout(image)
    data = np.ascontiguousarray(data)
    height, width = data.shape[:2]
    return RawImage(
        timestamp=_stamp(t_ns),
        frame_id=frame_id,
        width=width,
        height=height,
        encoding=encoding,
        step=data.strides[0],
        data=data.tobytes(),
    )


_FIXED32 = struct.Struct("<BI")  # a fixed32 field: its tag (numbers < 16) and value


def _image_layout(image: np.ndarray) -> tuple[str, np.ndarray]:
    img = np.asarray(image)
    if img.dtype == np.uint8 and img.ndim == 2:
        return "mono8", img
    if img.dtype == np.uint16 and img.ndim == 2:
        return "mono16", img.astype("<u2", copy=False)
    if img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3:
        return "bgr8", img
    raise ValueError(f"unsupported image {img.dtype} {img.shape}: want uint8/uint16 (H, W)")


def encode_raw_image_parts(t_ns: int, image: np.ndarray,
                           frame_id: str) -> tuple[bytes, memoryview, bytes]:
    """:func:`encode_raw_image` serialized, as three buffers to write one after the other:
    the fields before the pixels, the pixels themselves (a view of the array, not a copy),
    and ``frame_id`` (field 7, after ``data``, field 6, in protobuf's field-number order).
    The same bytes as ``encode_raw_image(...).SerializeToString()`` (tests/test_logs.py):
    a 245 kB frame is copied once, into the log, instead of three times on the way.

    Example:
        >>> img = np.arange(6, dtype=np.uint8).reshape(2, 3)
        >>> b"".join(encode_raw_image_parts(5, img, "camera")) == \\
        ...     encode_raw_image(5, img, "camera").SerializeToString()
        True
    """
    encoding, data = _image_layout(image)
    data = np.ascontiguousarray(data)
    height, width = data.shape[:2]
    head = [_field(1, _stamp_bytes(t_ns))]
    for number, value in ((2, width), (3, height)):  # fixed32 fields; proto3 skips zeros
        if value:
            head.append(_FIXED32.pack(number << 3 | 5, value))
    head.append(_field(4, encoding.encode()))
    if data.strides[0]:
        head.append(_FIXED32.pack(5 << 3 | 5, data.strides[0]))
    pixels = memoryview(data).cast("B") if data.size else memoryview(b"")
    if data.nbytes:
        head.append(_varint(6 << 3 | 2) + _varint_of(data.nbytes))
    tail = _field(7, frame_id.encode()) if frame_id else b""
    return b"".join(head), pixels, tail


def encode_png_image(t_ns: int, image: np.ndarray, frame_id: str) -> CompressedImage:
    """``foxglove.CompressedImage`` with ``format="png"`` (lossless; uint8 or uint16)."""
    ok, buf = cv2.imencode(".png", np.asarray(image))
    if not ok:
        raise ValueError(f"PNG encoding failed for image {image.dtype} {image.shape}")
    return CompressedImage(timestamp=_stamp(t_ns), frame_id=frame_id, data=buf.tobytes(),
                           format="png")


def _varint_of(n: int) -> bytes:
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


# varints below 2¹¹ (tags and the lengths of an annotation's parts) from a table: a replay
# encodes ~250 a frame, and the loop above cost 0.2 ms of them
_VARINTS = tuple(_varint_of(n) for n in range(1 << 11))


def _varint(n: int) -> bytes:
    return _VARINTS[n] if n < 2048 else _varint_of(n)


def _field(number: int, payload: bytes) -> bytes:
    """A length-delimited field (sub-message or string) in protobuf wire format."""
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def _stamp_bytes(t_ns: int) -> bytes:
    return _stamp(t_ns).SerializeToString()


# One serialized Point2 as a repeated field: tag, length 18, x (field 1, double), y (field 2).
_POINT = np.dtype([("tag", "u1"), ("len", "u1"), ("tx", "u1"), ("x", "<f8"), ("ty", "u1"),
                   ("y", "<f8")])
assert _POINT.itemsize == 20


def _points_bytes(field_number: int, xy: ArrayLike) -> bytes:
    """Repeated ``Point2`` field of (N, 2) points, packed by numpy instead of N objects."""
    arr = np.asarray(xy, dtype=float).reshape(-1, 2)
    rec = np.empty(len(arr), _POINT)
    rec["tag"], rec["len"], rec["tx"], rec["ty"] = field_number << 3 | 2, 18, 0x09, 0x11
    rec["x"], rec["y"] = arr[:, 0], arr[:, 1]
    return rec.tobytes()


def _layer_template(kind: int, color: Sequence[float], thickness: float, role: str) -> bytes:
    return PointsAnnotation(type=kind, outline_color=_color(color), thickness=thickness,
                            metadata=_meta(role=role)).SerializeToString()


# The constant fields of every layer, serialized once: protobuf concatenation is merging,
# so a message is its template's bytes followed by the fields that vary. Building the
# ~100 annotation objects of a frame one by one cost 0.3 ms per replayed frame.
_DETECTIONS = _layer_template(PointsAnnotation.POINTS, DETECTION_COLOR, 5.0, "detections")
_PREDICTED = _layer_template(PointsAnnotation.POINTS, PREDICTED_COLOR, 3.0, "predicted")
_OCCUPIED = _layer_template(PointsAnnotation.LINE_LOOP, OCCUPIED_COLOR, 1.5, "occupied")
_CIRCLE = CircleAnnotation(diameter=IDENTIFIED_DIAMETER_PX, thickness=1.5,
                           outline_color=_color(IDENTIFIED_COLOR),
                           metadata=_meta(role="identified")).SerializeToString()
_TEXT = TextAnnotation(font_size=12.0, text_color=_color(IDENTIFIED_COLOR),
                       background_color=_color((0.0, 0.0, 0.0, 0.5)),
                       metadata=_meta(role="label")).SerializeToString()


_LABEL_KEY = _field(1, b"label")
_POSITION = struct.Struct("<3sdBd")  # field 2 (position, a Point2): tag, length, x, y


@functools.lru_cache(maxsize=16384)
def _label_fields(text: str) -> tuple[bytes, bytes]:
    """A star's label as a circle's ``metadata`` entry and as a text's ``text`` field:
    the same stars are labelled frame after frame."""
    raw = text.encode()
    return _field(7, _LABEL_KEY + _field(2, raw)), _field(3, raw)


def encode_annotations_bytes(
    t_ns: int,
    detections_xy: ArrayLike | None = None,
    identified: Iterable[tuple[float, float, Any]] = (),
    predicted_xy: ArrayLike | None = None,
    occupied: Iterable[ArrayLike] = (),
) -> bytes:
    """:func:`encode_annotations`, serialized: the same message (parse it and compare),
    composed from pre-serialized pieces in protobuf wire format without building it.
    (Each identified star is one circle and one text joined from cached and packed
    pieces: ~20 stars a frame made this the replay's largest writing cost.)"""
    stamp = _field(1, _stamp_bytes(t_ns))  # field 1 (timestamp) of every annotation type
    circles, texts, layers = [], [], []
    circle_size = len(stamp) + _POSITION.size + len(_CIRCLE)
    text_size = len(stamp) + _POSITION.size + len(_TEXT)
    pack, join = _POSITION.pack, b"".join
    for x, y, label in identified:
        x, y = float(x), float(y)
        label_kv, text = _label_fields(str(label))
        circles.append(join((b"\x0a", _varint(circle_size + len(label_kv)), stamp,
                             pack(b"\x12\x12\x09", x, 0x11, y), _CIRCLE, label_kv)))
        texts.append(join((b"\x1a", _varint(text_size + len(text)), stamp,
                           pack(b"\x12\x12\x09", x + IDENTIFIED_DIAMETER_PX, 0x11, y - 4.0),
                           text, _TEXT)))
    if detections_xy is not None:
        layers.append(_field(2, stamp + _points_bytes(3, detections_xy) + _DETECTIONS))
    if predicted_xy is not None:
        layers.append(_field(2, stamp + _points_bytes(3, predicted_xy) + _PREDICTED))
    for polygon in occupied:
        layers.append(_field(2, stamp + _points_bytes(3, polygon) + _OCCUPIED))
    return b"".join(circles + layers + texts) + _field(5, stamp[2:])  # stamp[2:]: its body


def encode_annotations(
    t_ns: int,
    detections_xy: ArrayLike | None = None,
    identified: Iterable[tuple[float, float, Any]] = (),
    predicted_xy: ArrayLike | None = None,
    occupied: Iterable[ArrayLike] = (),
) -> ImageAnnotations:
    """``foxglove.ImageAnnotations`` in four layers, each tagged ``role`` in its metadata:
    detections (yellow points), identified stars (green circles + id text), projected
    catalogue (cyan points), occupied regions (red closed polygons, e.g. the tether mask)."""
    return ImageAnnotations.FromString(encode_annotations_bytes(
        t_ns, detections_xy, identified, predicted_xy, occupied))


def _encode_annotations_by_objects(
    t_ns: int,
    detections_xy: ArrayLike | None = None,
    identified: Iterable[tuple[float, float, Any]] = (),
    predicted_xy: ArrayLike | None = None,
    occupied: Iterable[ArrayLike] = (),
) -> ImageAnnotations:
    """The message built object by object (the reference :func:`encode_annotations_bytes`
    is tested against)."""
    stamp = _stamp(t_ns)
    msg = ImageAnnotations()
    if detections_xy is not None:
        msg.points.append(PointsAnnotation(
            timestamp=stamp, type=PointsAnnotation.POINTS, points=_points(detections_xy),
            outline_color=_color(DETECTION_COLOR), thickness=5.0,
            metadata=_meta(role="detections")))
    if predicted_xy is not None:
        msg.points.append(PointsAnnotation(
            timestamp=stamp, type=PointsAnnotation.POINTS, points=_points(predicted_xy),
            outline_color=_color(PREDICTED_COLOR), thickness=3.0,
            metadata=_meta(role="predicted")))
    for polygon in occupied:
        msg.points.append(PointsAnnotation(
            timestamp=stamp, type=PointsAnnotation.LINE_LOOP, points=_points(polygon),
            outline_color=_color(OCCUPIED_COLOR), thickness=1.5,
            metadata=_meta(role="occupied")))
    green = _color(IDENTIFIED_COLOR)
    for x, y, label in identified:
        text = str(label)
        msg.circles.append(CircleAnnotation(
            timestamp=stamp, position=Point2(x=float(x), y=float(y)),
            diameter=IDENTIFIED_DIAMETER_PX, thickness=1.5, outline_color=green,
            metadata=_meta(role="identified", label=text)))
        msg.texts.append(TextAnnotation(
            timestamp=stamp,
            position=Point2(x=float(x) + IDENTIFIED_DIAMETER_PX, y=float(y) - 4.0),
            text=text, font_size=12.0, text_color=green,
            background_color=_color((0.0, 0.0, 0.0, 0.5)), metadata=_meta(role="label")))
    msg.timestamp.CopyFrom(stamp)
    return msg


def encode_pose(t_ns: int, q_wxyz: ArrayLike, frame_id: str,
                position: ArrayLike = (0.0, 0.0, 0.0)) -> PoseInFrame:
    """``foxglove.PoseInFrame``: orientation of the body *in* ``frame_id`` (rotates body
    vectors into ``frame_id``)."""
    px, py, pz = (float(v) for v in np.asarray(position, dtype=float).reshape(3))
    msg = PoseInFrame(timestamp=_stamp(t_ns), frame_id=frame_id)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = px, py, pz
    for k, v in _quat_xyzw(q_wxyz).items():
        setattr(msg.pose.orientation, k, v)
    return msg


def encode_transforms(
    t_ns: int, transforms: Iterable[tuple[str, str, ArrayLike, ArrayLike]]
) -> FrameTransforms:
    """``foxglove.FrameTransforms`` from ``(parent, child, q_parent_child, translation)``:
    the rotation maps child-frame vectors into the parent frame (Foxglove's convention)."""
    msg = FrameTransforms()
    stamp = _stamp(t_ns)
    for parent, child, q_wxyz, translation in transforms:
        tf = FrameTransform(timestamp=stamp, parent_frame_id=parent, child_frame_id=child)
        tx, ty, tz = (float(v) for v in np.asarray(translation, dtype=float).reshape(3))
        tf.translation.x, tf.translation.y, tf.translation.z = tx, ty, tz
        for k, v in _quat_xyzw(q_wxyz).items():
            setattr(tf.rotation, k, v)
        msg.transforms.append(tf)
    return msg


def encode_calibration(t_ns: int, width: int, height: int, K: ArrayLike, D: ArrayLike,
                       frame_id: str) -> CameraCalibration:
    """``foxglove.CameraCalibration`` with OpenCV's distortion (``plumb_bob`` for up to five
    coefficients, ``rational_polynomial`` for eight), ``R = I`` and ``P = [K | 0]``."""
    k = np.asarray(K, dtype=float).reshape(3, 3)
    d = np.asarray(D, dtype=float).reshape(-1)
    model = "rational_polynomial" if d.size > 5 else "plumb_bob"
    p = np.hstack([k, np.zeros((3, 1))])
    return CameraCalibration(
        timestamp=_stamp(t_ns), frame_id=frame_id, width=int(width), height=int(height),
        distortion_model=model, D=d.tolist(), K=k.reshape(-1).tolist(),
        R=np.eye(3).reshape(-1).tolist(), P=p.reshape(-1).tolist())


def _raw_image_array(msg: RawImage) -> np.ndarray:
    enc = msg.encoding
    if enc in ("mono8", "8UC1"):
        dtype, channels = np.dtype(np.uint8), 1
    elif enc in ("mono16", "16UC1"):
        dtype, channels = np.dtype("<u2"), 1
    elif enc in ("bgr8", "rgb8"):
        dtype, channels = np.dtype(np.uint8), 3
    else:
        raise ValueError(f"RawImage encoding {enc!r} is not supported")
    row = msg.width * channels
    flat = np.frombuffer(msg.data, dtype=dtype)
    step = msg.step // dtype.itemsize if msg.step else row
    img = flat.reshape(msg.height, step)[:, :row]
    if channels == 3:
        img = img.reshape(msg.height, msg.width, 3)
        if enc == "rgb8":
            img = img[:, :, ::-1]
    return img.astype(np.uint16 if dtype.itemsize == 2 else np.uint8)


def _annotations_dict(msg: ImageAnnotations) -> dict[str, Any]:
    out: dict[str, Any] = {
        "detections_xy": np.zeros((0, 2)), "predicted_xy": np.zeros((0, 2)),
        "identified": [], "occupied": [], "points": [], "circles": [], "texts": [],
    }
    for p in msg.points:
        xy = np.array([(pt.x, pt.y) for pt in p.points], dtype=float).reshape(-1, 2)
        role = {kv.key: kv.value for kv in p.metadata}.get("role")
        if role == "detections":
            out["detections_xy"] = xy
        elif role == "predicted":
            out["predicted_xy"] = xy
        elif role == "occupied":
            out["occupied"].append(xy)
        else:
            out["points"].append(xy)
    for c in msg.circles:
        meta = {kv.key: kv.value for kv in c.metadata}
        if meta.get("role") == "identified":
            out["identified"].append((c.position.x, c.position.y, meta.get("label", "")))
        else:
            out["circles"].append((c.position.x, c.position.y, c.diameter))
    for t in msg.texts:
        if {kv.key: kv.value for kv in t.metadata}.get("role") != "label":
            out["texts"].append((t.position.x, t.position.y, t.text))
    return out


def decode(schema_name: str, data: bytes) -> Any:
    """Payload of a protobuf-encoded Foxglove message (see the module docstring)."""
    cls = MESSAGE_TYPES[schema_name]
    msg = cls.FromString(data)
    if isinstance(msg, RawImage):
        return _raw_image_array(msg)
    if isinstance(msg, CompressedImage):
        # the project's one decoder: pixel cap before decoding, truncation refused
        return decode_frame_bytes(msg.data, f"a {msg.format!r} CompressedImage", grey=False)
    if isinstance(msg, ImageAnnotations):
        return _annotations_dict(msg)
    if isinstance(msg, PoseInFrame):
        pos = msg.pose.position
        return {"frame_id": msg.frame_id, "q_wxyz": _q_wxyz(msg.pose.orientation),
                "position": np.array([pos.x, pos.y, pos.z])}
    if isinstance(msg, FrameTransforms):
        return {"transforms": [
            {"parent": tf.parent_frame_id, "child": tf.child_frame_id,
             "q_wxyz": _q_wxyz(tf.rotation),
             "translation": np.array([tf.translation.x, tf.translation.y, tf.translation.z])}
            for tf in msg.transforms]}
    assert isinstance(msg, CameraCalibration)
    return {"frame_id": msg.frame_id, "width": msg.width, "height": msg.height,
            "distortion_model": msg.distortion_model, "D": np.array(msg.D, dtype=float),
            "K": np.array(msg.K, dtype=float).reshape(3, 3),
            "R": np.array(msg.R, dtype=float).reshape(3, 3),
            "P": np.array(msg.P, dtype=float).reshape(3, 4)}
