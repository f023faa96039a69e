"""Camera images in an MCAP raw log: ``foxglove.CompressedImage`` (protobuf, PNG) or ROS 2
``sensor_msgs/msg/Image`` (CDR, raw ``mono8``) per frame beside the IMU and encoder topics (the
project's JSON schemas, docs/log_format.md).

A vision log holds ``/imu`` (``trackfusion.Imu``), ``/odometer`` (``trackfusion.Odometer``) and
one ``/camera/<side>/image`` channel per camera-laser unit. Each image channel is one of:

* ``png``: PNG-encoded by OpenCV (``cv2.imencode``) and wrapped in Foxglove's ``CompressedImage``
  message (the ``foxglove-schemas-protobuf`` package); decoded when the frames are sliced (about
  2 ms of CPU per noisy 640 x 400 frame);
* ``raw``: ``sensor_msgs/msg/Image`` (``mono8``, one byte a pixel, rows ``step`` bytes apart),
  serialised and read by ``rosbags`` (schema encoding ``ros2msg``, message encoding ``cdr``); the
  pixels are a view of the message, nothing to decode; the MCAP chunks are lz4-compressed
  (fast to decompress, about 1.7 times the size of the PNG log).

Foxglove shows both as they are. The MCAP records are written and read by the ``mcap`` library;
only the protobuf schema's FileDescriptorSet is assembled here (the ``mcap-protobuf-support``
helper would do the same but is not a dependency).
"""

from __future__ import annotations

import json
import struct
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np

from ..errors import SensorDataError
from ..sensors import schemas

IMU_TOPIC, ODOMETER_TOPIC = "/imu", "/odometer"
IMAGE_SCHEMA = "foxglove.CompressedImage"
RAW_IMAGE_SCHEMA = "sensor_msgs/msg/Image"
#: the log's image encodings (``write_vision_log``'s ``image_encoding``)
IMAGE_ENCODINGS = ("png", "raw")


def image_topic(side: str) -> str:
    """The image channel of the unit filming rail ``side`` ("left"/"right")."""
    return f"/camera/{side}/image"


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class LogFrames:
    """F grey images of one camera channel, read (and decoded) only when sliced: ``frames[a:b]``
    is the (b - a, H, W) uint8 array, ``frames[i]`` one (H, W) image. ``messages`` gives the
    channel's messages as ``(sequence, payload)`` (:class:`ChunkedMessages`, read from the file
    when asked, or a list), ``decode(payload, where)`` the (H, W) pixels of one. The per-frame
    measurement slices batches, so with forked workers each process reads and decodes its own
    frames (PNG decoding costs as much CPU as measuring; nothing is pickled between processes)
    and the run never holds every image. A message that does not decode to an (H, W) grey image
    raises :class:`SensorDataError` naming the file, topic and record."""

    ndim, dtype = 3, np.dtype(np.uint8)

    def __init__(self, messages, height_px: int, width_px: int, name: str, decode):
        self.messages, self.shape, self.name, self.decode = messages, (len(messages), height_px, width_px), name, decode

    def __len__(self) -> int:
        return self.shape[0]

    def _read(self, idx: range) -> np.ndarray:
        out = np.empty((len(idx), *self.shape[1:]), np.uint8)
        got = self.messages.read(idx) if isinstance(self.messages, ChunkedMessages) else [self.messages[i] for i in idx]
        for j, (seq, payload) in enumerate(got):
            where = f"{self.name}: message {seq}"
            img = self.decode(payload, where)
            if img.shape != self.shape[1:] or img.dtype != np.uint8:
                raise SensorDataError(f"{where}: a {'x'.join(map(str, img.shape[::-1]))} px {img.dtype} image, the "
                                      f"channel's are {self.shape[2]}x{self.shape[1]} px 8-bit grey")
            out[j] = img
        return out

    def __getitem__(self, key):
        if isinstance(key, slice):
            return self._read(range(*key.indices(len(self))))
        return self._read(range(int(key), int(key) + 1))[0]


