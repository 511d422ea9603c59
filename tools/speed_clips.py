#!/usr/bin/env python3
"""The speed benchmarks' real clips (docs/benchmarks.md, Speed): OpenCV's vtest.avi (people walking
past a static camera; the opencv-doc package, see tools/corpus/identity_clip.sh for fetching it)
blurred by a disk in linear light, sigma 1 noise, H.264.

    tools/speed_clips.py <vtest.avi> <out-dir>

writes plaza_blur.mp4 (384x288x30, 2.5 px in every frame), plaza_rack.mp4 (the same racking
0 -> 4 px), hd_blur.mp4 (1920x1080x240: 16:9 crop blurred 2.5 px at 768x432, scaled up with
Lanczos) and hd30.mp4 (its first 30 frames, decoded and encoded again). Needs python3-opencv and python3-numpy (Debian) and ffmpeg with libx264."""
import subprocess
import sys

import cv2
import numpy as np


def disk(r):
    """A disk of radius r px, antialiased by 8x8 supersampling."""
    if r < 0.05:
        return np.ones((1, 1))
    k = int(np.ceil(r))
    yy, xx = np.mgrid[-k - 1:k + 2, -k - 1:k + 2].astype(np.float64)
    acc = np.zeros_like(xx)
    for i in range(8):
        for j in range(8):
            acc += (xx + (i + 0.5) / 8 - 0.5) ** 2 + (yy + (j + 0.5) / 8 - 0.5) ** 2 <= r * r
    return acc / acc.sum()


def blur(frame, r):
    lin = (frame.astype(np.float32) / 255.0) ** 2.2
    b = cv2.filter2D(lin, -1, disk(r), borderType=cv2.BORDER_REFLECT)
    return np.maximum(b, 0) ** (1 / 2.2)


def write(path, size, fps, crf, frames):
    p = subprocess.Popen(['ffmpeg', '-y', '-loglevel', 'error', '-f', 'rawvideo', '-pix_fmt', 'bgr24',
                          '-s', '%dx%d' % size, '-r', str(fps), '-i', '-', '-c:v', 'libx264',
                          '-crf', str(crf), '-pix_fmt', 'yuv420p', path], stdin=subprocess.PIPE)
    for f in frames:
        p.stdin.write(f.tobytes())
    p.stdin.close()
    if p.wait() != 0:
        sys.exit('speed_clips.py: ffmpeg failed on ' + path)


def frames(avi, n):
    cap = cv2.VideoCapture(avi)
    for t in range(n):
        ok, f = cap.read()
        if not ok:
            sys.exit('speed_clips.py: %s ends before frame %d' % (avi, t))
        yield t, f


def noisy(img01, t):
    return np.clip(img01 * 255 + np.random.default_rng(t).normal(0, 1.0, img01.shape), 0,
                   255).astype(np.uint8)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    avi, out = sys.argv[1], sys.argv[2]
    small = lambda f: cv2.resize(f, (384, 288), interpolation=cv2.INTER_AREA)
    write(out + '/plaza_blur.mp4', (384, 288), 30, 16,
          (noisy(blur(small(f), 2.5), t) for t, f in frames(avi, 30)))
    write(out + '/plaza_rack.mp4', (384, 288), 30, 16,
          (noisy(blur(small(f), 4.0 * t / 29), t) for t, f in frames(avi, 30)))
    hd = lambda f: cv2.resize(blur(f[72:72 + 432], 2.5), (1920, 1080),
                              interpolation=cv2.INTER_LANCZOS4)
    write(out + '/hd_blur.mp4', (1920, 1080), 24, 18,
          (noisy(hd(f), t) for t, f in frames(avi, 240)))
    if subprocess.call(['ffmpeg', '-y', '-loglevel', 'error', '-i', out + '/hd_blur.mp4', '-frames:v',
                        '30', '-c:v', 'libx264', '-crf', '18', '-pix_fmt', 'yuv420p',
                        out + '/hd30.mp4']) != 0:
        sys.exit('speed_clips.py: ffmpeg failed on ' + out + '/hd30.mp4')


if __name__ == '__main__':
    main()
