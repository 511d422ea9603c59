#!/usr/bin/env python3
"""Renders the Blender misfocus corpus (tools/corpus/README.md): a fixed list of 16 clips, split
once into dev and val, each rendered by scene.py in Blender and, for a third of them, passed
through H.264. Clips already complete are skipped, so an interrupted run resumes (and scene.py
resumes a clip frame by frame).

  python3 tools/corpus/make_corpus.py [--out DIR] [--only NAME[,NAME]] [--jobs 1] [--samples 16]
"""

import argparse
import concurrent.futures
import json
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
FILES = ("input_%04d.png", "sharp_%04d.png", "coc_%04d.exr", "depth_%04d.exr", "alpha_%04d.png")


def _clip(name, seed, camera, subject, focus, h264=False, size=(320, 180)):
    split = "dev" if name.startswith("d") else "val"
    return {"name": name, "split": split, "seed": seed, "camera": camera, "subject": subject,
            "focus": focus, "h264": h264, "width": size[0], "height": size[1], "frames": 30}


# The split is fixed here once; each half covers every camera move and focus behaviour.
CLIPS = [
    _clip("d01_locked_rack", 3501, "locked", "stand", "rack"),
    _clip("d02_pan_hunt", 3502, "pan", "cross", "hunt"),
    _clip("d03_dollyin_breathe", 3503, "dolly_in", "stand", "breathe"),
    _clip("d04_orbit_wrong", 3504, "orbit", "stand", "wrong", h264=True),
    _clip("d05_hand_hunt", 3505, "handheld", "walk_depth", "hunt"),
    _clip("d06_dollyout_rack", 3506, "dolly_out", "none", "rack", h264=True),
    _clip("d07_locked_breathe", 3507, "locked", "pass_front", "breathe", size=(640, 360)),
    _clip("d08_hand_wrong", 3508, "handheld", "cross", "wrong", h264=True),
    _clip("v01_locked_wrong", 3509, "locked", "walk_depth", "wrong", h264=True),
    _clip("v02_pan_rack", 3510, "pan", "none", "rack"),
    _clip("v03_dollyin_hunt", 3511, "dolly_in", "walk_depth", "hunt"),
    _clip("v04_orbit_breathe", 3512, "orbit", "stand", "breathe", size=(640, 360)),
    _clip("v05_hand_rack", 3513, "handheld", "stand", "rack", h264=True),
    _clip("v06_dollyout_wrong", 3514, "dolly_out", "cross", "wrong"),
    _clip("v07_locked_hunt", 3515, "locked", "pass_front", "hunt", h264=True),
    _clip("v08_orbit_rack", 3516, "orbit", "none", "rack"),
]


def complete(folder, spec):
    """A clip counts as done when its clip.json matches the request and every frame is there."""
    try:
        with open(os.path.join(folder, "clip.json")) as f:
            j = json.load(f)
    except (OSError, ValueError):
        return False
    keys = ("seed", "width", "height", "frames", "samples", "h264", "camera", "subject", "focus")
    if any(j.get(k) != spec[k] for k in keys):
        return False
    return all(os.path.exists(os.path.join(folder, p % t)) for t in range(j["frames"])
               for p in FILES)


def h264_roundtrip(folder, frames):
    """Input frames through libx264 (crf 23, yuv420p) and back to PNG, as a camera file."""
    mp4 = os.path.join(folder, "input.mp4")
    pattern = os.path.join(folder, "input_%04d.png")
    nice = ["nice", "-n", "19"]
    # swscale's default RGB <-> YUV rounding shifts green by ~1.7 levels on a round trip;
    # accurate rounding and full chroma interpolation bring it under 0.5.
    sws = ["-sws_flags", "bicubic+accurate_rnd+full_chroma_int"]
    subprocess.run(nice + ["ffmpeg", "-y", "-v", "error", "-framerate", "24", "-start_number",
                           "0", "-i", pattern, "-frames:v", str(frames)] + sws +
                   ["-c:v", "libx264", "-preset", "medium", "-crf", "23", "-pix_fmt", "yuv420p",
                    "-threads", "1", mp4], check=True)
    subprocess.run(nice + ["ffmpeg", "-y", "-v", "error", "-threads", "1", "-i", mp4] + sws +
                   ["-start_number", "0", "-pix_fmt", "rgb24", pattern], check=True)
    os.remove(mp4)


