#!/usr/bin/env python3
"""Writes an MCAP file of ROS 2 messages from a frame dump, for the bag reader's tests.

An implementation of the MCAP format (https://mcap.dev/spec) and of ROS 2 CDR independent of
the reader under test: written from the specifications with Python's standard library, plus
Debian's python3-zstandard and python3-lz4 for compressed chunks (exit 77 when the requested
compression's module is missing, so the caller can skip).

Frame dump (little-endian), as test/ports/replay/bag_fixtures.hpp writes it:
  b"OFDUMP1\\n", u32 count, u32 width, u32 height, f32 fx fy cx cy, then per frame:
  i64 timestamp_us, f32 metres_per_unit, u8 has_pose, 16 f64 T_W_C (row-major), u16 pixels.

With a DUMP ending in .mcap (an unchunked MCAP such as octofuse-replay --record writes), its
schemas, channels and messages are rewritten in the layout and compression asked for.

usage: make_bag.py DUMP OUT.mcap [--compression none|zstd|lz4] [--unchunked] [--overlap]
       [--no-summary]
       [--encoding 16UC1|32FC1|mono16] [--big-endian]
       [--pose tf|odom_tf|odometry|pose_stamped|none]
       [--distortion K1] [--extra-image]
       [--motion single|chain|odometry [--tf-hz HZ] [--tf-offset-ms MS] [--tf2-hz HZ]
        [--tf2-offset-ms MS] [--depth-latency-ms MS] [--tf-end-ms MS]]

--motion replaces the dump's poses by an analytic trajectory (motion_edges) published at its own
rate and offset from the depth stamps, for the test of poses at each image's own stamp.
"""
import argparse
import math
import struct
import sys
import zlib

MAGIC = b"\x89MCAP0\r\n"


def mcap_string(text):
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def record(opcode, body):
    return struct.pack("<BQ", opcode, len(body)) + body


