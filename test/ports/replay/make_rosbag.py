#!/usr/bin/env python3
"""Writes a ROS 1 bag (format 2.0) from a frame dump, for the bag reader's tests.

The container is written by Debian's python3-rosbag (ROS 1's own Python writer), independent of
the reader under test; the messages are serialised here in ROS 1 form from the message
definitions (little-endian, packed, strings and variable arrays with a u32 length first, a
sequence number first in every std_msgs/Header). Exit 77 when python3-rosbag (or, for lz4 chunks,
python3-roslz4) is missing, so the caller can skip.

The frame dump is make_bag.py's (its docstring has the layout). With a DUMP ending in .mcap
(an unchunked MCAP of ROS 2 messages, such as octofuse-replay --record writes), its Image,
CameraInfo, PoseStamped and Odometry messages are converted from CDR to ROS 1 and written on
the same topics with their log times.

usage: make_rosbag.py DUMP OUT.bag [--compression none|bz2|lz4] [--chunk-threshold BYTES]
       [--encoding 16UC1|32FC1|mono16] [--pose tf|odom_tf|odometry|pose_stamped|none] [--tum]
       [--distortion K1] [--overlap] [--motion single|chain|odometry ...as make_bag.py]
       make_rosbag.py --batch FILE   (one "DUMP OUT.bag [options]" a line: one interpreter start,
                                      which with rosbag's imports is most of the time, for many)

--tum lays the bag out as TUM RGB-D's own bags are: /camera/depth/image (32FC1),
/camera/rgb/image_color, /camera/rgb/camera_info and /camera/depth/camera_info, /imu, and
tf/tfMessage on /tf with ROS 1's leading-slash frame names (/world -> /kinect -> ... ->
/openni_rgb_optical_frame, the depth images' frame).
"""
import argparse
import shlex
import struct
import sys

from make_bag import (BODY_CAMERA, IDENTITY, MAP_ODOM, motion_messages, odom_body, quaternion,
                      read_dump)

MD5 = {
    "sensor_msgs/Image": "060021388200f6f0f447d0fcd9c64743",
    "sensor_msgs/CameraInfo": "c9a58c1b0b154e0e6da7578cb991d214",
    "sensor_msgs/Imu": "6a62c6daae103f4ff57a132d6f95cec2",
    "tf/tfMessage": "94810edda583a504dfda3829e70d7eec",
    "tf2_msgs/TFMessage": "94810edda583a504dfda3829e70d7eec",
    "nav_msgs/Odometry": "cd5e73d190d741a2f92e81eda573aca7",
    "geometry_msgs/PoseStamped": "d3812c3cbc69362b77dc0b19b345f8f5",
}


