"""Camera images in an MCAP raw log: ``foxglove.CompressedImage`` (protobuf, PNG) per frame
beside the IMU and encoder topics (the project's JSON schemas, docs/log_format.md).

A vision log holds ``/imu`` (``trackfusion.Imu``), ``/odometer`` (``trackfusion.Odometer``) and
one ``/camera/<side>/image`` channel per camera-laser unit. Images are PNG-encoded by OpenCV
(``cv2.imencode``) and wrapped in Foxglove's ``CompressedImage`` message (the
``foxglove-schemas-protobuf`` package), so Foxglove shows them as they are. The MCAP records
are written and read by the ``mcap`` library; only the protobuf schema's FileDescriptorSet is
assembled here (the ``mcap-protobuf-support`` helper would do the same but is not a dependency).
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np

from ..errors import SensorDataError
from ..sensors import schemas

IMU_TOPIC, ODOMETER_TOPIC = "/imu", "/odometer"
IMAGE_SCHEMA = "foxglove.CompressedImage"


def image_topic(side: str) -> str:
    """The image channel of the unit filming rail ``side`` ("left"/"right")."""
    return f"/camera/{side}/image"


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class PngFrames:
    """F grey PNG images of one camera, decoded (``cv2.imdecode``) only when sliced: ``frames[a:b]``
    is the (b - a, H, W) uint8 array, ``frames[i]`` one (H, W) image. The per-frame measurement
    slices batches, so with forked workers each process decodes its own frames (decoding costs
    as much CPU as measuring) and the run never holds every decoded image. ``shape``, ``ndim``
    and ``dtype`` are those of the decoded stack, read from the PNG headers."""

    ndim, dtype = 3, np.dtype(np.uint8)

    def __init__(self, pngs: list[bytes], height_px: int, width_px: int, name: str):
        self.pngs, self.shape, self.name = pngs, (len(pngs), height_px, width_px), name

    def __len__(self) -> int:
        return len(self.pngs)

    def _decode(self, i: int) -> np.ndarray:
        img = cv2.imdecode(np.frombuffer(self.pngs[i], np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.shape != self.shape[1:] or img.dtype != np.uint8:
            raise SensorDataError(f"{self.name}: frame {i}: the PNG does not decode to its header's grey image")
        return img

    def __getitem__(self, key):
        if isinstance(key, slice):
            idx = range(*key.indices(len(self)))
            out = np.empty((len(idx), *self.shape[1:]), np.uint8)
            for j, i in enumerate(idx):
                out[j] = self._decode(i)
            return out
        return self._decode(int(key))


def png_header(data: bytes) -> tuple[int, int, int, int] | None:
    """(width, height, bit depth, colour type) of a PNG's IHDR chunk, None when not a PNG."""
    if len(data) < 26 or data[:8] != PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), data[24], data[25]


def frames_of(pngs: list[bytes], name: str) -> PngFrames:
    """The PNG frames of one channel, their headers checked: 8-bit grey, all of one size."""
    heads = {png_header(d) for d in pngs}
    if None in heads:
        raise SensorDataError(f"{name}: a message is not a PNG image")
    if len(heads) != 1 or next(iter(heads))[2:] != (8, 0):
        raise SensorDataError(f"{name}: frames must be 8-bit grey PNG images of one size, found {sorted(heads)}")
    w, h, _, _ = next(iter(heads))
    return PngFrames(pngs, h, w, name)


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


