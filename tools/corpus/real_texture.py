#!/usr/bin/python3
"""The real-texture tier: real footage and photographs (OpenCV's sample data from the Debian
package opencv-doc, never the identity clip's vtest.avi), blurred in linear light by a lens
kernel that is not the fit's pillbox (a soft edge, or a brighter rim), with a radius that is
constant, racks, or varies across the frame (a tilted focal plane); then sensor noise and an
H.264 round trip. The ground truth is the real frame. Laid out as `refocus bench corpus` reads
it: input_%04d.png, sharp_%04d.png, coc_%04d.exr (the radius in px), clip.json with a split.

  tools/corpus/real_texture.py <out-dir> [--only NAME[,NAME]]

Needs python3-opencv and python3-numpy (Debian) and ffmpeg with libx264.
"""
import argparse
import glob
import json
import os
import shutil
import subprocess
import sys
import tempfile

os.environ["OPENCV_IO_ENABLE_OPENEXR"] = "1"
import cv2  # noqa: E402
import numpy as np  # noqa: E402

FRAMES = 30
SIZE = (320, 240)

# name, split, source (video frames "avi:FILE:FIRST" or a photo panned "pan:FILE:DX:DY"),
# radius ("const:R", "rack:R0:R1", "tilt:RTOP:RBOTTOM"), kernel, noise sigma in 8-bit levels.
CLIPS = [
    ("r01_tree_const", "dev", "avi:tree.avi:0", "const:2.5", "soft", 1.5),
    ("r02_building_rack", "dev", "pan:building.jpg:2:0", "rack:0.3:4", "rim", 1.5),
    ("r03_fruits_tilt", "dev", "pan:fruits.jpg:1:1", "tilt:0.3:4", "soft", 3.0),
    ("r04_tree_rack", "val", "avi:tree.avi:36", "rack:4:0.5", "rim", 3.0),
    ("r05_home_const", "val", "pan:home.jpg:-2:0", "const:3", "soft", 1.5),
    ("r06_leuven_tilt", "val", "pan:leuvenA.jpg:0:1", "tilt:4:0.3", "rim", 1.5),
]


def srgb_to_linear(x):
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x):
    x = np.clip(x, 0, 1)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def lens_kernel(r, kind):
    """A lens's defocus that is not a uniform disk: a soft edge (a cosine taper over 1.5 px) or a
    brighter rim (weight growing to 1.8x at the edge, as a lens with spherical aberration)."""
    n = int(np.ceil(r)) + 2
    y, x = np.mgrid[-n:n + 1, -n:n + 1].astype(np.float64)
    rho = np.sqrt(x * x + y * y)
    if kind == "soft":
        k = np.clip((r + 0.75 - rho) / 1.5, 0, 1)
        k = 0.5 - 0.5 * np.cos(np.pi * k)
    else:
        k = np.clip(r + 0.5 - rho, 0, 1) * (1 + 0.8 * np.clip(rho / max(r, 0.5), 0, 1) ** 4)
    return k / k.sum()


def blur_varying(lin, radius, kind):
    """Each pixel blurred by its own radius (gather): the frame blurred at radii 0.25 px apart,
    each pixel interpolated between the two levels around its radius."""
    levels = np.arange(0.0, radius.max() + 0.5, 0.25)
    out = np.zeros_like(lin)
    wsum = np.zeros(radius.shape, np.float64)
    for i, r in enumerate(levels):
        w = np.clip(1 - np.abs(radius - r) / 0.25, 0, 1)
        if not w.any():
            continue
        b = lin if r < 0.3 else cv2.filter2D(lin, -1, lens_kernel(r, kind),
                                             borderType=cv2.BORDER_REFLECT)
        out += b * w[..., None]
        wsum += w
    return out / wsum[..., None]