class Ros1:
    """ROS 1 serialisation: little-endian, packed."""

    def __init__(self):
        self.buf = bytearray()

    def u8(self, v):
        self.buf += struct.pack("<B", v)

    def u32(self, v):
        self.buf += struct.pack("<I", v)

    def f64(self, v):
        self.buf += struct.pack("<d", v)

    def string(self, s):
        data = s.encode()
        self.u32(len(data))
        self.buf += data

    def bytes(self, data):
        self.u32(len(data))
        self.buf += data

    def header(self, seq, stamp_ns, frame_id):
        self.u32(seq)
        self.u32(stamp_ns // 1000000000)
        self.u32(stamp_ns % 1000000000)
        self.string(frame_id)


def image_msg(seq, stamp_ns, frame, width, height, pixels, mpu, encoding):
    c = Ros1()
    c.header(seq, stamp_ns, frame)
    c.u32(height)
    c.u32(width)
    c.string(encoding)
    c.u8(0)
    values = struct.unpack("<%dH" % (width * height), pixels)
    if encoding == "32FC1":
        c.u32(width * 4)
        floats = [v * mpu if v else float("nan") for v in values]
        c.bytes(struct.pack("<%df" % len(floats), *floats))
    else:
        c.u32(width * 2)
        c.bytes(pixels)
    return bytes(c.buf)


def camera_info_msg(seq, stamp_ns, frame, width, height, k4, distortion):
    fx, fy, cx, cy = k4
    c = Ros1()
    c.header(seq, stamp_ns, frame)
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
    for _ in range(6):  # binning_x, binning_y, roi x_offset, y_offset, height, width
        c.u32(0)
    c.u8(0)  # roi.do_rectify
    return bytes(c.buf)


def pose_fields(c, T):
    m = [[T[0], T[1], T[2]], [T[4], T[5], T[6]], [T[8], T[9], T[10]]]
    for v in (T[3], T[7], T[11]):
        c.f64(v)
    for v in quaternion(m):
        c.f64(v)


def tf_msg(transforms):
    c = Ros1()
    c.u32(len(transforms))
    for stamp_ns, parent, child, T in transforms:
        c.header(0, stamp_ns, parent)
        c.string(child)
        pose_fields(c, T)
    return bytes(c.buf)


def odometry_msg(seq, stamp_ns, T, child="camera_depth"):
    c = Ros1()
    c.header(seq, stamp_ns, "world")
    c.string(child)
    pose_fields(c, T)
    for _ in range(36 + 6 + 36):
        c.f64(0.0)
    return bytes(c.buf)


def pose_stamped_msg(seq, stamp_ns, T):
    c = Ros1()
    c.header(seq, stamp_ns, "world")
    pose_fields(c, T)
    return bytes(c.buf)


def imu_msg(seq, stamp_ns):
    c = Ros1()
    c.header(seq, stamp_ns, "/imu")
    for _ in range(4 + 9 + 3 + 9 + 3 + 9):
        c.f64(0.0)
    return bytes(c.buf)


class CdrReader:
    """ROS 2 CDR, little-endian: fields aligned to their size after the 4-byte header."""

    def __init__(self, data):
        if data[:2] != b"\x00\x01":
            raise SystemExit("make_rosbag: only little-endian CDR")
        self.data = data
        self.pos = 4

    def take(self, fmt, size):
        self.pos += (size - (self.pos - 4) % size) % size
        v = struct.unpack_from("<" + fmt, self.data, self.pos)[0]
        self.pos += size
        return v

    def u8(self):
        return self.take("B", 1)

    def u32(self):
        return self.take("I", 4)

    def f64(self):
        return self.take("d", 8)

    def string(self):
        n = self.u32()
        s = self.data[self.pos:self.pos + n - 1].decode()
        self.pos += n
        return s

    def bytes(self):
        n = self.u32()
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def header(self, out, seq):
        sec = self.take("i", 4)
        nsec = self.u32()
        out.header(seq, sec * 1000000000 + nsec, self.string())


def ros1_from_cdr(type_name, data, seq):
    """A ROS 2 message of the types --record writes, serialised again for ROS 1."""
    c = CdrReader(data)
    out = Ros1()
    c.header(out, seq)
    if type_name == "sensor_msgs/Image":
        out.u32(c.u32())  # height
        out.u32(c.u32())  # width
        out.string(c.string())
        out.u8(c.u8())
        out.u32(c.u32())  # step
        out.bytes(c.bytes())
    elif type_name == "sensor_msgs/CameraInfo":
        out.u32(c.u32())
        out.u32(c.u32())
        out.string(c.string())
        n = c.u32()
        out.u32(n)
        for _ in range(n + 9 + 9 + 12):
            out.f64(c.f64())
        for _ in range(6):
            out.u32(c.u32())
        out.u8(c.u8())
    elif type_name == "geometry_msgs/PoseStamped":
        for _ in range(7):
            out.f64(c.f64())
    elif type_name == "nav_msgs/Odometry":
        out.string(c.string())  # child_frame_id
        for _ in range(7 + 36 + 6 + 36):
            out.f64(c.f64())
    else:
        return None
    return bytes(out.buf)


def convert_mcap(args, write):
    """The messages of an unchunked MCAP, as ROS 1 messages."""
    with open(args.dump, "rb") as f:
        data = f.read()
    schemas, channels, seqs = {}, {}, {}
    pos = 8
    while pos + 9 <= len(data):
        opcode, size = struct.unpack_from("<BQ", data, pos)
        body = data[pos + 9:pos + 9 + size]
        if opcode == 0x03:
            sid, n = struct.unpack_from("<HI", body, 0)
            schemas[sid] = body[6:6 + n].decode().replace("/msg/", "/")
        elif opcode == 0x04:
            cid, sid, n = struct.unpack_from("<HHI", body, 0)
            channels[cid] = (body[8:8 + n].decode(), schemas[sid])
        elif opcode == 0x05:
            cid, _, log_ns, _ = struct.unpack_from("<HIQQ", body, 0)
            topic, type_name = channels[cid]
            seqs[cid] = seqs.get(cid, -1) + 1
            message = ros1_from_cdr(type_name, body[22:], seqs[cid])
            if message is not None:
                write(topic, type_name, message, log_ns)
        elif opcode in (0x0F, 0x02):
            break
        pos += 9 + size


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("dump")
    ap.add_argument("out")
    ap.add_argument("--compression", default="none", choices=["none", "bz2", "lz4"])
    ap.add_argument("--chunk-threshold", type=int, default=768 * 1024)
    ap.add_argument("--encoding", default="16UC1", choices=["16UC1", "32FC1", "mono16"])
    ap.add_argument("--pose", default="tf",
                    choices=["tf", "odom_tf", "odometry", "pose_stamped", "none"])
    ap.add_argument("--tum", action="store_true")
    ap.add_argument("--overlap", action="store_true",
                    help="pose messages written ahead of the frames they belong to")
    ap.add_argument("--distortion", type=float, default=0.0)
    ap.add_argument("--motion", choices=["single", "chain", "odometry"])
    ap.add_argument("--tf-hz", type=float, default=100.0)
    ap.add_argument("--tf-offset-ms", type=float, default=3.0)
    ap.add_argument("--tf2-hz", type=float, default=40.0)
    ap.add_argument("--tf2-offset-ms", type=float, default=7.0)
    ap.add_argument("--depth-latency-ms", type=float, default=0.0)
    ap.add_argument("--tf-end-ms", type=float)
    args = ap.parse_args(argv)
    try:
        import genpy
        import rosbag
        if args.compression == "lz4":
            import roslz4  # noqa: F401
    except ImportError:
        sys.exit(77)

    class Type:
        """What rosbag's raw write needs of a message class."""

        def __init__(self, name):
            self._type = name
            self._md5sum = MD5[name]
            self._full_text = "# %s, serialised by make_rosbag.py\n" % name

    def write(bag, topic, type_name, data, stamp_ns):
        t = genpy.Time(stamp_ns // 1000000000, stamp_ns % 1000000000)
        bag.write(topic, (type_name, data, MD5[type_name], Type(type_name)), t, raw=True)

    if args.dump.endswith(".mcap"):
        compression = {"none": rosbag.Compression.NONE, "bz2": rosbag.Compression.BZ2,
                       "lz4": rosbag.Compression.LZ4}[args.compression]
        with rosbag.Bag(args.out, "w", compression=compression,
                        chunk_threshold=args.chunk_threshold) as bag:
            convert_mcap(args, lambda *m: write(bag, *m))
        return
    width, height, k4, frames = read_dump(args.dump)
    compression = {"none": rosbag.Compression.NONE, "bz2": rosbag.Compression.BZ2,
                   "lz4": rosbag.Compression.LZ4}[args.compression]
    held = []  # --overlap: (topic, type, data, stamp), written at the end in another order

    def put(bag, topic, type_name, data, stamp_ns):
        if args.overlap:
            held.append((topic, type_name, data, stamp_ns))
        else:
            write(bag, topic, type_name, data, stamp_ns)

    if args.motion:
        with rosbag.Bag(args.out, "w", compression=compression,
                        chunk_threshold=args.chunk_threshold) as bag:
            write_motion(args, frames, width, height, k4, lambda *m: write(bag, *m))
        return
    with rosbag.Bag(args.out, "w", compression=compression,
                    chunk_threshold=args.chunk_threshold) as bag:
        write_frames(args, frames, width, height, k4, lambda *m: put(bag, *m))
        if args.overlap:
            # As make_bag.py --overlap: the camera's messages two frames a group, the pose topics
            # three messages a group, groups in the order of their first message (poses first
            # on a tie); with a small --chunk-threshold the chunks overlap in time.
            camera = [m for m in held if m[0].startswith("/camera/")]
            # Logged a microsecond before their frame, as make_bag.py --overlap does.
            poses = [m[:3] + (max(m[3] - 1000, 0),)
                     for m in held if not m[0].startswith("/camera/")]
            keyed, current, images = [], [], 0
            for m in camera:
                current.append(m)
                if m[1] == "sensor_msgs/Image" and "depth" in m[0]:
                    images += 1
                    if images % 2 == 0:
                        keyed.append((current[0][3], 1, current))
                        current = []
            if current:
                keyed.append((current[0][3], 1, current))
            for i in range(0, len(poses), 3):
                keyed.append((poses[i][3], 0, poses[i:i + 3]))
            keyed.sort(key=lambda k: (k[0], k[1]))
            for _, _, group in keyed:
                for m in group:
                    write(bag, *m)


def write_motion(args, frames, width, height, k4, write):
    """make_bag.py's --motion messages in ROS 1 form, /tf_static included."""
    seq = 0
    for log_ns, kind, payload in motion_messages(args, frames):
        if kind in ("tf", "tf_static"):
            write("/" + kind, "tf2_msgs/TFMessage", tf_msg(payload), log_ns)
        elif kind == "odometry":
            write("/odom", "nav_msgs/Odometry", odometry_msg(seq, payload[0], payload[1], "body"),
                  log_ns)
            seq += 1
        else:
            ts_us, mpu, _, _, pixels = frames[payload]
            stamp = ts_us * 1000
            write("/camera/depth/camera_info", "sensor_msgs/CameraInfo",
                  camera_info_msg(payload, stamp, "camera_depth", width, height, k4, 0.0), log_ns)
            write("/camera/depth/image_raw", "sensor_msgs/Image",
                  image_msg(payload, stamp, "camera_depth", width, height, pixels, mpu,
                            args.encoding), log_ns)


def write_frames(args, frames, width, height, k4, write):
    """The messages of the dump's frames, in time order, through write(topic, type, data, ns)."""
    encoding = "32FC1" if args.tum else args.encoding
    depth_topic = "/camera/depth/image" if args.tum else "/camera/depth/image_raw"
    frame = "/openni_rgb_optical_frame" if args.tum else "camera_depth"
    tf_type = "tf/tfMessage" if args.tum else "tf2_msgs/TFMessage"

    for i, (ts_us, mpu, has_pose, T, pixels) in enumerate(frames):
        stamp = ts_us * 1000
        if args.tum:
            # The mocap's /world -> /kinect, then the Kinect's fixed frames down to the optical
            # one, all on /tf as ROS 1 recorded them.
            fixed = [(stamp, "/kinect", "/openni_camera", IDENTITY),
                     (stamp, "/openni_camera", "/openni_rgb_frame", IDENTITY),
                     (stamp, "/openni_rgb_frame", frame, IDENTITY)]
            moving = [(stamp, "/world", "/kinect", T)] if has_pose else []
            write("/tf", tf_type, tf_msg(moving + fixed), stamp)
            write("/imu", "sensor_msgs/Imu", imu_msg(i, stamp), stamp)
        elif args.pose == "tf":
            transforms = [(stamp, "body", frame, IDENTITY)]
            if has_pose:
                transforms.insert(0, (stamp, "world", "body", T))
            write("/tf", tf_type, tf_msg(transforms), stamp)
        elif args.pose == "odom_tf":
            # ROS 1 bags keep static transforms on /tf too, repeated.
            transforms = [(stamp, "/body", frame, BODY_CAMERA)]
            if has_pose:
                transforms = [(stamp, "/map", "/odom", MAP_ODOM),
                              (stamp, "/odom", "/body", odom_body(T))] + transforms
            write("/tf", tf_type, tf_msg(transforms), stamp)
        elif has_pose and args.pose == "odometry":
            write("/odom", "nav_msgs/Odometry", odometry_msg(i, stamp, T), stamp)
        elif has_pose and args.pose == "pose_stamped":
            write("/camera/pose", "geometry_msgs/PoseStamped",
                  pose_stamped_msg(i, stamp, T), stamp)
        info = camera_info_msg(i, stamp, frame, width, height, k4, args.distortion)
        if args.tum:
            write("/camera/rgb/camera_info", "sensor_msgs/CameraInfo", info, stamp)
            colour = Ros1()
            colour.header(i, stamp, frame)
            for v in (2, 2):
                colour.u32(v)
            colour.string("rgb8")
            colour.u8(0)
            colour.u32(6)
            colour.bytes(bytes(12))
            write("/camera/rgb/image_color", "sensor_msgs/Image", bytes(colour.buf),
                  stamp)
        write("/camera/depth/camera_info", "sensor_msgs/CameraInfo", info, stamp)
        write(depth_topic, "sensor_msgs/Image",
              image_msg(i, stamp, frame, width, height, pixels, mpu, encoding), stamp)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--batch":
        with open(sys.argv[2]) as batch:
            for line in batch:
                if line.strip():
                    main(shlex.split(line))
    else:
        main(sys.argv[1:])