class ChunkedMessages:
    """Where the messages of one channel of an indexed MCAP file lie, in log-time order: the
    chunk's offset in the file and the message record's offset in the uncompressed chunk (from
    the chunk indexes and message indexes, nothing decompressed). :meth:`read` reads messages;
    the chunks (decompressed by the ``mcap`` library) are kept in a small per-process cache, so
    channels whose messages share chunks (the two cameras) decompress each once."""

    def __init__(self, path: Path, chunk_offsets: np.ndarray, record_offsets: np.ndarray):
        self.path, self.chunk_offsets, self.record_offsets = path, chunk_offsets, record_offsets

    def __len__(self) -> int:
        return len(self.chunk_offsets)

    def read(self, idx: range) -> list[tuple[int, memoryview]]:
        """``(sequence, payload)`` of the messages ``idx`` (views of the cached chunks)."""
        from mcap.opcode import Opcode
        out = []
        with open(self.path, "rb") as fh:
            for i in idx:
                data = _chunk_data(fh, self.path, int(self.chunk_offsets[i]))
                at = int(self.record_offsets[i])
                # MCAP Message record: opcode, length (u64); channel (u16), sequence (u32), log
                # and publish time (u64 each), then the payload (a view: no copy)
                op, length, _channel, sequence = (struct.unpack_from("<BQHI", data, at) if at + 15 <= len(data)
                                                  else (None, 0, 0, 0))
                if op != Opcode.MESSAGE or length < 22 or at + 9 + length > len(data):
                    raise SensorDataError(f"{self.path}: the message index of the chunk at byte {self.chunk_offsets[i]} "
                                          f"points at no message record (offset {at})")
                out.append((sequence, data[at + 9 + 22:at + 9 + length]))
        return out


_CHUNKS: OrderedDict = OrderedDict()
_CHUNK_CACHE_BYTES = 96 << 20


def _chunk_data(fh, path: Path, offset: int) -> memoryview:
    """The uncompressed data of the chunk record at ``offset`` of the file ``fh`` (cached)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Chunk
    from mcap.stream_reader import get_chunk_data_stream
    key = (str(path), offset)
    if key in _CHUNKS:
        _CHUNKS.move_to_end(key)
        return _CHUNKS[key]
    fh.seek(offset + 1 + 8)                               # opcode, record length
    try:
        stream, n = get_chunk_data_stream(Chunk.read(ReadDataStream(fh)))
    except Exception as exc:  # noqa: BLE001 (a truncated record, a corrupt zstd or lz4 frame)
        raise SensorDataError(f"{path}: the chunk at byte {offset} does not read ({type(exc).__name__})") from None
    data = memoryview(stream.read(n))
    _CHUNKS[key] = data
    while sum(len(v) for v in _CHUNKS.values()) > _CHUNK_CACHE_BYTES and len(_CHUNKS) > 1:
        _CHUNKS.popitem(last=False)
    return data


def png_pixels(payload: bytes, where: str) -> np.ndarray:
    """The (H, W) pixels of a serialised ``foxglove.CompressedImage`` holding an 8-bit grey PNG
    (``cv2.imdecode``, ``IMREAD_UNCHANGED``: no conversion); :class:`SensorDataError` starting
    with ``where`` otherwise."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    try:
        msg = CompressedImage.FromString(bytes(payload))
    except Exception:  # noqa: BLE001 (protobuf's DecodeError)
        raise SensorDataError(f"{where}: not a foxglove.CompressedImage") from None
    if msg.format != "png":
        raise SensorDataError(f"{where}: format {msg.format!r}, expected 'png'")
    head = png_header(msg.data)
    if head is None or head[2:] != (8, 0):
        raise SensorDataError(f"{where}: not an 8-bit grey PNG image (header {head})")
    img = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SensorDataError(f"{where}: the PNG does not decode")
    return img