def render(spec, out, blender, log):
    """Renders one clip into out/.partial/<name>, then moves it to out/<name>."""
    name = spec["name"]
    final = os.path.join(out, name)
    work = os.path.join(out, ".partial", name)
    os.makedirs(work, exist_ok=True)
    spec_path = os.path.join(out, ".partial", name + ".spec.json")
    with open(spec_path, "w") as f:
        json.dump(spec, f, indent=2)
    log_path = os.path.join(out, ".partial", name + ".log")
    t0 = time.time()
    cmd = ["nice", "-n", "19", blender, "-b", "--factory-startup", "-noaudio", "--python",
           os.path.join(HERE, "scene.py"), "-t", "1", "--", "--spec", spec_path, "--out", work]
    with open(log_path, "a") as lf:
        rc = subprocess.run(cmd, stdout=lf, stderr=subprocess.STDOUT).returncode
    if rc != 0 or not os.path.exists(os.path.join(work, "clip.json")):
        raise RuntimeError("%s: Blender failed (exit %d); see %s" % (name, rc, log_path))
    if spec["h264"]:
        h264_roundtrip(work, spec["frames"])
    if not complete(work, spec):
        raise RuntimeError("%s: frames missing after the render; see %s" % (name, log_path))
    if os.path.exists(final):
        shutil.rmtree(final)
    os.rename(work, final)
    os.remove(spec_path)
    os.remove(log_path)
    with open(os.path.join(final, "clip.json")) as f:
        st = json.load(f)["coc_stats_px"]
    log("%-20s %-3s done in %5.0f s: blur radius px median %.2f p90 %.2f max %.2f" %
        (name, spec["split"], time.time() - t0, st["median"], st["p90"], st["max"]))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=os.path.expanduser("~/.cache/refocus/corpus"),
                    help="corpus folder (default ~/.cache/refocus/corpus)")
    ap.add_argument("--only", help="render only these clips (comma-separated names)")
    ap.add_argument("--jobs", type=int, default=1, help="clips rendered at once (default 1)")
    ap.add_argument("--samples", type=int, default=16,
                    help="Cycles samples of the input (the sharp frame gets half; default 16)")
    ap.add_argument("--blender", default="blender", help="Blender executable")
    args = ap.parse_args()
    names = {c["name"] for c in CLIPS}
    only = args.only.split(",") if args.only else None
    for n in only or []:
        if n not in names:
            sys.exit("make_corpus.py: no clip named '%s' (known: %s)" % (n, ", ".join(
                sorted(names))))
    if shutil.which(args.blender) is None or shutil.which("ffmpeg") is None:
        sys.exit("make_corpus.py: needs '%s' and ffmpeg on PATH" % args.blender)
    todo = []
    for c in CLIPS:  # dev clips first: the list is in that order
        spec = dict(c, samples=args.samples)
        if only and c["name"] not in only:
            continue
        if complete(os.path.join(args.out, c["name"]), spec):
            print("%-20s %-3s already complete" % (c["name"], c["split"]))
            continue
        todo.append(spec)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.time()
    failed = []
    with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futures = {pool.submit(render, s, args.out, args.blender,
                               lambda m: print(m, flush=True)): s["name"] for s in todo}
        for fut in concurrent.futures.as_completed(futures):
            try:
                fut.result()
            except (RuntimeError, subprocess.CalledProcessError, OSError) as e:
                failed.append(futures[fut])
                print("make_corpus.py: %s" % e, flush=True)
    try:
        os.rmdir(os.path.join(args.out, ".partial"))  # only when empty
    except OSError:
        pass
    print("make_corpus.py: %d clip(s) rendered in %.0f min into %s%s" %
          (len(todo) - len(failed), (time.time() - t0) / 60, args.out,
           "; failed: " + ", ".join(failed) if failed else ""))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