def write_vision_log(path: str | Path, t_imu_s: np.ndarray, gyro_b: np.ndarray, accel_b: np.ndarray,
                     encoder_m: np.ndarray, tick_m: float, t_frame_s: np.ndarray, images: dict,
                     metadata: dict | None = None) -> None:
    """Write ``path``: IMU (N,) times [s], gyro (N, 3) [rad/s], specific force (N, 3) [m/s^2],
    encoder distance (N,) [m] in ticks of ``tick_m``, and per side the images (F, H, W) uint8 at
    ``t_frame_s`` (F,) [s]; zstd chunks, messages in time order per channel, ``metadata`` as one
    record ``trackfusion`` (``{"json": text}``)."""
    from mcap.writer import CompressionType, Writer
    from ..sensors.fileio import atomic_path
    ns_imu = np.round(np.asarray(t_imu_s) * 1e9).astype(np.int64)
    ns_frame = np.round(np.asarray(t_frame_s) * 1e9).astype(np.int64)
    imu_tpl = schemas.CANONICAL[schemas.IMU].template
    odo_tpl = schemas.CANONICAL[schemas.ODOMETER].template
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="trackfusion")
        ids = {}
        for topic, name in ((IMU_TOPIC, schemas.IMU), (ODOMETER_TOPIC, schemas.ODOMETER)):
            sid = w.register_schema(name=name, encoding="jsonschema", data=schemas.schema_bytes(name))
            ids[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        pb = w.register_schema(name=IMAGE_SCHEMA, encoding="protobuf", data=_descriptor_set())
        for side in images:
            ids[side] = w.register_channel(topic=image_topic(side), message_encoding="protobuf", schema_id=pb)
        ticks = np.round(np.asarray(encoder_m) / tick_m).astype(np.int64)
        for i, ns in enumerate(ns_imu.tolist()):
            w.add_message(ids[IMU_TOPIC], ns, (imu_tpl % (*gyro_b[i].tolist(), *accel_b[i].tolist())).encode(), ns, i)
            w.add_message(ids[ODOMETER_TOPIC], ns, (odo_tpl % (float(encoder_m[i]), int(ticks[i]))).encode(), ns, i)
        for i, ns in enumerate(ns_frame.tolist()):
            for side, frames in images.items():
                w.add_message(ids[side], ns, encode_png_message(frames[i], ns, f"camera_{side}"), ns, i)
        if metadata:
            w.add_metadata("trackfusion", {"json": json.dumps(metadata)})
        w.finish()


def read_vision_log(path: str | Path, sides: tuple[str, ...] = ("left", "right")) -> dict:
    """Read a vision log: ``t_imu_s`` (N,), ``gyro_b``, ``accel_b`` (N, 3), ``encoder_m`` (N,),
    ``t_frame_s`` (F,) and per side ``images`` (:class:`PngFrames`, decoded when sliced).
    Raises :class:`SensorDataError` naming the file and topic for a missing channel, an image
    that is not an 8-bit grey PNG, or frames of the two cameras not at the same times."""
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap.reader import make_reader
    p = Path(path)
    imu, odo, t_imu, t_odo = [], [], [], []
    frames: dict = {s: ([], []) for s in sides}
    topics = {image_topic(s): s for s in sides}
    with open(p, "rb") as fh:
        for _schema, channel, message in make_reader(fh).iter_messages():
            if channel.topic == IMU_TOPIC:
                d = json.loads(message.data)
                imu.append([d["angular_velocity"][a] for a in "xyz"] + [d["linear_acceleration"][a] for a in "xyz"])
                t_imu.append(message.log_time)
            elif channel.topic == ODOMETER_TOPIC:
                odo.append(json.loads(message.data)["distance_m"])
                t_odo.append(message.log_time)
            elif channel.topic in topics:
                msg = CompressedImage.FromString(message.data)
                if msg.format != "png":
                    raise SensorDataError(f"{p}: {channel.topic}: message {message.sequence}: format "
                                          f"{msg.format!r}, expected 'png'")
                frames[topics[channel.topic]][0].append(message.log_time)
                frames[topics[channel.topic]][1].append(msg.data)
    for topic, got in ((IMU_TOPIC, imu), (ODOMETER_TOPIC, odo), *((t, frames[s][1]) for t, s in topics.items())):
        if not got:
            raise SensorDataError(f"{p}: {topic}: no messages (a vision log needs the IMU, the encoder and both cameras)")
    if t_imu != t_odo:
        raise SensorDataError(f"{p}: {ODOMETER_TOPIC}: not at the IMU's times")
    t_frames = [np.asarray(frames[s][0], np.int64) for s in sides]
    if any(not np.array_equal(t, t_frames[0]) for t in t_frames):
        raise SensorDataError(f"{p}: {image_topic(sides[1])}: frames not at the times of {image_topic(sides[0])}")
    a = np.asarray(imu, float)
    return {"t_imu_s": np.asarray(t_imu, np.int64) * 1e-9, "gyro_b": a[:, :3], "accel_b": a[:, 3:],
            "encoder_m": np.asarray(odo, float), "t_frame_s": t_frames[0] * 1e-9,
            "images": {s: frames_of(frames[s][1], f"{p}: {image_topic(s)}") for s in sides}}