@lru_cache(maxsize=1)
def _ros2_types():
    """The ROS 2 Humble type store of ``rosbags`` (made once per process)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_HUMBLE)


def encode_raw_message(image: np.ndarray, t_ns: int, frame_id: str) -> bytes:
    """One grey image (H, W) uint8 as a serialised (CDR) ``sensor_msgs/msg/Image`` (``mono8``)
    stamped ``t_ns``."""
    ts = _ros2_types()
    t = ts.types["builtin_interfaces/msg/Time"](sec=int(t_ns) // 10**9, nanosec=int(t_ns) % 10**9)
    img = np.ascontiguousarray(image, np.uint8)
    msg = ts.types[RAW_IMAGE_SCHEMA](header=ts.types["std_msgs/msg/Header"](stamp=t, frame_id=frame_id),
                                     height=img.shape[0], width=img.shape[1], encoding="mono8", is_bigendian=0,
                                     step=img.shape[1], data=img.ravel())
    return bytes(ts.serialize_cdr(msg, RAW_IMAGE_SCHEMA))


def decode_raw_message(data: bytes, where: str) -> np.ndarray:
    """The (H, W) uint8 pixels (a view of ``data``) of a serialised ``sensor_msgs/msg/Image``;
    :class:`SensorDataError` starting with ``where`` (file, topic, record) when the message does
    not deserialise, is not ``mono8`` or its data is not ``height`` rows of ``step`` bytes."""
    try:
        msg = _ros2_types().deserialize_cdr(data, RAW_IMAGE_SCHEMA)
    except Exception as exc:  # noqa: BLE001 (rosbags raises several kinds on a truncated record)
        raise SensorDataError(f"{where}: not a sensor_msgs/msg/Image ({type(exc).__name__})") from None
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if msg.encoding != "mono8":
        raise SensorDataError(f"{where}: encoding {msg.encoding!r}, expected 'mono8' (8-bit grey)")
    if h < 1 or w < 1 or step < w or msg.data.size != h * step:
        raise SensorDataError(f"{where}: {msg.data.size} bytes of data for {h} rows of {step} bytes "
                              f"({w} px wide)")
    return msg.data.reshape(h, step)[:, :w]


def png_header(data: bytes) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) of a PNG's IHDR chunk, None when not a PNG."""
    if len(data) < 26 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), data[24], data[25]


def _descriptor_set() -> bytes:
    """The FileDescriptorSet of ``foxglove.CompressedImage`` and the files it imports."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from google.protobuf.descriptor_pb2 import FileDescriptorSet
    out, seen = FileDescriptorSet(), set()

    def add(fd) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        fd.CopyToProto(out.file.add())

    add(CompressedImage.DESCRIPTOR.file)
    return out.SerializeToString()


def encode_png_message(image: np.ndarray, t_ns: int, frame_id: str) -> bytes:
    """One grey image (H, W) uint8 as a serialised ``CompressedImage`` (PNG) stamped ``t_ns``."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise SensorDataError(f"{frame_id}: cv2.imencode could not encode an image")
    msg = CompressedImage(frame_id=frame_id, format="png", data=png.tobytes())
    msg.timestamp.FromNanoseconds(int(t_ns))
    return msg.SerializeToString()


@dataclass(frozen=True)
class ImuEncoderSamples:
    """The IMU and the encoder of a vision log, sampled at the same times: ``t_imu_s`` (N,) [s],
    ``gyro_b`` (N, 3) [rad/s], ``accel_b`` (N, 3) specific force [m/s^2], ``encoder_m`` (N,)
    distance [m], counted in ticks of ``tick_m`` [m]."""

    t_imu_s: np.ndarray
    gyro_b: np.ndarray
    accel_b: np.ndarray
    encoder_m: np.ndarray
    tick_m: float


