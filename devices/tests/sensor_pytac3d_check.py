#!/usr/bin/env python3
"""Read an emulated Tac3D sensor with the vendor's own client, PyTac3D.

Not run by CI (it needs `pip install pytac3d`). Start a sender that streams to
127.0.0.1:PORT (e.g. `easycalib sim serve --tac3d-to 127.0.0.1:9988`), then:

    python3 devices/tests/sensor_pytac3d_check.py [--port 9988] [--frames 60]

It checks what PyTac3D hands its users: 3D_Positions and 3D_Displacements as
float64 n x 3 arrays, finite values, a string SN, increasing frame indices,
increasing send timestamps; then sends the calibrate command ($C) through
PyTac3D and reports the largest |displacement| before and after it.
Exit status 0 when every check passed.
"""
import argparse
import sys
import time

import numpy as np
import PyTac3D


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, default=9988)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--timeout", type=float, default=20.0)
    a = ap.parse_args()
    sensor = PyTac3D.Sensor(port=a.port, maxQSize=10 * a.frames)
    t0 = time.time()
    frames = []
    calibrated_at = None
    while len(frames) < a.frames and time.time() - t0 < a.timeout:
        f = sensor.getFrame()
        if f is None:
            time.sleep(0.002)
            continue
        frames.append(f)
        if calibrated_at is None and len(frames) == a.frames // 2:
            sensor.calibrate(f["SN"])
            calibrated_at = len(frames)
    ok = True

    def check(cond, what):
        nonlocal ok
        print(("ok   " if cond else "FAIL ") + what)
        ok &= bool(cond)

    check(len(frames) == a.frames, f"received {len(frames)} of {a.frames} frames")
    if not frames:
        return 1
    sn = frames[0]["SN"]
    check(isinstance(sn, str) and all(f["SN"] == sn for f in frames), f"string SN {sn!r} in every frame")
    for name in ("3D_Positions", "3D_Displacements"):
        arrs = [f.get(name) for f in frames]
        check(all(isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 2 and x.shape[1] == 3
                  for x in arrs), f"{name}: float64 n x 3 ({arrs[0].shape if arrs[0] is not None else None})")
        check(all(np.isfinite(x).all() for x in arrs if x is not None), f"{name}: all finite")
    idx = [f["index"] for f in frames]
    ts = [f["sendTimestamp"] for f in frames]
    check(all(b > c for b, c in zip(idx[1:], idx)), f"indices increase ({idx[0]}..{idx[-1]})")
    check(all(b > c for b, c in zip(ts[1:], ts)), f"send timestamps increase ({ts[0]:.3f}..{ts[-1]:.3f} s)")
    if len(ts) > 1 and ts[-1] > ts[0]:
        print(f"info sensor-time rate {(len(ts) - 1) / (ts[-1] - ts[0]):.1f} frames/s")
    if calibrated_at:
        before = max(np.abs(f["3D_Displacements"]).max() for f in frames[:calibrated_at])
        after = np.abs(frames[-1]["3D_Displacements"]).max()
        print(f"info max |displacement| before $C {before:.4f} mm, last frame after $C {after:.4f} mm")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
