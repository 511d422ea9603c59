#!/usr/bin/python3
"""The clean tier of the Blender corpus (tools/corpus/README.md, The clean tier): procedural
scenes as in make_corpus.py, but the misfocused input is the clean sharp Cycles frame through the
compositor's Defocus node (scene_defocus.py), so its render noise is well under one 8-bit level
and the added sensor noise is the only noise. Each base clip renders once into DIR/.base/<name>
(resuming, like make_corpus.py); then every noise level gets its own clip folder
DIR/<name>_n<sigma> (sigma 0, 0.5, 1, 2, 4 8-bit levels; no H.264) whose sharp, coc, depth and
alpha frames are hard links to the base clip's.

  python3 tools/corpus/clean_tier.py [--out DIR] [--only NAME[,NAME]] [--samples 192]
      [--look DIR]

Needs Blender 3.4 on PATH, python3-opencv and python3-numpy.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import time

os.environ["OPENCV_IO_ENABLE_OPENEXR"] = "1"
import cv2  # noqa: E402
import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
LEVELS = (0, 0.5, 1, 2, 4)  # sensor noise sigma, 8-bit levels; 0: the input only rounded
BASE_FILES = ("sharp_%04d.png", "clean_%04d.png", "coc_%04d.exr", "depth_%04d.exr",
              "alpha_%04d.png")
LINKED = ("sharp_%04d.png", "coc_%04d.exr", "depth_%04d.exr", "alpha_%04d.png")
NOISE_FRAME = 15  # the frame rendered a second time, with another Cycles seed
RENDERER = "cycles sharp + compositor defocus"
# Cycles adaptive sampling: at least MIN_SAMPLES a pixel, more where the estimated error is above
# THRESHOLD (fine ground textures seen at a grazing angle), up to --samples.
MIN_SAMPLES, THRESHOLD = 32, 0.006


def _clip(name, split, seed, camera, subject, focus):
    return {"name": name, "split": split, "seed": seed, "camera": camera, "subject": subject,
            "focus": focus, "h264": False, "width": 320, "height": 180, "frames": 30,
            "renderer": "defocus"}


# Fixed once (seeds apart from the Cycles tier's 3501-3516); each half has a rack and a wrong
# focus; camera moves locked, pan, dolly in/out, orbit and handheld.
CLIPS = [
    _clip("c01_locked_rack", "dev", 3601, "locked", "stand", "rack"),
    _clip("c02_pan_hunt", "dev", 3602, "pan", "cross", "hunt"),
    _clip("c03_dollyin_wrong", "dev", 3603, "dolly_in", "walk_depth", "wrong"),
    _clip("c04_orbit_breathe", "val", 3604, "orbit", "stand", "breathe"),
    _clip("c05_hand_wrong", "val", 3605, "handheld", "pass_front", "wrong"),
    _clip("c06_dollyout_rack", "val", 3606, "dolly_out", "none", "rack"),
]


def read_json(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def write_json(path, j):
    with open(path + ".tmp", "w") as f:
        json.dump(j, f, indent=2)
        f.write("\n")
    os.replace(path + ".tmp", path)


def complete(folder, spec):
    """A base clip is done when its clip.json matches the request and every frame is there."""
    j = read_json(os.path.join(folder, "clip.json"))
    keys = ("seed", "width", "height", "frames", "samples", "camera", "subject", "focus",
            "adaptive_threshold", "adaptive_min_samples")
    if j is None or j.get("renderer") != RENDERER or any(j.get(k) != spec.get(k) for k in keys):
        return False
    return all(os.path.exists(os.path.join(folder, p % t)) for t in range(j["frames"])
               for p in BASE_FILES)


def blender(spec, folder, log_path, exe):
    """scene.py in Blender, niced, one thread."""
    spec_path = folder.rstrip("/") + ".spec.json"
    write_json(spec_path, spec)
    cmd = ["nice", "-n", "19", exe, "-b", "--factory-startup", "-noaudio", "--python",
           os.path.join(HERE, "scene.py"), "-t", "1", "--", "--spec", spec_path, "--out", folder]
    with open(log_path, "a") as lf:
        rc = subprocess.run(cmd, stdout=lf, stderr=subprocess.STDOUT).returncode
    os.remove(spec_path)
    if rc != 0:
        raise RuntimeError("%s: Blender failed (exit %d); see %s" % (spec["name"], rc, log_path))


def render_base(spec, out, exe):
    """Renders a base clip into out/.partial/<name>, then moves it to out/.base/<name>."""
    name = spec["name"]
    work, final = os.path.join(out, ".partial", name), os.path.join(out, ".base", name)
    os.makedirs(work, exist_ok=True)
    os.makedirs(os.path.dirname(final), exist_ok=True)
    log_path = os.path.join(out, ".partial", name + ".log")
    t0 = time.time()
    blender(spec, work, log_path, exe)
    if not complete(work, spec):
        raise RuntimeError("%s: frames missing after the render; see %s" % (name, log_path))
    if os.path.exists(final):
        shutil.rmtree(final)
    os.rename(work, final)
    os.remove(log_path)
    st = read_json(os.path.join(final, "clip.json"))["coc_stats_px"]
    print("%-20s %-3s rendered in %5.0f s: blur radius px median %.2f p90 %.2f max %.2f" %
          (name, spec["split"], time.time() - t0, st["median"], st["p90"], st["max"]),
          flush=True)


def load(path, div=1.0):
    """An image as float RGB (8-bit levels; 16-bit PNGs divided by 257)."""
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise RuntimeError("cannot read %s" % path)
    return img[..., ::-1].astype(np.float64) / div if img.ndim == 3 else img.astype(np.float64)


def render_noise(spec, base, out, exe):
    """Renders NOISE_FRAME again with Cycles seed 1 and measures the render noise against the
    base clip's frame: sigma = std(a - b)/sqrt(2) per channel (R, G, B), 8-bit levels, of the
    sharp frame (its 8-bit PNG) and of the input (the 16-bit defocused frame, before noise)."""
    folder = os.path.join(out, ".partial", spec["name"] + ".noise")
    os.makedirs(folder, exist_ok=True)
    log_path = folder + ".log"
    blender(dict(spec, noise_check={"frames": [NOISE_FRAME], "seed": 1}), folder, log_path, exe)
    res = {"frame": NOISE_FRAME, "method": "two renders of the frame with Cycles seeds 0 and 1: "
           "std(a - b)/sqrt(2) per channel R, G, B over all pixels, 8-bit levels; input before "
           "the sensor noise (16-bit)"}
    for key, pattern, div in (("input", "clean_%04d.png", 257.0), ("sharp", "sharp_%04d.png", 1)):
        a = load(os.path.join(base, pattern % NOISE_FRAME), div)
        b = load(os.path.join(folder, pattern % NOISE_FRAME), div)
        res[key] = [round(float(v), 3) for v in (a - b).reshape(-1, 3).std(0) / np.sqrt(2)]
    shutil.rmtree(folder)
    os.remove(log_path)
    return res


def link(src, dst):
    try:
        os.link(src, dst)
    except OSError:  # another file system, or no hard links: a copy
        shutil.copy2(src, dst)


def make_level(base, bj, sigma, out):
    """The clip folder of one noise level: the clean input plus gaussian noise of sigma 8-bit
    levels, rounded and clipped to 8 bits (a fixed seed per clip and level); the rest linked."""
    name = "%s_n%g" % (bj["name"], sigma)
    work, final = os.path.join(out, ".partial", name), os.path.join(out, name)
    if os.path.exists(work):
        shutil.rmtree(work)
    os.makedirs(work)
    rng = np.random.default_rng([bj["seed"], int(round(sigma * 100))])
    for t in range(bj["frames"]):
        clean = cv2.imread(os.path.join(base, "clean_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        v = clean.astype(np.float64) / 257.0
        if sigma:
            v += rng.normal(0.0, sigma, v.shape)
        cv2.imwrite(os.path.join(work, "input_%04d.png" % t),
                    np.clip(np.round(v), 0, 255).astype(np.uint8))
        for p in LINKED:
            link(os.path.join(base, p % t), os.path.join(work, p % t))
    j = dict(bj, name=name, tier="clean", base_clip=bj["name"], noise_sigma=sigma, h264=False,
             noise_seed=[bj["seed"], int(round(sigma * 100))])
    j["description"] = "clean tier, sensor noise sigma %g: %s" % (sigma, bj["description"])
    j["files"] = {k: v for k, v in bj["files"].items() if k != "clean"}
    j["files"]["input"] = "input_%04d.png"
    j["passes"] = {k: v for k, v in bj["passes"].items() if k != "clean"}
    j["passes"]["input"] = (
        "misfocused frames: the sharp render through the compositor's Defocus node with the coc "
        "of each pixel (no render noise to speak of: render_noise_sigma), plus gaussian noise "
        "of noise_sigma 8-bit levels added to the 8-bit sRGB value, rounded and clipped; "
        "no H.264")
    write_json(os.path.join(work, "clip.json"), j)
    if os.path.exists(final):
        shutil.rmtree(final)
    os.rename(work, final)
    return name


def look(base, bj, path):
    """sharp | noiseless input | coc (turbo colour map, 0-25 px) of the middle frame."""
    t = bj["frames"] // 2
    sharp = cv2.imread(os.path.join(base, "sharp_%04d.png" % t))
    clean = cv2.imread(os.path.join(base, "clean_%04d.png" % t), cv2.IMREAD_UNCHANGED)
    clean = np.clip(np.round(clean / 257.0), 0, 255).astype(np.uint8)
    coc = cv2.imread(os.path.join(base, "coc_%04d.exr" % t), cv2.IMREAD_UNCHANGED)
    vis = cv2.applyColorMap(np.clip(coc / 25.0 * 255, 0, 255).astype(np.uint8),
                            cv2.COLORMAP_TURBO)
    img = np.hstack([sharp, clean, vis])
    cv2.putText(img, "%s t=%d focus %.2f m; coc 0-25 px" % (bj["name"], t,
                bj["focus_distance_m"][t]), (4, 12), cv2.FONT_HERSHEY_PLAIN, 0.8,
                (255, 255, 255), 1)
    cv2.imwrite(path, img)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.expanduser("~/.cache/refocus/clean"),
                    help="tier folder (default ~/.cache/refocus/clean)")
    ap.add_argument("--only", help="these base clips only (comma-separated names)")
    ap.add_argument("--samples", type=int, default=192,
                    help="Cycles samples at most a pixel (adaptive, at least %d)" % MIN_SAMPLES)
    ap.add_argument("--look", help="write sharp | input | coc of each clip's middle frame here")
    ap.add_argument("--blender", default="blender", help="Blender executable")
    args = ap.parse_args()
    names = [c["name"] for c in CLIPS]
    only = args.only.split(",") if args.only else names
    for n in only:
        if n not in names:
            sys.exit("clean_tier.py: no clip named '%s' (known: %s)" % (n, ", ".join(names)))
    if shutil.which(args.blender) is None:
        sys.exit("clean_tier.py: needs '%s' on PATH" % args.blender)
    out = os.path.abspath(args.out)
    os.makedirs(os.path.join(out, ".partial"), exist_ok=True)
    t0, failed = time.time(), []
    for c in CLIPS:
        if c["name"] not in only:
            continue
        spec = dict(c, samples=args.samples, adaptive_threshold=THRESHOLD,
                    adaptive_min_samples=MIN_SAMPLES)
        base = os.path.join(out, ".base", c["name"])
        try:
            if complete(base, spec):
                print("%-20s %-3s base clip already complete" % (c["name"], c["split"]))
            else:
                render_base(spec, out, args.blender)
            bj = read_json(os.path.join(base, "clip.json"))
            if "render_noise_sigma" not in bj:  # measured once per base clip
                bj["render_noise_sigma"] = render_noise(spec, base, out, args.blender)
                write_json(os.path.join(base, "clip.json"), bj)
            levels = [make_level(base, bj, s, out) for s in LEVELS]
            print("%-20s %-3s render noise (R, G, B levels) input %s, sharp %s; %s" %
                  (c["name"], c["split"], bj["render_noise_sigma"]["input"],
                   bj["render_noise_sigma"]["sharp"], " ".join(levels)), flush=True)
            if args.look:
                os.makedirs(args.look, exist_ok=True)
                look(base, bj, os.path.join(args.look, c["name"] + ".png"))
        except (RuntimeError, subprocess.CalledProcessError, OSError) as e:
            failed.append(c["name"])
            print("clean_tier.py: %s" % e, flush=True)
    try:
        os.rmdir(os.path.join(out, ".partial"))  # only when empty
    except OSError:
        pass
    print("clean_tier.py: done in %.0f min into %s%s" % ((time.time() - t0) / 60, out,
          "; failed: " + ", ".join(failed) if failed else ""))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