def source_frames(spec, data):
    kind, rest = spec.split(":", 1)
    if kind == "avi":
        name, first = rest.split(":")
        cap = cv2.VideoCapture(os.path.join(data, name))
        for _ in range(int(first)):  # read through: seeking an AVI is not frame-exact
            cap.read()
        frames = []
        for _ in range(FRAMES):
            ok, f = cap.read()
            if not ok:
                sys.exit("%s: fewer than %d frames from %s" % (name, FRAMES, first))
            frames.append(cv2.resize(f, SIZE, interpolation=cv2.INTER_AREA))
        return frames
    name, dx, dy = rest.split(":")
    img = cv2.imread(os.path.join(data, name))
    if img is None:
        sys.exit("cannot read %s" % name)
    dx, dy = float(dx), float(dy)
    # The photo scaled so that the window and its path fit, then a sub-pixel pan.
    need_w = SIZE[0] + abs(dx) * FRAMES + 4
    need_h = SIZE[1] + abs(dy) * FRAMES + 4
    s = max(need_w / img.shape[1], need_h / img.shape[0])
    img = cv2.resize(img, (int(np.ceil(img.shape[1] * s)), int(np.ceil(img.shape[0] * s))),
                     interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)
    frames = []
    x0 = 2 if dx >= 0 else img.shape[1] - SIZE[0] - 2
    y0 = 2 if dy >= 0 else img.shape[0] - SIZE[1] - 2
    for t in range(FRAMES):
        m = np.float32([[1, 0, -(x0 + dx * t)], [0, 1, -(y0 + dy * t)]])
        frames.append(cv2.warpAffine(img, m, SIZE, flags=cv2.INTER_CUBIC,
                                     borderMode=cv2.BORDER_REFLECT))
    return frames


def radius_map(spec, t):
    kind, *v = spec.split(":")
    v = [float(x) for x in v]
    w, h = SIZE
    if kind == "const":
        return np.full((h, w), v[0])
    if kind == "rack":
        return np.full((h, w), v[0] + (v[1] - v[0]) * t / (FRAMES - 1))
    rows = np.linspace(v[0], v[1], h)[:, None]
    return np.repeat(rows, w, axis=1)


def make_clip(clip, data, out):
    name, split, src, rad, kind, sigma = clip
    rng = np.random.default_rng(abs(hash(name)) % (2 ** 32))
    final = os.path.join(out, name)
    work = tempfile.mkdtemp(prefix=name + ".", dir=out)
    for t, f in enumerate(source_frames(src, data)):
        sharp = f.astype(np.float64) / 255
        cv2.imwrite(os.path.join(work, "sharp_%04d.png" % t), f)
        r = radius_map(rad, t)
        lin = blur_varying(srgb_to_linear(sharp), r, kind)
        noisy = linear_to_srgb(lin) * 255 + rng.normal(0, sigma, lin.shape)
        cv2.imwrite(os.path.join(work, "pre_%04d.png" % t),
                    np.clip(np.round(noisy), 0, 255).astype(np.uint8))
        cv2.imwrite(os.path.join(work, "coc_%04d.exr" % t), r.astype(np.float32))
    # H.264 as a camera file, decoded back to PNG (accurate rounding, full chroma).
    sws = ["-sws_flags", "bicubic+accurate_rnd+full_chroma_int"]
    mp4 = os.path.join(work, "input.mp4")
    subprocess.run(["ffmpeg", "-y", "-v", "error", "-framerate", "24", "-start_number", "0",
                    "-i", os.path.join(work, "pre_%04d.png")] + sws +
                   ["-c:v", "libx264", "-crf", "20", "-pix_fmt", "yuv420p", mp4], check=True)
    subprocess.run(["ffmpeg", "-y", "-v", "error", "-i", mp4] + sws +
                   ["-start_number", "0", os.path.join(work, "input_%04d.png")], check=True)
    for p in glob.glob(os.path.join(work, "pre_*.png")):
        os.remove(p)
    meta = {"version": 1, "name": name, "split": split, "tier": "real_texture",
            "source": "opencv-doc " + src, "radius": rad, "kernel": kind,
            "noise_sigma": sigma, "h264": True, "width": SIZE[0], "height": SIZE[1],
            "frames": FRAMES}
    with open(os.path.join(work, "clip.json"), "w") as f:
        json.dump(meta, f, indent=1)
    if os.path.exists(final):
        shutil.rmtree(final)
    os.rename(work, final)
    print(final, flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--only", default="")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    work = tempfile.mkdtemp()
    try:
        subprocess.run(["apt-get", "download", "opencv-doc"], cwd=work, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deb = glob.glob(os.path.join(work, "opencv-doc_*.deb"))[0]
        subprocess.run(["dpkg", "-x", deb, os.path.join(work, "x")], check=True)
        data = glob.glob(os.path.join(work, "x", "usr", "share", "doc", "opencv-doc",
                                      "examples", "data"))[0]
        only = set(filter(None, args.only.split(",")))
        for c in CLIPS:
            if not only or c[0] in only:
                make_clip(c, data, args.out)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
