"""Renders one clip of the misfocus corpus with Blender Cycles (see tools/corpus/README.md).

  blender -b --factory-startup -noaudio --python tools/corpus/scene.py -t 1 -- \
      --spec clip_spec.json --out DIR [--frames N] [--size WxH] [--samples N]

The spec (JSON, written by make_corpus.py) names the clip and fixes its seed, split, size, camera
move, subject action, focus behaviour and whether make_corpus.py passes it through H.264; lens,
layout, materials, lights, motion amplitudes and noise are drawn from the seed. Each frame is
rendered twice: without depth of field (sharp_, with the Z and object-index passes) and with it
(input_, then gaussian sensor noise). Frames already finished in DIR are kept (resume). A spec
with "renderer": "defocus" renders the clean tier instead (scene_defocus.py, clean_tier.py).
"""

import argparse
import array
import json
import math
import os
import random
import shutil
import sys
import time

import bpy
from mathutils import Euler, Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import corpus_io  # noqa: E402
import scene_build as sb  # noqa: E402
import scene_defocus  # noqa: E402

FPS = 24
CAMERAS = ("locked", "pan", "dolly_in", "dolly_out", "orbit", "handheld")
SUBJECTS = ("walk_depth", "cross", "pass_front", "stand", "none")
FOCUS = ("rack", "hunt", "breathe", "wrong")
COC_FORMULA = "r_px = K*|1/z_f - 1/z|, K = f^2/(2N) * W_px/sensor_w"
FILES = {"input": "input_%04d.png", "sharp": "sharp_%04d.png", "coc": "coc_%04d.exr",
         "depth": "depth_%04d.exr", "alpha": "alpha_%04d.png"}


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="scene.py", description=__doc__.split("\n")[0])
    ap.add_argument("--spec", required=True, help="clip spec JSON (see make_corpus.py)")
    ap.add_argument("--out", required=True, help="folder for the clip's frames and clip.json")
    ap.add_argument("--frames", type=int, help="override the spec's frame count")
    ap.add_argument("--size", help="override the spec's size, WxH")
    ap.add_argument("--samples", type=int, help="override the spec's Cycles samples")
    return ap.parse_args(argv)


def load_spec(args):
    try:
        with open(args.spec) as f:
            spec = json.load(f)
    except (OSError, ValueError) as e:
        sys.exit("%s: cannot read the clip spec: %s" % (args.spec, e))
    spec.setdefault("frames", 30)
    spec.setdefault("width", 320)
    spec.setdefault("height", 180)
    spec.setdefault("samples", 16)  # the input's (depth of field); the sharp frame gets half
    if args.frames:
        spec["frames"] = args.frames
    if args.size:
        w, _, h = args.size.partition("x")
        spec["width"], spec["height"] = int(w), int(h)
    if args.samples:
        spec["samples"] = args.samples
    for key, allowed in (("camera", CAMERAS), ("subject", SUBJECTS), ("focus", FOCUS)):
        if spec.get(key) not in allowed:
            sys.exit("%s: %s must be one of %s (got %r)" % (args.spec, key, ", ".join(allowed),
                                                           spec.get(key)))
    for key in ("name", "seed", "split"):
        if key not in spec:
            sys.exit("%s: the spec has no '%s'" % (args.spec, key))
    if spec["width"] % 2 or spec["height"] % 2:
        sys.exit("%s: width and height must be even (H.264 4:2:0)" % args.spec)
    return spec


