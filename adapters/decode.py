"""ROS 2 message formats -> what a sense takes: text, touch frames, camera images. Each sense
says which message types it reads and decodes its own (``Sense.message_types``,
``Sense.from_message``, using the readers here); the built-in ones (anything else on a mapped
topic is a :class:`RecordingError` naming the topic and the type):

* ``text``: ``std_msgs/msg/String``;
* ``touch``: ``sensor_msgs/msg/Image`` single-channel (``mono16``/``16UC1``: raw sensor units;
  ``32FC1``: raw, or calibrated when in [0, 1]; ``mono8``/``8UC1``: calibrated pressure x 255)
  of the sense's frame shape, and ``std_msgs/msg/{Int16,UInt16,Float32}MultiArray`` holding
  exactly H*W values (row-major; when its ``layout.dim`` names sizes, they must be (H, W),
  or (1, H, W), the sense's frame shape: a 16x16 array is never read as a 32x8 one);
* ``image``: ``sensor_msgs/msg/Image`` (``rgb8``/``bgr8``) and ``sensor_msgs/msg/CompressedImage``
  (any format Pillow reads: jpeg, png).
"""

from __future__ import annotations

import io
from typing import Any

import numpy as np

from tactus_memory.errors import RecordingError

STRING = "std_msgs/msg/String"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
ARRAYS = {
    "std_msgs/msg/Int16MultiArray": np.int16,
    "std_msgs/msg/UInt16MultiArray": np.uint16,
    "std_msgs/msg/Float32MultiArray": np.float32,
}

#: single-channel encodings for touch: (numpy dtype, scale to calibrated pressure or None=raw)
TOUCH_ENCODINGS: dict[str, tuple[str, float | None]] = {
    "mono16": ("u2", None),
    "16UC1": ("u2", None),
    "16SC1": ("i2", None),
    "32FC1": ("f4", None),
    "mono8": ("u1", 255.0),
    "8UC1": ("u1", 255.0),
}
COLOUR_ENCODINGS = ("rgb8", "bgr8")


def default_modality(msgtype: str, encoding: str | None = None) -> str | None:
    """The modality a topic of this type (and image encoding, when known) would map to."""
    if msgtype == STRING:
        return "text"
    if msgtype in ARRAYS:
        return "touch"
    if msgtype == COMPRESSED:
        return "image"
    if msgtype == IMAGE:
        if encoding in COLOUR_ENCODINGS:
            return "image"
        if encoding in TOUCH_ENCODINGS:
            return "touch"
        return None
    return None


def check_supported(topic: str, msgtype: str, sense: str, supported: tuple[str, ...]) -> None:
    """RecordingError unless ``msgtype`` is one the sense reads (its ``message_types``)."""
    if msgtype not in supported:
        raise RecordingError(
            f"topic {topic!r} has type {msgtype!r}, which cannot become {sense} "
            f"(supported for {sense}: {', '.join(supported) or 'none'})"
        )


def stamp_ns(msg: Any) -> int | None:
    """The header stamp in ns when the message has one that is set, else None."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return ns if ns > 0 else None


def _bytes(data: Any) -> bytes:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return bytes(data)
    return np.asarray(data, dtype=np.uint8).tobytes()


def _image_pixels(msg: Any, dtype: np.dtype, channels: int, where: str) -> np.ndarray:
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row = w * channels * dtype.itemsize
    buf = _bytes(msg.data)
    if step < row or len(buf) < h * step:
        raise RecordingError(
            f"{where}: image data is {len(buf)} bytes, too short for {h}x{w} "
            f"{msg.encoding} with step {step}"
        )
    rows = np.frombuffer(buf[: h * step], np.uint8).reshape(h, step)[:, :row]
    return np.ascontiguousarray(rows).view(dtype).reshape(h, w, channels)


def touch_frame(msg: Any, msgtype: str, shape: tuple[int, int], where: str) -> np.ndarray:
    """One touch message -> an (H, W) frame: integer raw units, or float32 (calibrated when a
    mono8 image, else raw or calibrated as the values say)."""
    if msgtype == IMAGE:
        enc = str(msg.encoding)
        if enc not in TOUCH_ENCODINGS:
            raise RecordingError(
                f"{where}: image encoding {enc!r} is not single-channel touch "
                f"(use one of {', '.join(TOUCH_ENCODINGS)})"
            )
        code, scale = TOUCH_ENCODINGS[enc]
        order = ">" if int(msg.is_bigendian) and code != "u1" else "<"
        frame = _image_pixels(msg, np.dtype(order + code), 1, where)[..., 0]
        frame = frame.astype(frame.dtype.newbyteorder("="))
        if scale is not None:
            frame = frame.astype(np.float32) / np.float32(scale)
    elif msgtype in ARRAYS:
        dims = _layout_sizes(msg)
        if dims and tuple(d for d in dims if d != 1) != tuple(s for s in shape if s != 1):
            raise RecordingError(
                f"{where}: {msgtype} layout is {'x'.join(map(str, dims))}, but the sense reads "
                f"{shape[0]}x{shape[1]} frames"
            )
        values = np.asarray(msg.data, dtype=ARRAYS[msgtype]).reshape(-1)
        if values.size != shape[0] * shape[1]:
            raise RecordingError(
                f"{where}: {msgtype} holds {values.size} values, expected "
                f"{shape[0]}x{shape[1]} = {shape[0] * shape[1]}"
            )
        frame = values.reshape(shape)
    else:
        raise RecordingError(f"{where}: type {msgtype!r} is not touch")
    if frame.shape != shape:
        raise RecordingError(f"{where}: touch frame is {frame.shape}, the sense takes {shape}")
    return frame


def _layout_sizes(msg: Any) -> tuple[int, ...]:
    """The sizes a MultiArray's ``layout.dim`` names (empty when it names none)."""
    layout = getattr(msg, "layout", None)
    dims = getattr(layout, "dim", None) or ()
    return tuple(int(getattr(d, "size", 0)) for d in dims if int(getattr(d, "size", 0)) > 0)


def camera_image(msg: Any, msgtype: str, where: str) -> np.ndarray:
    """One image message -> (H, W, 3) uint8 RGB."""
    if msgtype == COMPRESSED:
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(io.BytesIO(_bytes(msg.data))) as im:
                return np.asarray(im.convert("RGB"), dtype=np.uint8)
        except (UnidentifiedImageError, OSError) as exc:
            raise RecordingError(f"{where}: compressed image cannot be decoded: {exc}") from exc
    enc = str(msg.encoding)
    if enc not in COLOUR_ENCODINGS:
        raise RecordingError(f"{where}: image encoding {enc!r} is not rgb8/bgr8")
    px = _image_pixels(msg, np.dtype(np.uint8), 3, where)
    return np.ascontiguousarray(px[..., ::-1] if enc == "bgr8" else px)