def write_vision_log(path: str | Path, motion: ImuEncoderSamples, t_frame_s: np.ndarray, images: dict,
                     metadata: dict | None = None, image_encoding: str = "png") -> None:
    """Write ``path``: the IMU and encoder samples ``motion`` (``/imu``, ``/odometer``), and per
    side the images (F, H, W) uint8 at ``t_frame_s`` (F,) [s] as ``image_encoding`` (``"png"``:
    ``foxglove.CompressedImage``, ``"raw"``: ``sensor_msgs/msg/Image``); zstd chunks for PNG images, lz4 chunks for raw ones
    (noisy pixels: zstd takes about 0.6 ms of CPU an image to decompress, lz4 0.12 ms, for 45 %
    and 74 % of the size; ``benchmarks/vision_stages.py``), messages in time order per channel, ``metadata`` as one record
    ``trackfusion`` (``{"json": text}``)."""
    from mcap.writer import CompressionType, Writer
    from ..sensors.cdr import msgdef
    from ..sensors.fileio import atomic_path
    if image_encoding not in IMAGE_ENCODINGS:
        raise ValueError(f"image_encoding {image_encoding!r}: one of {', '.join(IMAGE_ENCODINGS)}")
    ns_imu = np.round(np.asarray(motion.t_imu_s) * 1e9).astype(np.int64)
    ns_frame = np.round(np.asarray(t_frame_s) * 1e9).astype(np.int64)
    imu_tpl = schemas.CANONICAL[schemas.IMU].template
    odo_tpl = schemas.CANONICAL[schemas.ODOMETER].template
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD if image_encoding == "png" else CompressionType.LZ4)
        w.start(profile="", library="trackfusion")
        ids = {}
        for topic, name in ((IMU_TOPIC, schemas.IMU), (ODOMETER_TOPIC, schemas.ODOMETER)):
            sid = w.register_schema(name=name, encoding="jsonschema", data=schemas.schema_bytes(name))
            ids[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        if image_encoding == "png":
            sid = w.register_schema(name=IMAGE_SCHEMA, encoding="protobuf", data=_descriptor_set())
            encoding, encode = "protobuf", encode_png_message
        else:
            sid = w.register_schema(name=RAW_IMAGE_SCHEMA, encoding="ros2msg", data=msgdef(RAW_IMAGE_SCHEMA).encode())
            encoding, encode = "cdr", encode_raw_message
        for side in images:
            ids[side] = w.register_channel(topic=image_topic(side), message_encoding=encoding, schema_id=sid)
        gyro_b, accel_b, encoder_m = motion.gyro_b, motion.accel_b, motion.encoder_m
        ticks = np.round(np.asarray(encoder_m) / motion.tick_m).astype(np.int64)
        for i, ns in enumerate(ns_imu.tolist()):
            w.add_message(ids[IMU_TOPIC], ns, (imu_tpl % (*gyro_b[i].tolist(), *accel_b[i].tolist())).encode(), ns, i)
            w.add_message(ids[ODOMETER_TOPIC], ns, (odo_tpl % (float(encoder_m[i]), int(ticks[i]))).encode(), ns, i)
        for i, ns in enumerate(ns_frame.tolist()):
            for side, frames in images.items():
                w.add_message(ids[side], ns, encode(frames[i], ns, f"camera_{side}"), ns, i)
        if metadata:
            w.add_metadata("trackfusion", {"json": json.dumps(metadata)})
        w.finish()


def read_vision_log(path: str | Path, sides: tuple[str, ...] = ("left", "right")) -> dict:
    """Read a vision log: ``t_imu_s`` (N,), ``gyro_b``, ``accel_b`` (N, 3), ``encoder_m`` (N,),
    ``t_frame_s`` (F,) and per side ``images`` (:class:`LogFrames`: read and decoded when sliced;
    ``foxglove.CompressedImage`` PNG or ``sensor_msgs/msg/Image`` by the channel's schema). Of an
    indexed log (a summary with message indexes, what the ``mcap`` writers write) only the IMU
    and encoder chunks and each camera's first frame are read here. Raises
    :class:`SensorDataError` naming the file and topic for a missing channel, an image schema
    it does not read, a first frame that is not an 8-bit grey image (naming the record; the
    others are checked when read), or frames of the two cameras not at the same times."""
    from mcap.reader import make_reader
    p = Path(path)
    imu, odo, t_imu, t_odo = [], [], [], []
    topics = {image_topic(s): s for s in sides}
    with open(p, "rb") as fh:
        reader = make_reader(fh)
        for _schema, channel, message in reader.iter_messages(topics=[IMU_TOPIC, ODOMETER_TOPIC]):
            if channel.topic == IMU_TOPIC:
                d = json.loads(message.data)
                imu.append([d["angular_velocity"][a] for a in "xyz"] + [d["linear_acceleration"][a] for a in "xyz"])
                t_imu.append(message.log_time)
            else:
                odo.append(json.loads(message.data)["distance_m"])
                t_odo.append(message.log_time)
        channels = _image_channels(p, reader.get_summary(), topics)
        images, times = {}, {}
        for topic, (schema_name, t_ns, messages) in channels.items():
            times[topic] = t_ns
            _require_messages(p, topic, messages)
            images[topics[topic]] = _frames(messages, f"{p}: {topic}", schema_name)
    for topic, got in ((IMU_TOPIC, imu), (ODOMETER_TOPIC, odo)):
        _require_messages(p, topic, got)
    if t_imu != t_odo:
        raise SensorDataError(f"{p}: {ODOMETER_TOPIC}: not at the IMU's times")
    t_frames = [times[image_topic(s)] for s in sides]
    if any(not np.array_equal(t, t_frames[0]) for t in t_frames):
        raise SensorDataError(f"{p}: {image_topic(sides[1])}: frames not at the times of {image_topic(sides[0])}")
    a = np.asarray(imu, float)
    return {"t_imu_s": np.asarray(t_imu, np.int64) * 1e-9, "gyro_b": a[:, :3], "accel_b": a[:, 3:],
            "encoder_m": np.asarray(odo, float), "t_frame_s": t_frames[0] * 1e-9, "images": images}


def _require_messages(p: Path, topic: str, messages) -> None:
    """:class:`SensorDataError` naming ``p`` and ``topic`` when ``messages`` is empty."""
    if not len(messages):
        raise SensorDataError(f"{p}: {topic}: no messages (a vision log needs the IMU, the encoder and both cameras)")


def _image_channels(p: Path, summary, topics: dict) -> dict:
    """Per image topic: its schema name, its messages' log times (F,) [ns] and the messages
    (:class:`ChunkedMessages` from the message indexes of an indexed log; else every message
    read, in log-time order)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import MessageIndex
    from mcap.reader import make_reader
    found = {c.topic: (cid, c) for cid, c in (summary.channels.items() if summary else ()) if c.topic in topics}
    names = {t: (summary.schemas[c.schema_id].name if c.schema_id in summary.schemas else "")
             for t, (_, c) in found.items()}
    indexed = summary is not None and bool(summary.chunk_indexes) and all(
        ci.message_index_offsets for ci in summary.chunk_indexes)
    out = {}
    if indexed:
        with open(p, "rb") as fh:
            for topic in topics:
                cid = found.get(topic, (None,))[0]
                rows = []
                for ci in summary.chunk_indexes:
                    if cid in ci.message_index_offsets:
                        fh.seek(ci.message_index_offsets[cid] + 1 + 8)       # opcode, record length
                        rows += [(t, ci.chunk_start_offset, o) for t, o in MessageIndex.read(ReadDataStream(fh)).records]
                r = np.array(sorted(rows), np.int64).reshape(-1, 3)
                out[topic] = (names.get(topic, ""), r[:, 0], ChunkedMessages(p, r[:, 1], r[:, 2]))
        return out
    got: dict = {t: [] for t in topics}
    with open(p, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=list(topics)):
            names[channel.topic] = schema.name if schema is not None else ""
            got[channel.topic].append((message.log_time, message.sequence, message.data))
    for topic, msgs in got.items():
        out[topic] = (names.get(topic, ""), np.array([m[0] for m in msgs], np.int64), [m[1:] for m in msgs])
    return out


def _frames(messages, name: str, schema_name: str) -> LogFrames:
    """The frames of one image channel, their size from the first one."""
    decoders = {IMAGE_SCHEMA: png_pixels, RAW_IMAGE_SCHEMA: decode_raw_message}
    if schema_name not in decoders:
        raise SensorDataError(f"{name}: schema {schema_name!r}, expected {IMAGE_SCHEMA} or {RAW_IMAGE_SCHEMA}")
    seq, payload = (messages.read(range(1)) if isinstance(messages, ChunkedMessages) else messages[:1])[0]
    img = decoders[schema_name](payload, f"{name}: message {seq}")
    if img.ndim != 2 or img.dtype != np.uint8:
        raise SensorDataError(f"{name}: message {seq}: not an 8-bit grey image")
    return LogFrames(messages, img.shape[0], img.shape[1], name, decoders[schema_name])
