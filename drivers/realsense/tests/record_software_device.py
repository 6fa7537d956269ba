"""Writes a librealsense .bag with pyrealsense2's software device: depth Z16 + colour RGB8 of a
known pattern, known intrinsics and depth units, so that a test can check what comes back.

    python record_software_device.py OUT.bag [--frames N] [--width W] [--height H] [--fps F]

Pixel values (frame i, pixel u, v):
    depth  = 500 + 7*u + 13*v + i            (sensor units)
    colour = (u % 256, v % 256, (11*i) % 256)  RGB
Timestamps: 1000 + i * 1000 / fps milliseconds, global time domain; frame numbers i + 1.
Depth units 0.00025 m; both streams share the intrinsics below and identity extrinsics, so
librealsense's align block maps every depth pixel onto the same colour pixel.
Prints one JSON line with what it wrote.
"""

import argparse
import gc
import json
import time

import numpy as np
import pyrealsense2 as rs

FX, FY = 70.5, 71.25
DEPTH_UNITS = 0.00025
T0_MS = 1000.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--width", type=int, default=80)
    ap.add_argument("--height", type=int, default=60)
    ap.add_argument("--fps", type=int, default=30)
    a = ap.parse_args()
    w, h = a.width, a.height

    intr = rs.intrinsics()
    intr.width, intr.height = w, h
    intr.fx, intr.fy = FX, FY
    intr.ppx, intr.ppy = (w - 1) / 2.0 - 0.75, (h - 1) / 2.0 + 0.25
    intr.model = rs.distortion.none
    intr.coeffs = [0.0] * 5

    dev = rs.software_device()
    depth_sensor = dev.add_sensor("Depth")
    colour_sensor = dev.add_sensor("Color")

    vs = rs.video_stream()
    vs.type, vs.index, vs.uid = rs.stream.depth, 0, 0
    vs.width, vs.height, vs.fps, vs.bpp = w, h, a.fps, 2
    vs.fmt, vs.intrinsics = rs.format.z16, intr
    depth_profile = depth_sensor.add_video_stream(vs)
    depth_sensor.add_read_only_option(rs.option.depth_units, DEPTH_UNITS)

    cs = rs.video_stream()
    cs.type, cs.index, cs.uid = rs.stream.color, 0, 1
    cs.width, cs.height, cs.fps, cs.bpp = w, h, a.fps, 3
    cs.fmt, cs.intrinsics = rs.format.rgb8, intr
    colour_profile = colour_sensor.add_video_stream(cs)

    identity = rs.extrinsics()
    identity.rotation = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    identity.translation = [0, 0, 0]
    depth_profile.register_extrinsics_to(colour_profile, identity)
    colour_profile.register_extrinsics_to(depth_profile, identity)
    dev.create_matcher(rs.matchers.default)

    recorder = rs.recorder(a.out, dev)
    depth_sensor.open(depth_profile)
    colour_sensor.open(colour_profile)
    queue = rs.frame_queue(1024)
    depth_sensor.start(queue)
    colour_sensor.start(queue)

    vv, uu = np.mgrid[0:h, 0:w].astype(np.int64)
    stamps = []
    for i in range(a.frames):
        stamp = T0_MS + i * 1000.0 / a.fps
        stamps.append(stamp)
        depth = (500 + 7 * uu + 13 * vv + i).astype("<u2").tobytes()
        colour = np.stack([uu % 256, vv % 256, np.full_like(uu, (11 * i) % 256)], axis=-1).astype(np.uint8).tobytes()
        for sensor, profile, pixels, bpp in (
            (depth_sensor, depth_profile, depth, 2),
            (colour_sensor, colour_profile, colour, 3),
        ):
            f = rs.software_video_frame()
            f.pixels = pixels
            f.stride = w * bpp
            f.bpp = bpp
            f.timestamp = stamp
            f.domain = rs.timestamp_domain.global_time
            f.frame_number = i + 1
            f.profile = profile.as_video_stream_profile()
            if bpp == 2:
                f.depth_units = DEPTH_UNITS
            sensor.on_video_frame(f)
        time.sleep(1.0 / a.fps)

    time.sleep(0.2)
    depth_sensor.stop()
    colour_sensor.stop()
    depth_sensor.close()
    colour_sensor.close()
    # The bag's index is written when the recorder is destroyed.
    del recorder
    gc.collect()
    print(json.dumps({
        "frames": a.frames, "width": w, "height": h, "fps": a.fps,
        "fx": FX, "fy": FY, "ppx": intr.ppx, "ppy": intr.ppy,
        "depth_units": DEPTH_UNITS, "stamps_ms": stamps,
    }))


if __name__ == "__main__":
    main()