def draw_shot(spec):
    """Lens, scale and layout numbers from the seed. d_h: camera-to-hero distance (m), chosen
    so that the far background blurs by r_bg px when the hero is in focus."""
    rng = random.Random(spec["seed"])
    W, H = spec["width"], spec["height"]
    s = {"rng": rng, "W": W, "H": H, "T": spec["frames"]}
    # Drawn first, then overridden: a spec that fixes the lens keeps the rest of the draw.
    s["f_mm"] = rng.choice([35, 50, 65, 85, 100, 135])
    s["N"] = rng.choice([1.4, 1.8, 2.0, 2.8, 4.0])
    s["sensor_mm"] = rng.choice([36.0, 24.89])
    for key, name in (("f_mm", "focal_mm"), ("N", "fstop"), ("sensor_mm", "sensor_mm")):
        s[key] = spec.get(name, s[key])
    f, sw = s["f_mm"] * 1e-3, s["sensor_mm"] * 1e-3
    s["K"] = f * f / (2 * s["N"]) * W / sw
    s["focal_px"] = f / sw * W
    s["m"] = rng.uniform(3.5, 7.0)  # background distance / hero distance
    s["r_bg"] = rng.uniform(5.0, 10.0) * W / 320.0
    s["d_h"] = s["K"] * (1 - 1 / s["m"]) / s["r_bg"]
    s["W_h"] = sw * s["d_h"] / f  # frame width at the hero (m)
    s["H_s"] = s["W_h"] * H / W * rng.uniform(0.75, 1.3)  # subject height
    s["h_c"] = s["H_s"] * rng.uniform(0.45, 0.85)  # camera height
    s["noise_sigma"] = round(rng.uniform(0.5, 2.0), 2)
    s["spread"] = 1.9 if spec["camera"] in ("pan", "orbit") else 1.2
    return s


def subject_plan(s, kind):
    """Where the subject walks: start/end (x, y) on the ground (None for no subject)."""
    rng, d, H_s = s["rng"], s["d_h"], s["H_s"]
    if kind in ("none",):
        return None
    if kind == "stand":
        return (0.0, 0.0), (0.0, 0.0)
    if kind == "walk_depth":
        run = min(rng.uniform(1.2, 2.5) * H_s, 0.6 * d)
        x0 = rng.uniform(-0.15, 0.15) * s["W_h"]
        a, b = (x0, 0.55 * run), (x0 + rng.uniform(-0.1, 0.1) * s["W_h"], -0.45 * run)
        return (a, b) if rng.random() < 0.5 else (b, a)
    y = rng.uniform(-0.15, 0.3) * d if kind == "cross" else -rng.uniform(0.25, 0.4) * d
    half = 0.45 * (y + d) * s["sensor_mm"] / s["f_mm"]
    a, b = (-half, y), (half, y)
    return (a, b) if rng.random() < 0.5 else (b, a)


def _seg_dist(p, a, b):
    ax, ay = b[0] - a[0], b[1] - a[1]
    L2 = ax * ax + ay * ay
    t = 0 if L2 == 0 else max(0, min(1, ((p[0] - a[0]) * ax + (p[1] - a[1]) * ay) / L2))
    return math.hypot(p[0] - a[0] - t * ax, p[1] - a[1] - t * ay)


def _blocks(p, r, eyes, targets):
    """Whether a prop at p (radius r) stands between a camera position and a target."""
    for ex, ey in eyes:
        for tx, ty in targets:
            vx, vy = tx - ex, ty - ey
            L = math.hypot(vx, vy)
            along = ((p[0] - ex) * vx + (p[1] - ey) * vy) / L
            if 0 < along < L and abs((p[0] - ex) * vy - (p[1] - ey) * vx) / L < r:
                return True
    return False