class Cdr:
    """ROS 2 CDR: encapsulation header, then fields aligned to their size after it."""

    def __init__(self, big_endian=False):
        self.e = ">" if big_endian else "<"
        self.buf = bytearray(b"\x00\x00\x00\x00" if big_endian else b"\x00\x01\x00\x00")

    def align(self, n):
        while (len(self.buf) - 4) % n:
            self.buf.append(0)

    def u8(self, v):
        self.buf += struct.pack("B", v)

    def u32(self, v):
        self.align(4)
        self.buf += struct.pack(self.e + "I", v)

    def i32(self, v):
        self.align(4)
        self.buf += struct.pack(self.e + "i", v)

    def f64(self, v):
        self.align(8)
        self.buf += struct.pack(self.e + "d", v)

    def string(self, s):
        data = s.encode() + b"\x00"
        self.u32(len(data))
        self.buf += data

    def bytes(self, data):
        self.u32(len(data))
        self.buf += data

    def header(self, stamp_ns, frame_id):
        self.i32(stamp_ns // 1000000000)
        self.u32(stamp_ns % 1000000000)
        self.string(frame_id)


def quaternion(m):
    """Rotation matrix (3x3 rows) to x, y, z, w."""
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return ((m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s)
    if m[0][0] > m[1][1] and m[0][0] > m[2][2]:
        s = math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2]) * 2
        return (0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s, (m[2][1] - m[1][2]) / s)
    if m[1][1] > m[2][2]:
        s = math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2]) * 2
        return ((m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s, (m[0][2] - m[2][0]) / s)
    s = math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1]) * 2
    return ((m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s, (m[1][0] - m[0][1]) / s)


def read_dump(path):
    with open(path, "rb") as f:
        data = f.read()
    if data[:8] != b"OFDUMP1\n":
        raise SystemExit("make_bag: not a frame dump")
    count, width, height = struct.unpack_from("<III", data, 8)
    fx, fy, cx, cy = struct.unpack_from("<4f", data, 20)
    pos = 36
    frames = []
    for _ in range(count):
        ts_us, mpu, has_pose = struct.unpack_from("<qfB", data, pos)
        pos += 13
        T = struct.unpack_from("<16d", data, pos)
        pos += 128
        n = width * height * 2
        frames.append((ts_us, mpu, has_pose, T, data[pos:pos + n]))
        pos += n
    return width, height, (fx, fy, cx, cy), frames


def image_msg(stamp_ns, width, height, pixels, mpu, encoding, big_endian):
    c = Cdr(big_endian)
    c.header(stamp_ns, "camera_depth")
    c.u32(height)
    c.u32(width)
    c.string(encoding)
    c.u8(1 if big_endian else 0)
    values = struct.unpack("<%dH" % (width * height), pixels)
    e = ">" if big_endian else "<"
    if encoding == "32FC1":
        c.u32(width * 4)
        floats = [v * mpu if v else float("nan") for v in values]
        c.bytes(struct.pack(e + "%df" % len(floats), *floats))
    else:
        c.u32(width * 2)
        c.bytes(struct.pack(e + "%dH" % len(values), *values))
    return bytes(c.buf)


def camera_info_msg(stamp_ns, width, height, k4, distortion):
    fx, fy, cx, cy = k4
    c = Cdr()
    c.header(stamp_ns, "camera_depth")
    c.u32(height)
    c.u32(width)
    c.string("plumb_bob")
    c.u32(5)
    for d in (distortion, 0.0, 0.0, 0.0, 0.0):
        c.f64(d)
    for k in (fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0):
        c.f64(k)
    for r in (1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0):
        c.f64(r)
    for p in (fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0):
        c.f64(p)
    c.u32(0)
    c.u32(0)
    for _ in range(4):
        c.u32(0)
    c.u8(0)
    return bytes(c.buf)


def pose_fields(c, T):
    m = [[T[0], T[1], T[2]], [T[4], T[5], T[6]], [T[8], T[9], T[10]]]
    for v in (T[3], T[7], T[11]):
        c.f64(v)
    for v in quaternion(m):
        c.f64(v)


def tf_msg(transforms):
    c = Cdr()
    c.u32(len(transforms))
    for stamp_ns, parent, child, T in transforms:
        c.header(stamp_ns, parent)
        c.string(child)
        pose_fields(c, T)
    return bytes(c.buf)


def odometry_msg(stamp_ns, T, child="camera_depth"):
    c = Cdr()
    c.header(stamp_ns, "world")
    c.string(child)
    pose_fields(c, T)
    for _ in range(36):
        c.f64(0.0)
    for _ in range(6 + 36):
        c.f64(0.0)
    return bytes(c.buf)


def pose_stamped_msg(stamp_ns, T):
    c = Cdr()
    c.header(stamp_ns, "world")
    pose_fields(c, T)
    return bytes(c.buf)


def png16(width, height, values):
    """A 16-bit grayscale PNG (big-endian samples, filter 0 on every row)."""
    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data +
                struct.pack(">I", zlib.crc32(kind + data)))
    rows = b"".join(b"\x00" + struct.pack(">%dH" % width, *values[y * width:(y + 1) * width])
                    for y in range(height))
    return (b"\x89PNG\r\n\x1a\n" +
            chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def rvl(values):
    """RVL (Wilson 2017): zero runs, then runs of zig-zag deltas, as 3-bit nibbles."""
    words = []
    state = {"word": 0, "nibbles": 0}

    def put_nibble(n):
        state["word"] = (state["word"] << 4) | n
        state["nibbles"] += 1
        if state["nibbles"] == 8:
            words.append(state["word"] & 0xFFFFFFFF)
            state["word"] = 0
            state["nibbles"] = 0

    def vle(v):
        while True:
            n = v & 7
            v >>= 3
            if v:
                n |= 8
            put_nibble(n)
            if not v:
                break

    i, previous = 0, 0
    while i < len(values):
        zeros = 0
        while i < len(values) and values[i] == 0:
            zeros += 1
            i += 1
        vle(zeros)
        j = i
        while j < len(values) and values[j] != 0:
            j += 1
        vle(j - i)
        for v in values[i:j]:
            delta = v - previous
            vle((delta << 1) ^ (delta >> 31) if delta >= 0 else ((-delta) << 1) - 1)
            previous = v
        i = j
    if state["nibbles"]:
        words.append((state["word"] << (4 * (8 - state["nibbles"]))) & 0xFFFFFFFF)
    return struct.pack("<%dI" % len(words), *words)


def compressed_depth_msg(stamp_ns, width, height, pixels, mpu, encoding, codec):
    """sensor_msgs/CompressedImage as compressed_depth_image_transport writes it."""
    values = list(struct.unpack("<%dH" % (width * height), pixels))
    quant_a, quant_b = 0.0, 0.0
    if encoding == "32FC1":
        quant_a = 100.0 * 101.0  # depth_quantization 100, depth_max 10 m (the defaults)
        quant_b = 1.0 - quant_a / 10.0
        values = [int(quant_a / (v * mpu) + quant_b) if v and v * mpu < 10.0 else 0
                  for v in values]
    header = struct.pack("<iff", 0, quant_a, quant_b)
    if codec == "rvl":
        body = struct.pack("<II", width, height) + rvl(values)
    else:
        body = png16(width, height, values)
    c = Cdr()
    c.header(stamp_ns, "camera_depth")
    c.string("%s; compressedDepth %s" % (encoding, codec))
    c.bytes(header + body)
    return bytes(c.buf)


IDENTITY = (1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0)

# --pose odom_tf: a robot's TF tree map -> odom -> body -> camera_depth. The camera sits on the
# body at BODY_CAMERA (a quarter turn about z, 10 cm ahead, 5 cm up); the odometry's frame sits
# in the map at MAP_ODOM (30 degrees about z, at (1, 2, 0)). The bag reader's test uses the
# same numbers: the camera's pose in the odom frame is inverse(MAP_ODOM) * T_W_C.
BODY_CAMERA = (0.0, -1.0, 0, 0.1, 1.0, 0.0, 0, 0, 0, 0, 1.0, 0.05, 0, 0, 0, 1.0)
_C30, _S30 = math.cos(math.radians(30)), math.sin(math.radians(30))
MAP_ODOM = (_C30, -_S30, 0, 1.0, _S30, _C30, 0, 2.0, 0, 0, 1.0, 0, 0, 0, 0, 1.0)


def mat_mul(a, b):
    """4x4 row-major products."""
    return tuple(sum(a[4 * r + k] * b[4 * k + c] for k in range(4))
                 for r in range(4) for c in range(4))


def rigid_inverse(a):
    rt = [a[0], a[4], a[8], a[1], a[5], a[9], a[2], a[6], a[10]]
    t = [a[3], a[7], a[11]]
    ti = [-(rt[3 * r] * t[0] + rt[3 * r + 1] * t[1] + rt[3 * r + 2] * t[2]) for r in range(3)]
    return (rt[0], rt[1], rt[2], ti[0], rt[3], rt[4], rt[5], ti[1], rt[6], rt[7], rt[8], ti[2],
            0, 0, 0, 1.0)


def odom_body(T):
    """odom -> body such that map -> odom -> body -> camera_depth is the camera's pose T."""
    return mat_mul(mat_mul(rigid_inverse(MAP_ODOM), T), rigid_inverse(BODY_CAMERA))


def rot_z(a, p):
    c, s = math.cos(a), math.sin(a)
    return (c, -s, 0, p[0], s, c, 0, p[1], 0, 0, 1.0, p[2], 0, 0, 0, 1.0)


def rot_x(a, p):
    c, s = math.cos(a), math.sin(a)
    return (1.0, 0, 0, p[0], 0, c, -s, p[1], 0, s, c, p[2], 0, 0, 0, 1.0)


def motion_edges(kind, t):
    """The moving edges of --motion at t seconds after the first image: [(parent, child, T)].
    Constant velocities and turn rates, so that the pose between two transforms is their lerp
    and slerp; bag_source_test.cpp has the same numbers. camera_depth hangs from body at
    BODY_CAMERA (static)."""
    if kind == "chain":
        return [("world", "odom", rot_z(0.7 * t, (0.3 * t, 0.0, 0.0))),
                ("odom", "body", rot_x(-1.1 * t, (0.6 * t, 0.4 * t, -0.1 * t)))]
    return [("world", "body", rot_z(1.5 * t, (0.8 * t, -0.5 * t, 0.2 * t)))]


def motion_messages(args, frames):
    """--motion: (log_ns, kind, payload) in log-time order. kind tf or tf_static (payload: the
    transforms), odometry (stamp, T), frame (index: its camera info and image). Each moving edge
    is published alone at its rate from 100 ms before the first image to 100 ms after the last
    (up to --tf-end-ms before the last image when given); images are logged --depth-latency-ms
    after their stamps."""
    t0 = frames[0][0] * 1000
    last = frames[-1][0] * 1000
    out = [(t0 - 100000000, "tf_static", [(t0, "body", "camera_depth", BODY_CAMERA)])]
    rates = [(args.tf_hz, args.tf_offset_ms), (args.tf2_hz, args.tf2_offset_ms)]
    for e, (hz, offset_ms) in enumerate(rates[:len(motion_edges(args.motion, 0.0))]):
        period = int(round(1e9 / hz))
        k = -(100000000 // period) - 1
        while True:
            stamp = t0 + int(round(offset_ms * 1e6)) + k * period
            k += 1
            if stamp > last + 100000000:
                break
            if stamp < t0 - 100000000:
                continue
            if args.tf_end_ms is not None and stamp > last - int(round(args.tf_end_ms * 1e6)):
                break
            parent, child, T = motion_edges(args.motion, (stamp - t0) * 1e-9)[e]
            if args.motion == "odometry":
                out.append((stamp, "odometry", (stamp, T)))
            else:
                out.append((stamp, "tf", [(stamp, parent, child, T)]))
    latency = int(round(args.depth_latency_ms * 1e6))
    for i, frame in enumerate(frames):
        out.append((frame[0] * 1000 + latency, "frame", i))
    out.sort(key=lambda m: m[0])  # stable: ties keep the order above
    return out


def compress(data, how):
    if how == "zstd":
        import zstandard
        return zstandard.ZstdCompressor().compress(data)
    if how == "lz4":
        import lz4.frame
        return lz4.frame.compress(data)
    return data


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dump")
    ap.add_argument("out")
    ap.add_argument("--compression", default="none", choices=["none", "zstd", "lz4"])
    ap.add_argument("--unchunked", action="store_true")
    ap.add_argument("--overlap", action="store_true",
                    help="chunks that overlap in time (camera and pose topics chunked apart)")
    ap.add_argument("--no-summary", action="store_true")
    ap.add_argument("--encoding", default="16UC1", choices=["16UC1", "32FC1", "mono16"])
    ap.add_argument("--big-endian", action="store_true")
    ap.add_argument("--pose", default="tf",
                    choices=["tf", "odom_tf", "odometry", "pose_stamped", "none"])
    ap.add_argument("--distortion", type=float, default=0.0)
    ap.add_argument("--compressed", choices=["png", "rvl"],
                    help="compressedDepth CompressedImage instead of Image")
    ap.add_argument("--extra-image", action="store_true", help="a second (colour) image topic")
    ap.add_argument("--motion", choices=["single", "chain", "odometry"])
    ap.add_argument("--tf-hz", type=float, default=100.0)
    ap.add_argument("--tf-offset-ms", type=float, default=3.0)
    ap.add_argument("--tf2-hz", type=float, default=40.0)
    ap.add_argument("--tf2-offset-ms", type=float, default=7.0)
    ap.add_argument("--depth-latency-ms", type=float, default=0.0)
    ap.add_argument("--tf-end-ms", type=float)
    args = ap.parse_args()
    try:
        if args.compression == "zstd":
            import zstandard  # noqa: F401
        if args.compression == "lz4":
            import lz4.frame  # noqa: F401
    except ImportError:
        sys.exit(77)

    if args.dump.endswith(".mcap"):
        return rewrite(args)
    width, height, k4, frames = read_dump(args.dump)
    if args.motion:
        return write_motion(args, width, height, k4, frames)
    image_type = "CompressedImage" if args.compressed else "Image"
    schemas = [(1, "sensor_msgs/msg/" + image_type), (2, "sensor_msgs/msg/CameraInfo"),
               (3, "tf2_msgs/msg/TFMessage"), (4, "nav_msgs/msg/Odometry"),
               (5, "geometry_msgs/msg/PoseStamped")]
    depth_topic = "/camera/depth/image_raw" + ("/compressedDepth" if args.compressed else "")
    channels = [(1, 1, depth_topic), (2, 2, "/camera/depth/camera_info")]
    if args.pose in ("tf", "odom_tf"):
        channels += [(3, 3, "/tf"), (4, 3, "/tf_static")]
    elif args.pose == "odometry":
        channels += [(3, 4, "/odom")]
    elif args.pose == "pose_stamped":
        channels += [(3, 5, "/camera/pose")]
    if args.extra_image:
        channels += [(9, 1, "/camera/color/image_raw")]

    messages = []  # (channel, log_time_ns, data)
    for i, (ts_us, mpu, has_pose, T, pixels) in enumerate(frames):
        stamp = ts_us * 1000
        if i == 0 and args.pose == "tf":
            # camera_depth hangs from a body frame, which the odometry-like /tf moves.
            messages.append((4, stamp, tf_msg([(stamp, "body", "camera_depth", IDENTITY)])))
        if i == 0 and args.pose == "odom_tf":
            messages.append((4, stamp, tf_msg([(stamp, "body", "camera_depth", BODY_CAMERA)])))
        if has_pose and args.pose == "tf":
            messages.append((3, stamp, tf_msg([(stamp, "world", "body", T)])))
        elif has_pose and args.pose == "odom_tf":
            messages.append((3, stamp, tf_msg([(stamp, "map", "odom", MAP_ODOM),
                                               (stamp, "odom", "body", odom_body(T))])))
        elif has_pose and args.pose == "odometry":
            messages.append((3, stamp, odometry_msg(stamp, T)))
        elif has_pose and args.pose == "pose_stamped":
            messages.append((3, stamp, pose_stamped_msg(stamp, T)))
        messages.append((2, stamp, camera_info_msg(stamp, width, height, k4, args.distortion)))
        if args.extra_image:
            c = Cdr()
            c.header(stamp, "camera_color")
            c.u32(2)
            c.u32(2)
            c.string("rgb8")
            c.u8(0)
            c.u32(6)
            c.bytes(bytes(12))
            messages.append((9, stamp, bytes(c.buf)))
        if args.compressed:
            messages.append((1, stamp, compressed_depth_msg(stamp, width, height, pixels, mpu,
                                                            args.encoding, args.compressed)))
        else:
            messages.append((1, stamp, image_msg(stamp, width, height, pixels, mpu,
                                                 args.encoding, args.big_endian)))

    schema_records = [record(0x03, struct.pack("<H", sid) + mcap_string(name) +
                             mcap_string("ros2msg") + struct.pack("<I", 0))
                      for sid, name in schemas]
    channel_records = [record(0x04, struct.pack("<HH", cid, sid) + mcap_string(topic) +
                              mcap_string("cdr") + struct.pack("<I", 0))
                       for cid, sid, topic in channels]
    write_mcap(args, schema_records, channel_records, messages)


def write_motion(args, width, height, k4, frames):
    schemas = [(1, "sensor_msgs/msg/Image"), (2, "sensor_msgs/msg/CameraInfo"),
               (3, "tf2_msgs/msg/TFMessage"), (4, "nav_msgs/msg/Odometry")]
    channels = [(1, 1, "/camera/depth/image_raw"), (2, 2, "/camera/depth/camera_info"),
                (3, 3, "/tf"), (4, 3, "/tf_static")]
    if args.motion == "odometry":
        channels.append((5, 4, "/odom"))
    messages = []
    for log_ns, kind, payload in motion_messages(args, frames):
        if kind == "tf":
            messages.append((3, log_ns, tf_msg(payload)))
        elif kind == "tf_static":
            messages.append((4, log_ns, tf_msg(payload)))
        elif kind == "odometry":
            messages.append((5, log_ns, odometry_msg(payload[0], payload[1], "body")))
        else:
            ts_us, mpu, _, _, pixels = frames[payload]
            stamp = ts_us * 1000
            messages.append((2, log_ns, camera_info_msg(stamp, width, height, k4, 0.0)))
            messages.append((1, log_ns, image_msg(stamp, width, height, pixels, mpu,
                                                  args.encoding, args.big_endian)))
    schema_records = [record(0x03, struct.pack("<H", sid) + mcap_string(name) +
                             mcap_string("ros2msg") + struct.pack("<I", 0))
                      for sid, name in schemas]
    channel_records = [record(0x04, struct.pack("<HH", cid, sid) + mcap_string(topic) +
                              mcap_string("cdr") + struct.pack("<I", 0))
                       for cid, sid, topic in channels]
    write_mcap(args, schema_records, channel_records, messages)


def rewrite(args):
    """Messages of an unchunked MCAP, written again as asked."""
    with open(args.dump, "rb") as f:
        data = f.read()
    schema_records, channel_records, messages = [], [], []
    pos = 8
    while pos + 9 <= len(data):
        opcode, size = struct.unpack_from("<BQ", data, pos)
        whole = data[pos:pos + 9 + size]
        if opcode == 0x03:
            schema_records.append(whole)
        elif opcode == 0x04:
            channel_records.append(whole)
        elif opcode == 0x05:
            cid, _, log_ns, _ = struct.unpack_from("<HIQQ", data, pos + 9)
            messages.append((cid, log_ns, data[pos + 9 + 22:pos + 9 + size]))
        elif opcode in (0x0F, 0x02):
            break
        pos += 9 + size
    write_mcap(args, schema_records, channel_records, messages)


def write_mcap(args, schema_records, channel_records, messages):
    seq = 0
    out = bytearray(MAGIC)
    out += record(0x01, mcap_string("ros2") + mcap_string("octofuse-test-writer"))
    for r in schema_records + channel_records:
        out += r

    def message_record(cid, log_ns, data):
        nonlocal seq
        seq += 1
        return record(0x05, struct.pack("<HIQQ", cid, seq, log_ns, log_ns) + data)

    chunk_indexes = []
    if args.unchunked:
        for cid, log_ns, data in messages:
            out += message_record(cid, log_ns, data)
    else:
        # A chunk per frame (an image message is larger than rosbag2's default chunk size).
        groups = []
        current = []
        for m in messages:
            current.append(m)
            if m[0] == 1:
                groups.append(current)
                current = []
        if current:
            groups.append(current)
        if args.overlap:
            # Chunks whose times overlap, as a recorder that chunks each topic apart writes them:
            # the camera's topics two frames a chunk, the pose topics three messages a chunk,
            # chunks in the order of their first message (pose chunks first on a tie). In file
            # order the poses of later frames then come before a frame's image.
            # Pose messages are logged a microsecond before their frame (as a TF broadcast
            # arrives before the image it belongs to), so that log-time order is one order.
            camera = [m for m in messages if m[0] in (1, 2, 9)]
            poses = [(m[0], max(m[1] - 1000, 0), m[2])
                     for m in messages if m[0] not in (1, 2, 9)]
            keyed = []
            current = []
            images = 0
            for m in camera:
                current.append(m)
                images += m[0] == 1
                if m[0] == 1 and images % 2 == 0:
                    keyed.append((min(x[1] for x in current), 1, current))
                    current = []
            if current:
                keyed.append((min(x[1] for x in current), 1, current))
            for i in range(0, len(poses), 3):
                group = poses[i:i + 3]
                keyed.append((min(x[1] for x in group), 0, group))
            keyed.sort(key=lambda k: (k[0], k[1]))
            groups = [k[2] for k in keyed]
        for group in groups:
            records = bytearray()
            offsets = {}
            for cid, log_ns, data in group:
                offsets.setdefault(cid, []).append((log_ns, len(records)))
                records += message_record(cid, log_ns, data)
            compression = "" if args.compression == "none" else args.compression
            payload = compress(bytes(records), args.compression)
            start = min(m[1] for m in group)
            end = max(m[1] for m in group)
            chunk_start = len(out)
            body = (struct.pack("<QQQI", start, end, len(records), zlib.crc32(records)) +
                    mcap_string(compression) + struct.pack("<Q", len(payload)) + payload)
            out += record(0x06, body)
            index_start = len(out)
            for cid, entries in offsets.items():
                arr = b"".join(struct.pack("<QQ", t, o) for t, o in entries)
                out += record(0x07, struct.pack("<H", cid) + struct.pack("<I", len(arr)) + arr)
            chunk_indexes.append((start, end, chunk_start, len(out) - index_start,
                                  compression, len(payload), len(records), index_start))
    out += record(0x0F, struct.pack("<I", zlib.crc32(out)))

    summary_start = 0
    if not args.no_summary:
        summary_start = len(out)
        for r in schema_records + channel_records:
            out += r
        counts = {}
        for cid, _, _ in messages:
            counts[cid] = counts.get(cid, 0) + 1
        counts_bytes = b"".join(struct.pack("<HQ", c, n) for c, n in sorted(counts.items()))
        stats = (struct.pack("<QHIIIQQ", len(messages), len(schema_records), len(channel_records), 0, 0,
                             min(m[1] for m in messages), max(m[1] for m in messages)) +
                 struct.pack("<I", len(counts_bytes)) + counts_bytes)
        out += record(0x0B, stats)
        for start, end, offset, index_len, compression, csize, usize, index_start in chunk_indexes:
            out += record(0x08, struct.pack("<QQQQ", start, end, offset, index_start - offset) +
                          struct.pack("<I", 0) + struct.pack("<Q", index_len) +
                          mcap_string(compression) + struct.pack("<QQ", csize, usize))
    out += record(0x02, struct.pack("<QQI", summary_start, 0, 0))
    out += MAGIC
    with open(args.out, "wb") as f:
        f.write(out)


if __name__ == "__main__":
    main()
