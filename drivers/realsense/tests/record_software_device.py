"""Writes a librealsense .bag with pyrealsense2's software device: depth Z16 + colour RGB8 of a
known pattern, known intrinsics and depth units, so that a test can check what comes back.

    python record_software_device.py OUT.bag [--frames N] [--width W] [--height H] [--fps F]
        [--fx FX --fy FY] [--colour-width CW --colour-height CH --colour-fx CFX --colour-fy CFY]
        [--translation TX TY TZ] [--yaw-deg A] [--scene] [--imu]
        [--depth-distortion MODEL K1 K2 P1 P2 K3] [--colour-distortion MODEL K1 K2 P1 P2 K3]
        [--name NAME --serial SERIAL]

Pixel values (frame i, pixel u, v):
    depth  = 500 + 7*u + 13*v + i            (sensor units)
    colour = (u % 256, v % 256, (11*i) % 256)  RGB
With --scene the depth is a room instead: a wall slanting from 2 m to 3 m across the image, a
box at 0.9 m in front of it, and scattered pixels without depth (0), plus i units per frame.
With --imu a motion module records gyro samples k at 1000 + 5*k ms (200 Hz), values
(0.001*k, -0.002*k, 0.5) rad/s, and accelerometer samples k at 1000 + 10*k ms (100 Hz), values
(0.01*k, -9.81, 0.02) m/s^2, over the video's span; the JSON lists them under "imu".
Timestamps: 1000 + i * 1000 / fps milliseconds, global time domain; frame numbers i + 1.
Depth units 0.00025 m. By default both streams share the intrinsics below and identity
extrinsics, so librealsense's align block maps every depth pixel onto the same colour pixel;
the colour options give the colour stream its own size and focal lengths (principal point near
the centre) and the depth -> colour extrinsics a translation (metres) and a rotation about the
camera's y axis, as a real D435i has.
--name and --serial give the device the camera info a real camera reports (e.g. "Intel
RealSense D435I"); without them the recording's device has no name.
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
    ap.add_argument("--fx", type=float, default=FX)
    ap.add_argument("--fy", type=float, default=FY)
    ap.add_argument("--colour-width", type=int)
    ap.add_argument("--colour-height", type=int)
    ap.add_argument("--colour-fx", type=float)
    ap.add_argument("--colour-fy", type=float)
    ap.add_argument("--translation", type=float, nargs=3, default=[0.0, 0.0, 0.0])
    ap.add_argument("--yaw-deg", type=float, default=0.0)
    ap.add_argument("--scene", action="store_true")
    ap.add_argument("--imu", action="store_true")
    ap.add_argument("--name")
    ap.add_argument("--serial")
    ap.add_argument("--depth-distortion", nargs=6, metavar=("MODEL", "K1", "K2", "P1", "P2", "K3"))
    ap.add_argument("--colour-distortion", nargs=6, metavar=("MODEL", "K1", "K2", "P1", "P2", "K3"))
    a = ap.parse_args()
    w, h = a.width, a.height
    cw, ch = a.colour_width or w, a.colour_height or h

    intr = rs.intrinsics()
    intr.width, intr.height = w, h
    intr.fx, intr.fy = a.fx, a.fy
    intr.ppx, intr.ppy = (w - 1) / 2.0 - 0.75, (h - 1) / 2.0 + 0.25
    intr.model = rs.distortion.none
    intr.coeffs = [0.0] * 5

    def lens_model(given):
        # MODEL is a name of rs.distortion (modified_brown_conrady, inverse_brown_conrady, ...).
        return getattr(rs.distortion, given[0]), [float(c) for c in given[1:]]

    if a.depth_distortion:
        intr.model, intr.coeffs = lens_model(a.depth_distortion)
    same = (cw, ch) == (w, h) and a.colour_fx is None and a.colour_fy is None and not a.colour_distortion
    if same:
        cintr = intr
    else:
        cintr = rs.intrinsics()
        cintr.width, cintr.height = cw, ch
        cintr.fx, cintr.fy = a.colour_fx or a.fx * cw / w, a.colour_fy or a.fy * ch / h
        cintr.ppx, cintr.ppy = (cw - 1) / 2.0 + 0.4, (ch - 1) / 2.0 - 0.3
        cintr.model = rs.distortion.none
        cintr.coeffs = [0.0] * 5
        if a.colour_distortion:
            cintr.model, cintr.coeffs = lens_model(a.colour_distortion)

    dev = rs.software_device()
    if a.name:
        dev.register_info(rs.camera_info.name, a.name)
    if a.serial:
        dev.register_info(rs.camera_info.serial_number, a.serial)
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
    cs.width, cs.height, cs.fps, cs.bpp = cw, ch, a.fps, 3
    cs.fmt, cs.intrinsics = rs.format.rgb8, cintr
    colour_profile = colour_sensor.add_video_stream(cs)

    # Depth -> colour: p_c = R p_d + t, R about y; librealsense stores R column-major.
    yaw = np.radians(a.yaw_deg)
    rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
    t = np.array(a.translation)
    to_colour = rs.extrinsics()
    to_colour.rotation = [float(x) for x in rot.T.reshape(-1)]
    to_colour.translation = [float(x) for x in t]
    to_depth = rs.extrinsics()
    to_depth.rotation = [float(x) for x in rot.reshape(-1)]
    to_depth.translation = [float(x) for x in -rot.T @ t]
    depth_profile.register_extrinsics_to(colour_profile, to_colour)
    colour_profile.register_extrinsics_to(depth_profile, to_depth)
    if a.imu:
        motion_sensor = dev.add_sensor("Motion Module")
        profiles = {}
        for kind, uid, fps in ((rs.stream.gyro, 2, 200), (rs.stream.accel, 3, 100)):
            m = rs.motion_stream()
            m.type, m.index, m.uid, m.fps, m.fmt = kind, 0, uid, fps, rs.format.motion_xyz32f
            profiles[kind] = motion_sensor.add_motion_stream(m)
    dev.create_matcher(rs.matchers.default)

    recorder = rs.recorder(a.out, dev)
    depth_sensor.open(depth_profile)
    colour_sensor.open(colour_profile)
    queue = rs.frame_queue(1024)
    depth_sensor.start(queue)
    colour_sensor.start(queue)
    if a.imu:
        motion_sensor.open([profiles[rs.stream.gyro], profiles[rs.stream.accel]])
        motion_sensor.start(queue)
    imu = {"gyro": [], "accel": []}
    next_motion = {"gyro": 0, "accel": 0}

    def send_motion(until_ms):
        for name, kind, period, value in (
            ("gyro", rs.stream.gyro, 5.0, lambda k: (0.001 * k, -0.002 * k, 0.5)),
            ("accel", rs.stream.accel, 10.0, lambda k: (0.01 * k, -9.81, 0.02)),
        ):
            while T0_MS + next_motion[name] * period < until_ms:
                k = next_motion[name]
                v = rs.vector()
                v.x, v.y, v.z = value(k)
                f = rs.software_motion_frame()
                f.data = v
                f.timestamp = T0_MS + k * period
                f.domain = rs.timestamp_domain.global_time
                f.frame_number = k + 1
                f.profile = profiles[kind].as_motion_stream_profile()
                motion_sensor.on_motion_frame(f)
                # As librealsense stores them (float32).
                imu[name].append([f.timestamp] + [float(np.float32(x)) for x in value(k)])
                next_motion[name] += 1

    vv, uu = np.mgrid[0:h, 0:w].astype(np.int64)
    cvv, cuu = np.mgrid[0:ch, 0:cw].astype(np.int64)
    if a.scene:
        wall = (2.0 + uu / w) / DEPTH_UNITS
        box = (uu >= 0.35 * w) & (uu < 0.6 * w) & (vv >= 0.3 * h) & (vv < 0.7 * h)
        room = np.where(box, 0.9 / DEPTH_UNITS, wall).astype(np.int64)
        room[(7 * uu + 3 * vv) % 53 == 0] = 0
    stamps = []
    for i in range(a.frames):
        stamp = T0_MS + i * 1000.0 / a.fps
        stamps.append(stamp)
        if a.scene:
            depth = np.where(room > 0, room + i, 0).astype("<u2").tobytes()
        else:
            depth = (500 + 7 * uu + 13 * vv + i).astype("<u2").tobytes()
        colour = np.stack([cuu % 256, cvv % 256, np.full_like(cuu, (11 * i) % 256)], axis=-1).astype(np.uint8).tobytes()
        for sensor, profile, pixels, bpp, width in (
            (depth_sensor, depth_profile, depth, 2, w),
            (colour_sensor, colour_profile, colour, 3, cw),
        ):
            f = rs.software_video_frame()
            f.pixels = pixels
            f.stride = width * bpp
            f.bpp = bpp
            f.timestamp = stamp
            f.domain = rs.timestamp_domain.global_time
            f.frame_number = i + 1
            f.profile = profile.as_video_stream_profile()
            if bpp == 2:
                f.depth_units = DEPTH_UNITS
            sensor.on_video_frame(f)
        if a.imu:
            send_motion(stamp + 1000.0 / a.fps)
        time.sleep(1.0 / a.fps)

    time.sleep(0.2)
    depth_sensor.stop()
    colour_sensor.stop()
    depth_sensor.close()
    colour_sensor.close()
    if a.imu:
        motion_sensor.stop()
        motion_sensor.close()
    # The bag's index is written when the recorder is destroyed.
    del recorder
    gc.collect()
    print(json.dumps({
        "frames": a.frames, "width": w, "height": h, "fps": a.fps,
        "fx": intr.fx, "fy": intr.fy, "ppx": intr.ppx, "ppy": intr.ppy,
        "colour": {"width": cw, "height": ch, "fx": cintr.fx, "fy": cintr.fy, "ppx": cintr.ppx, "ppy": cintr.ppy},
        "depth_units": DEPTH_UNITS, "stamps_ms": stamps, "imu": imu,
    }))


if __name__ == "__main__":
    main()