def build_set(s, spec, cplan):
    """Ground, backdrop, walls, clutter, hero prop / subject and lights. Props keep out of the
    sight lines from the camera's path to the subject's path (and the hero prop)."""
    rng, d, m = s["rng"], s["d_h"], s["m"]
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    sb.set_lens(s["focal_px"])
    R = m * d * rng.uniform(1.1, 1.4)
    sb.plane((0, -d, 0), (2.2 * R, 2.2 * R), (0, 0, 0),
             sb.material(rng, "ground", d)).name = "ground"  # names: see scene_depths
    sb.dome((0, -d, 0), R, sb.dome_material(rng, R, rng.uniform(0.4, 0.9))).name = "backdrop"
    layout = {"hero_distance_m": round(d, 4), "backdrop_radius_m": round(R, 3)}
    wall_y, wall_x = (m - 1) * d, None
    if rng.random() < 0.5:
        w = 2.2 * m * d * s["sensor_mm"] / s["f_mm"] * s["spread"]
        sb.plane((0, wall_y, w / 4), (w, w / 2), (math.pi / 2, 0, 0),
                 sb.material(rng, "backwall", m * d))
        layout["back_wall_y_m"] = round(wall_y, 3)
    if rng.random() < 0.4:
        side = rng.choice([-1, 1])
        wall_x = side * rng.uniform(0.6, 1.0) * d * s["sensor_mm"] / s["f_mm"] * s["spread"]
        L = wall_y + d
        sb.plane((wall_x, wall_y - L / 2, s["H_s"] * 1.5), (L, s["H_s"] * 3),
                 (math.pi / 2, 0, math.pi / 2), sb.material(rng, "sidewall", 1.5 * d))
        layout["side_wall_x_m"] = round(wall_x, 3)
    path = subject_plan(s, spec["subject"])
    placed = []  # (x, y, r)
    if spec["subject"] in ("none", "pass_front"):
        r = sb.prop(rng, 0.0, 0.0, s["W_h"] * rng.uniform(0.25, 0.4), d, "hero")
        placed.append((0.0, 0.0, r))
    hero = Vector((0.0, 0.0, 0.55 * s["H_s"]))
    eyes = [tuple(camera_at(s, cplan, t, hero).translation)[:2]
            for t in (0, s["T"] // 2, s["T"] - 1)]
    targets = [(0.0, 0.0)] if spec["subject"] in ("none", "pass_front") else []
    if path:
        targets += [path[0], path[1], ((path[0][0] + path[1][0]) / 2,
                                       (path[0][1] + path[1][1]) / 2)]
    n_props = rng.randint(12, 22)
    tries = 0
    while len(placed) < n_props + (1 if spec["subject"] in ("none", "pass_front") else 0):
        tries += 1
        if tries > 2000:
            break
        near = len(placed) < 3 and tries < 400  # a few props at the frame's edges, close up
        D = d * (rng.uniform(0.5, 0.75) if near else math.exp(
            rng.uniform(math.log(0.5), math.log(0.85 * m))))
        hw = D * s["sensor_mm"] / (2 * s["f_mm"])
        sx = (rng.choice([-1, 1]) * rng.uniform(0.55, 0.95) if near else
              rng.uniform(-s["spread"], s["spread"]))
        x, y = sx * hw, D - d
        size = 2 * hw * rng.uniform(0.05, 0.2)
        if wall_x is not None and (x - wall_x) * math.copysign(1, wall_x) > -size:
            continue  # in or behind the side wall
        if y > wall_y - size:
            continue
        if _blocks((x, y), size / 2 + 0.35 * s["H_s"], eyes, targets):
            continue  # would hide the subject / hero
        if path and _seg_dist((x, y), path[0], path[1]) < size / 2 + 0.3 * s["H_s"]:
            continue
        if any(math.hypot(x - px, y - py) < size / 2 + pr for px, py, pr in placed):
            continue
        if any(math.hypot(x - ex, y - ey) < 0.25 * d + size / 2 for ex, ey in eyes):
            continue  # too close to the camera's path
        placed.append((x, y, sb.prop(rng, x, y, size, D, "prop%d" % len(placed))))
    layout["props"] = len(placed)
    rig = sb.person(rng, s["H_s"], d) if path else None
    layout["light"] = sb.lights(rng, d, s["H_s"], rng.uniform(1.5, 2.5))
    world = bpy.data.worlds.new("black")  # no sky light: one light less to sample
    world.use_nodes = False
    world.color = (0.0, 0.0, 0.0)
    bpy.context.scene.world = world
    return path, rig, layout


def ease(u):
    u = max(0.0, min(1.0, u))
    return u * u * (3 - 2 * u)


def subject_at(s, path, t):
    """(x, y, heading, walk phase) of the subject at frame t."""
    u = t / max(1, s["T"] - 1)
    (ax, ay), (bx, by) = path
    x, y = ax + (bx - ax) * u, ay + (by - ay) * u
    dist = math.hypot(bx - ax, by - ay)
    if dist < 1e-9:  # standing: turns a little
        return x, y, s["stand_heading"] + 0.35 * math.sin(2 * math.pi * (0.7 * u)), 0.0
    heading = math.atan2(-(bx - ax), by - ay)  # the rig walks along its local +Y
    return x, y, heading, 2 * math.pi * dist * u / (0.7 * s["H_s"])


def pose_subject(s, path, rig, t):
    root, piv = rig
    x, y, heading, phase = subject_at(s, path, t)
    swing = 0.45 if phase else 0.05 * math.sin(2 * math.pi * t / max(1, s["T"]))
    root.location = (x, y, 0.012 * s["H_s"] * abs(math.sin(phase)))
    root.rotation_euler = (0, 0, heading)
    piv["hip_l"].rotation_euler = (swing * math.sin(phase), 0, 0)
    piv["hip_r"].rotation_euler = (-swing * math.sin(phase), 0, 0)
    piv["shoulder_l"].rotation_euler = (-0.8 * swing * math.sin(phase), 0, 0)
    piv["shoulder_r"].rotation_euler = (0.8 * swing * math.sin(phase), 0, 0)


def camera_plan(s, kind):
    rng = s["rng"]
    c = {"kind": kind, "sign": rng.choice([-1, 1])}
    c["pan"] = math.radians(rng.uniform(10, 22))
    c["orbit"] = math.radians(rng.uniform(25, 50))
    c["dolly"] = (1.3, 0.72) if kind == "dolly_in" else (0.72, 1.3)
    # handheld: three sines per axis (0.4-3 Hz), up to ~1 deg of rotation at 50 mm, less on
    # longer lenses (held steadier, else the shake is tens of px), ~0.2% of d_h of translation
    amp = math.radians(1.0) * math.sqrt(50.0 / s["f_mm"])
    c["shake"] = [(amp * rng.uniform(0.2, 0.6) / (k + 1), rng.uniform(0.4, 3.0),
                   rng.uniform(0, 6.3)) for _ in range(6) for k in range(3)]
    return c


def camera_at(s, c, t, aim):
    """World matrix of the camera at frame t; aim: the point it looks at (the hero)."""
    u = t / max(1, s["T"] - 1)
    P0 = Vector((0.0, -s["d_h"], s["h_c"]))
    pos, kind = P0.copy(), c["kind"]
    if kind in ("dolly_in", "dolly_out"):
        a, b = c["dolly"]
        pos = aim + (P0 - aim) * (a + (b - a) * ease(u))
    elif kind == "orbit":
        pos = Matrix.Rotation(c["sign"] * c["orbit"] * (u - 0.5), 4, "Z") @ P0
    look = aim - pos
    if kind == "pan" and not c.get("follow"):
        look = Matrix.Rotation(c["sign"] * c["pan"] * (ease(u) - 0.5), 3, "Z") @ look
    rot = look.to_track_quat("-Z", "Y")
    if kind == "handheld":
        tt = t / FPS
        waves = [c["shake"][3 * i:3 * i + 3] for i in range(6)]
        v = [sum(a * math.sin(2 * math.pi * fr * tt + ph) for a, fr, ph in w) for w in waves]
        rot = rot @ Euler((v[0], v[1], 0.4 * v[2]), "XYZ").to_quaternion()
        pos = pos + Vector(v[3:6]) * (0.3 * s["d_h"])
    return Matrix.Translation(pos) @ rot.to_matrix().to_4x4()


def cam_depth(M, p):
    return -(M.inverted() @ Vector(p)).z


def scene_depths(s, M):
    """Depths along the optical axis seen through a 17x9 grid of the frame at camera matrix M:
    the nearest prop or wall (not the ground, the backdrop or the subject: a rack to "near"
    lands on a thing) and the 80th percentile of everything (the background)."""
    sc = bpy.context.scene
    dg = bpy.context.evaluated_depsgraph_get()
    origin = M.translation
    zs, props = [], []
    for i in range(17):
        for j in range(9):
            x = (i / 16 - 0.5) * 0.9 * s["W"] / s["focal_px"]
            y = (j / 8 - 0.5) * 0.9 * s["H"] / s["focal_px"]
            dr = (M.to_3x3() @ Vector((x, y, -1.0))).normalized()
            hit, loc, _, _, obj, _ = sc.ray_cast(dg, origin, dr)
            if hit:
                zs.append(cam_depth(M, loc))
                if obj.pass_index != sb.SUBJECT_INDEX and obj.name not in ("ground", "backdrop"):
                    props.append(zs[-1])
    zs.sort()
    return min(props) if props else float("inf"), corpus_io.percentile(zs, 80)


def focus_plan(s, kind, z_s, z_near, z_bg):
    """Per-frame focus distance (m). Works in inverse depth, where the blur is linear."""
    rng, T = s["rng"], s["T"]
    u_s = [1 / z for z in z_s]
    # "near": the nearest prop in view, or half the hero's distance when none is nearer
    u_near = 1 / z_near if z_near < 0.8 * z_s[0] else 2.0 * u_s[0]
    u_bg = 1 / z_bg
    info = {"kind": kind}
    if kind == "rack":
        a, b = rng.choice([("bg", "subject"), ("subject", "bg"), ("near", "subject"),
                           ("subject", "near")])
        t0, dur = rng.uniform(0.15, 0.45) * T, rng.uniform(0.2, 0.4) * T
        pick = {"bg": lambda t: u_bg, "near": lambda t: u_near, "subject": lambda t: u_s[t]}
        u = [pick[a](t) + (pick[b](t) - pick[a](t)) * ease((t - t0) / dur) for t in range(T)]
        info.update({"from": a, "to": b, "start_frame": round(t0, 2), "frames": round(dur, 2)})
    elif kind == "hunt":
        start = rng.choice(["bg", "near"])
        u0 = u_bg if start == "bg" else u_near
        t0, tau = rng.uniform(0, 0.2) * T, rng.uniform(0.15, 0.3) * T
        period = rng.uniform(0.25, 0.45) * T
        u = [u0 if t < t0 else u_s[t] + (u0 - u_s[0]) * math.exp(-(t - t0) / tau) *
             math.cos(2 * math.pi * (t - t0) / period) for t in range(T)]
        info.update({"from": start, "start_frame": round(t0, 2), "decay_frames": round(tau, 2),
                     "period_frames": round(period, 2)})
    elif kind == "breathe":
        a, bias = rng.uniform(0.08, 0.18), rng.uniform(-0.08, 0.08)
        period, ph = rng.uniform(0.4, 1.0) * T, rng.uniform(0, 6.3)
        u = [u_s[t] * (1 + bias + a * math.sin(2 * math.pi * t / period + ph)) for t in range(T)]
        info.update({"amplitude": round(a, 3), "bias": round(bias, 3),
                     "period_frames": round(period, 2)})
    else:
        where = rng.choice(["behind", "in_front", "bg"])
        uw = {"behind": u_s[0] * rng.uniform(0.3, 0.6),
              "in_front": u_s[0] * rng.uniform(1.3, 1.8), "bg": u_bg}[where]
        u = [uw] * T
        info["where"] = where
    floor = 0.5 * u_bg  # never past twice the background
    return [1 / max(floor, v) for v in u], info


def setup_render(s, spec, work):
    """Cycles, the compositor (Z and object index into one EXR in work) and the camera."""
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = spec["samples"]
    cy.use_denoising = False  # this Blender build has no OpenImageDenoise
    cy.use_adaptive_sampling = False  # the same samples everywhere: even noise
    # Direct light only: the materials' emission is the fill (see scene_build.material).
    cy.max_bounces = cy.diffuse_bounces = cy.glossy_bounces = 0
    cy.transmission_bounces = cy.volume_bounces = 0
    cy.transparent_max_bounces = 2
    cy.caustics_reflective = cy.caustics_refractive = False
    cy.blur_glossy = 1.0
    cy.sample_clamp_direct = 4.0  # point/area light close to a surface: no fireflies
    cy.use_animated_seed = True
    sc.render.resolution_x, sc.render.resolution_y = s["W"], s["H"]
    sc.render.resolution_percentage = 100
    sc.render.threads_mode, sc.render.threads = "FIXED", 1
    sc.render.use_persistent_data = True
    sc.render.fps = FPS
    sc.view_settings.view_transform, sc.view_settings.look = "Standard", "None"
    sc.render.image_settings.file_format = "PNG"
    sc.render.image_settings.color_mode = "RGB"
    sc.render.image_settings.color_depth = "8"
    sc.render.image_settings.compression = 15
    vl = sc.view_layers[0]
    vl.use_pass_z = vl.use_pass_object_index = True
    sc.use_nodes = True
    nt = sc.node_tree
    nt.nodes.clear()
    rl = nt.nodes.new("CompositorNodeRLayers")
    comp = nt.nodes.new("CompositorNodeComposite")
    nt.links.new(rl.outputs["Image"], comp.inputs["Image"])
    # Z and object index into one float EXR (R, G); Cycles writes both from the first sample
    # only, so they are not mixed across edges.
    comb = nt.nodes.new("CompositorNodeCombineColor")
    nt.links.new(rl.outputs["Depth"], comb.inputs["Red"])
    nt.links.new(rl.outputs["IndexOB"], comb.inputs["Green"])
    fo = nt.nodes.new("CompositorNodeOutputFile")
    fo.base_path = work
    fo.format.file_format, fo.format.color_mode = "OPEN_EXR", "RGB"
    fo.format.color_depth, fo.format.exr_codec = "32", "ZIP"
    fo.file_slots[0].path = "pass_"
    nt.links.new(comb.outputs["Image"], fo.inputs[0])
    cam = bpy.data.cameras.new("cam")
    cam.lens, cam.sensor_width, cam.sensor_fit = s["f_mm"], s["sensor_mm"], "HORIZONTAL"
    cam.clip_start, cam.clip_end = 0.02 * s["d_h"], 10 * s["m"] * s["d_h"]
    cam.dof.aperture_fstop, cam.dof.aperture_blades = s["N"], 0
    co = bpy.data.objects.new("cam", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    return co


def load_pixels(path):
    """An image's pixels as (array of floats RGBA bottom-up, width, height)."""
    img = bpy.data.images.load(path)
    img.colorspace_settings.name = "Non-Color"
    w, h = img.size
    buf = array.array("f", bytes(4 * w * h * 4))
    img.pixels.foreach_get(buf)
    bpy.data.images.remove(img)
    return buf, w, h


def post_frame(s, spec, out, work, t, z_f):
    """Depth, blur radius and mask from the sharp render's passes; noise on the input."""
    W, H = s["W"], s["H"]
    buf, w, h = load_pixels(os.path.join(work, "pass_%04d.exr" % t))
    if (w, h) != (W, H):
        raise RuntimeError("%s: pass image is %dx%d, expected %dx%d" % (work, w, h, W, H))
    top = corpus_io.flip_rows(buf, W, H, 4)
    far = 10 * s["m"] * s["d_h"]
    z = [v if 0 < v < far else far for v in top[0::4]]
    inv_f = 1.0 / z_f
    coc = [s["K"] * abs(inv_f - 1.0 / v) for v in z]
    corpus_io.write_exr_1ch(os.path.join(out, FILES["depth"] % t), W, H, z)
    corpus_io.write_exr_1ch(os.path.join(out, FILES["coc"] % t), W, H, coc)
    mask = bytes(255 if abs(v - sb.SUBJECT_INDEX) < 0.5 else 0 for v in top[1::4])
    corpus_io.write_png(os.path.join(out, FILES["alpha"] % t), W, H, 1, mask)
    raw_path = os.path.join(work, "raw_%04d.png" % t)
    buf, w, h = load_pixels(raw_path)
    top = corpus_io.flip_rows(buf, W, H, 4)
    rng = random.Random(spec["seed"] * 100003 + t)
    sigma, g = s["noise_sigma"], rng.gauss
    rgb = bytearray(W * H * 3)
    for i in range(W * H):
        for c in range(3):
            v = int(top[4 * i + c] * 255.0 + 0.5 + g(0.0, sigma))
            rgb[3 * i + c] = 0 if v < 0 else 255 if v > 255 else v
    corpus_io.write_png(os.path.join(out, FILES["input"] % t), W, H, 3, rgb)
    os.remove(raw_path)
    os.remove(os.path.join(work, "pass_%04d.exr" % t))


def sharp_samples(spec):
    """Without depth of field only antialiasing needs samples; a blur disk needs more."""
    return max(8, spec["samples"] // 2)


def frame_done(out, t):
    return all(os.path.exists(os.path.join(out, v % t)) for v in FILES.values())


def render_frames(s, spec, out, cam_obj, path, rig, cams, focus):
    sc = bpy.context.scene
    work = os.path.join(out, ".work")
    os.makedirs(work, exist_ok=True)
    secs = []
    for t in range(s["T"]):
        if frame_done(out, t):
            continue
        t0 = time.time()
        sc.frame_set(t)
        cam_obj.matrix_world = cams[t]
        if rig:
            pose_subject(s, path, rig, t)
        cam_obj.data.dof.focus_distance = focus[t]
        cam_obj.data.dof.use_dof = False  # ground truth + passes (compositor)
        sc.render.use_compositing = True
        sc.cycles.samples = sharp_samples(spec)
        sc.render.filepath = os.path.join(out, FILES["sharp"] % t)
        bpy.ops.render.render(write_still=True)
        cam_obj.data.dof.use_dof = True  # the misfocused input: render result as is
        sc.render.use_compositing = False
        sc.cycles.samples = spec["samples"]
        sc.render.filepath = os.path.join(work, "raw_%04d.png" % t)
        bpy.ops.render.render(write_still=True)
        post_frame(s, spec, out, work, t, focus[t])
        secs.append(time.time() - t0)
        print("scene.py: %s frame %d/%d in %.1f s" % (spec["name"], t + 1, s["T"], secs[-1]),
              flush=True)
    shutil.rmtree(work, ignore_errors=True)
    return secs


def clip_stats(s, out):
    """Blur radius statistics over every frame, all pixels and subject pixels."""
    allv, subj, p90s = [], [], []
    for t in range(s["T"]):
        coc, W, H = load_pixels(os.path.join(out, FILES["coc"] % t))
        alpha, _, _ = load_pixels(os.path.join(out, FILES["alpha"] % t))
        v = coc[0::4]
        p90s.append(round(corpus_io.percentile(sorted(v), 90), 2))
        allv.extend(v)
        subj.extend(c for c, a in zip(v, alpha[0::4]) if a > 0.5)
    st = corpus_io.radius_stats(allv)
    st["p90_per_frame"] = p90s
    return st, corpus_io.radius_stats(subj) if subj else None


def render_seconds(out, secs):
    """Mean seconds a frame of this run; a run that rendered nothing (all frames were there)
    keeps the figure of the clip.json it replaces."""
    if secs:
        return round(sum(secs) / len(secs), 2)
    try:
        with open(os.path.join(out, "clip.json")) as f:
            return json.load(f).get("render_seconds_per_frame")
    except (OSError, ValueError):
        return None


def clip_json(s, spec, info):
    """clip.json: the keys of a `refocus synth` clip where they apply, plus the shot's facts."""
    W = s["W"]
    j = {"version": 1, "generator": "tools/corpus/scene.py (Blender %s, Cycles CPU)" %
         bpy.app.version_string, "name": spec["name"], "split": spec["split"],
         "source": "blender", "seed": spec["seed"], "width": W, "height": s["H"],
         "frames": s["T"], "fps": FPS, "camera": spec["camera"], "subject": spec["subject"],
         "focus": spec["focus"], "focal_mm": s["f_mm"], "fstop": s["N"],
         "sensor_mm": s["sensor_mm"], "h264": bool(spec.get("h264")),
         "noise_sigma": s["noise_sigma"], "samples": spec["samples"],
         "samples_sharp": sharp_samples(spec),
         "coc_formula": COC_FORMULA, "K_px_m": round(s["K"], 5)}
    j["description"] = "%s camera, subject %s, focus %s; %g mm f/%g on a %g mm wide sensor" % (
        spec["camera"], spec["subject"], spec["focus"], s["f_mm"], s["N"], s["sensor_mm"])
    j["lens"] = {"model": "Cycles thin lens, round aperture (aperture_blades = 0), "
                          "sensor fit horizontal; checked by tools/corpus/check_lens.py",
                 "radius_formula": COC_FORMULA, "K_px_m": j["K_px_m"],
                 "focal_px": round(s["focal_px"], 4), "shape": "circle",
                 "z": "depth along the optical axis (m), as in depth_%04d.exr"}
    j.update(info)
    j["files"] = dict(FILES)
    j["passes"] = {
        "input": "misfocused frames: Cycles render with depth of field, sRGB 8-bit, plus "
                 "gaussian noise of noise_sigma 8-bit levels" +
                 ("; then H.264 (libx264 crf 23, yuv420p) and decoded back" if spec.get("h264")
                  else ""),
        "sharp": "the same frame without depth of field, sRGB 8-bit, no added noise",
        "coc": "blur radius px of the visible surface of the sharp frame, coc_formula with that "
               "frame's focus distance, 1 channel float",
        "depth": "depth z along the optical axis (m) of the visible surface of the sharp frame "
                 "(Cycles Z pass, first sample: no edge mixing), 1 channel float",
        "alpha": "subject mask from the object-index pass, 255 = subject, 8-bit grey; all 0 "
                 "when subject is none"}
    return j


def main():
    args = parse_args()
    spec = load_spec(args)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    s = draw_shot(spec)
    s["stand_heading"] = math.pi + s["rng"].uniform(-0.6, 0.6)  # facing the camera
    cplan = camera_plan(s, spec["camera"])
    path, rig, layout = build_set(s, spec, cplan)
    T, H_s = s["T"], s["H_s"]
    hero = Vector((0.0, 0.0, 0.55 * H_s))

    def subject_point(t):
        x, y, _, _ = subject_at(s, path, t)
        return Vector((x, y, 0.6 * H_s))

    tracked = spec["subject"] in ("walk_depth", "cross", "stand")
    cplan["follow"] = spec["camera"] == "pan" and spec["subject"] in ("walk_depth", "cross")
    cams, z_s = [], []
    for t in range(T):
        aim = hero
        if cplan["follow"]:  # the operator pans after the subject, lagging a little
            aim = hero + 0.8 * (subject_point(t) - hero)
        cams.append(camera_at(s, cplan, t, aim))
        z_s.append(cam_depth(cams[-1], subject_point(t) if tracked else hero))
    if rig:
        pose_subject(s, path, rig, 0)
    bpy.context.view_layer.update()
    z_near, z_bg = scene_depths(s, cams[0])
    focus, finfo = focus_plan(s, spec["focus"], z_s, z_near, z_bg)
    cam_obj = setup_render(s, spec, os.path.join(out, ".work"))
    t0 = time.time()
    if spec.get("renderer") == "defocus":  # the clean tier: sharp render + compositor Defocus
        secs = scene_defocus.render_frames(s, spec, out, cam_obj, cams, focus,
                                           lambda t: rig and pose_subject(s, path, rig, t))
        if secs is None:  # a render-noise check: those frames only
            return
    else:
        secs = render_frames(s, spec, out, cam_obj, path, rig, cams, focus)
    stats, subj_stats = clip_stats(s, out)
    info = {"focus_distance_m": [round(z, 5) for z in focus],
            "focus_plan": finfo, "hero_depth_m": [round(z, 5) for z in z_s],
            "near_depth_m": round(z_near, 4) if z_near < 1e30 else None,
            "background_depth_m": round(z_bg, 4),
            "coc_stats_px": stats, "coc_subject_stats_px": subj_stats,
            "camera_world": [[round(v, 6) for row in M for v in row] for M in cams],
            "camera_world_meaning": "per frame, the camera's 4x4 world matrix, row-major "
                                    "(Blender: Z up, the camera looks down its local -Z)",
            "layout": layout, "render_seconds_per_frame": render_seconds(out, secs)}
    j = clip_json(s, spec, info)
    if spec.get("renderer") == "defocus":
        scene_defocus.describe(j, s, spec)
    corpus_io._atomic_write(os.path.join(out, "clip.json"),
                            (json.dumps(j, indent=2) + "\n").encode())
    print("scene.py: %s done in %.0f s; blur radius px median %.2f p90 %.2f max %.2f" %
          (spec["name"], time.time() - t0, stats["median"], stats["p90"], stats["max"]),
          flush=True)


main()
