"""Checks the blur radius of the clean tier's compositor Defocus node (scene_defocus.py).

Run:  blender -b --factory-startup -noaudio --python tools/corpus/check_defocus.py -t 1 -- \
          [--out DIR]

Renders, without depth of field, small emissive spheres at depths chosen so that the corpus's
formula r_px = K*|1/z_f - 1/z| gives radii 1.7-24.6 px, each in front of its own black card at
almost the same depth (so every pixel around a sphere has the sphere's radius, as inside a
surface), and passes the frame through two Defocus set-ups: the clean tier's (the radius from the
Z pass by the formula, fed to the node as a radius) and the node's own Z-buffer mode with the
scene camera and f_stop = N*1000/sensor_mm (its conversion is 1000/sensor_mm times the thin lens
at the camera's f-number). Each blur disk's radius is measured from its second moment (a uniform
disk of radius R has E[rho^2] = R^2/2, less the sphere's own disk and the box pixel filter) and
from the area above half its plateau, next to the second-moment radius of the node's kernel (the
lattice points within r of the centre). A last strip checks a depth edge: a white card blurred by
10 px in front of a black card in focus.
"""

import math
import os
import sys

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scene_defocus  # noqa: E402

W, H = 640, 540  # two rows of 4 disks (180 px each), then the edge strip
FOCAL_MM, FSTOP, SENSOR_MM = 100.0, 1.4, 36.0
FOCUS_M = 2.0
SPHERE_PX = 2.0
# radius (px), off the lattice steps at sqrt(integer), and side: behind (+1) or in front of (-1)
# the focus distance
RADII = [(1.7, 1), (3.3, -1), (5.2, 1), (8.4, -1), (12.3, 1), (16.5, -1), (20.2, 1), (24.6, 1)]
EDGE_R = 10.0


def parse_out():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    return argv[argv.index("--out") + 1] if "--out" in argv else "/tmp/refocus_check_defocus"


def emission(value):
    mat = bpy.data.materials.new("e%g" % value)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = value
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs[0], out.inputs[0])
    return mat


def at(x, y, z, fpx):
    """World point at depth z that projects to pixel (x, y) (y up; camera at 0, looking -Z)."""
    return ((x - W / 2) * z / fpx, (y - H / 2) * z / fpx, -z)


def card(x0, y0, x1, y1, z, fpx, mat):
    """A rectangle facing the camera covering pixels [x0, x1] x [y0, y1] at depth z."""
    cx, cy, _ = at((x0 + x1) / 2, (y0 + y1) / 2, z, fpx)
    bpy.ops.mesh.primitive_plane_add(size=1, location=(cx, cy, -z))
    o = bpy.context.object
    o.scale = ((x1 - x0) * z / fpx, (y1 - y0) * z / fpx, 1)
    o.data.materials.append(mat)


def build(sc, K, fpx):
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    black, bright = emission(0.0), emission(1e3)
    spheres = []
    for i, (r, side) in enumerate(RADII):
        z = 1.0 / (1.0 / FOCUS_M - side * r / K)
        x, y = 80 + 160 * (i % 4) + 0.3, 360 + 90 - 180 * (i // 4) + 0.3  # off the pixel grid
        bpy.ops.mesh.primitive_uv_sphere_add(radius=SPHERE_PX * z / fpx,
                                             location=at(x, y, z, fpx))
        bpy.context.object.data.materials.append(bright)
        card(x - 80.5, y - 90.5, x + 80.5, y + 90.5, z * 1.001, fpx, black)  # no gaps
        spheres.append((r, z, x, y))
    # edge strip (rows 0-179): white card in front, its right edge at x = 320, on a black card
    z_fg = 1.0 / (1.0 / FOCUS_M + EDGE_R / K)
    card(-10, -10, 320, 179.5, z_fg, fpx, emission(1.0))
    card(-10, -10, W + 10, 180.5, FOCUS_M, fpx, black)
    return spheres


def setup(sc, out, K):
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.use_denoising = sc.cycles.use_adaptive_sampling = False
    sc.cycles.samples = 64
    sc.cycles.pixel_filter_type, sc.cycles.filter_width = "BOX", 1.0
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.render.resolution_percentage = 100
    sc.render.threads_mode, sc.render.threads = "FIXED", 1
    sc.view_settings.view_transform = "Standard"
    sc.world = bpy.data.worlds.new("black")
    sc.world.color, sc.world.use_nodes = (0, 0, 0), False
    cam = bpy.data.cameras.new("cam")
    cam.lens, cam.sensor_width, cam.sensor_fit = FOCAL_MM, SENSOR_MM, "HORIZONTAL"
    cam.clip_start, cam.clip_end = 0.01, 1000
    cam.dof.use_dof, cam.dof.focus_distance = False, FOCUS_M  # the node reads focus_distance
    cam.dof.aperture_fstop, cam.dof.aperture_blades = FSTOP, 0
    co = bpy.data.objects.new("cam", cam)
    sc.collection.objects.link(co)
    sc.camera = co
    sc.view_layers[0].use_pass_z = True
    sc.use_nodes = True
    nt = sc.node_tree
    nt.nodes.clear()
    rl = nt.nodes.new("CompositorNodeRLayers")
    comp = nt.nodes.new("CompositorNodeComposite")
    nt.links.new(rl.outputs["Image"], comp.inputs["Image"])
    tier, focus = scene_defocus.add_defocus(nt, rl.outputs["Image"], rl.outputs["Depth"], K)
    focus.inputs[0].default_value = 1.0 / FOCUS_M
    zmode = nt.nodes.new("CompositorNodeDefocus")
    zmode.bokeh, zmode.use_gamma_correction, zmode.use_preview = "CIRCLE", False, False
    zmode.use_zbuffer, zmode.threshold = True, 0.0
    zmode.blur_max, zmode.f_stop = scene_defocus.BLUR_MAX, FSTOP * 1000.0 / SENSOR_MM
    nt.links.new(rl.outputs["Image"], zmode.inputs["Image"])
    nt.links.new(rl.outputs["Depth"], zmode.inputs["Z"])
    for prefix, sock in (("sharp_", rl.outputs["Image"]), ("tier_", tier.outputs["Image"]),
                         ("zmode_", zmode.outputs["Image"])):
        scene_defocus.file_output(nt, out, prefix, sock, "OPEN_EXR", "RGB", "32")


def red(path):
    buf, w, h = scene_defocus.load_pixels(path)
    return buf[0::4]  # rows bottom-up, as the pixel coordinates here


def lattice_radius(r):
    """Second-moment radius of the node's kernel: the pixel offsets with |dx|, |dy| < r inside
    the bokeh disk of radius r, each weight 1, the centre included."""
    n, s2 = 0, 0.0
    for dy in range(-int(r) - 1, int(r) + 2):
        for dx in range(-int(r) - 1, int(r) + 2):
            inside = abs(dx) < r and abs(dy) < r and dx * dx + dy * dy < r * r
            if inside or (dx == 0 and dy == 0):
                n += 1
                s2 += dx * dx + dy * dy
    return math.sqrt(2 * s2 / n)


def measure(img, cx, cy, r):
    win = int(1.6 * r) + 4
    pts = [(x, y, img[y * W + x]) for y in range(int(cy) - win, int(cy) + win + 1)
           for x in range(int(cx) - win, int(cx) + win + 1)]
    s = sum(v for _, _, v in pts)
    mx = sum(v * (x + 0.5) for x, _, v in pts) / s
    my = sum(v * (y + 0.5) for _, y, v in pts) / s
    m2 = sum(v * ((x + 0.5 - mx) ** 2 + (y + 0.5 - my) ** 2) for x, y, v in pts) / s
    r_mom = math.sqrt(max(0.0, 2.0 * (m2 - 1.0 / 6.0) - SPHERE_PX ** 2))
    inner = [v for x, y, v in pts if (x + 0.5 - mx) ** 2 + (y + 0.5 - my) ** 2 < (0.5 * r) ** 2]
    plateau = sum(inner) / max(1, len(inner))
    r_area = math.sqrt(sum(1 for _, _, v in pts if v >= 0.5 * plateau) / math.pi)
    return r_mom, r_area


def main():
    out = parse_out()
    os.makedirs(out, exist_ok=True)
    sc = bpy.context.scene
    fpx = FOCAL_MM / SENSOR_MM * W
    K = (FOCAL_MM * 1e-3) ** 2 / (2 * FSTOP) * W / (SENSOR_MM * 1e-3)
    spheres = build(sc, K, fpx)
    setup(sc, out, K)
    sc.frame_set(1)
    sc.render.filepath = os.path.join(out, "composite.png")
    bpy.ops.render.render(write_still=True)
    imgs = {k: red(os.path.join(out, "%s_0001.exr" % k)) for k in ("sharp", "tier", "zmode")}
    print("check_defocus: %dx%d, f=%g mm, N=%g, sensor %g mm, focus %g m, K=%.3f px*m; "
          "Z-buffer mode f_stop %.2f" % (W, H, FOCAL_MM, FSTOP, SENSOR_MM, FOCUS_M, K,
                                         FSTOP * 1000.0 / SENSOR_MM))
    print("check_defocus: z_m  coc_px  kernel_px  tier:moment halfmax  zbuffer:moment halfmax")
    for r, z, x, y in spheres:
        coc = K * abs(1.0 / FOCUS_M - 1.0 / z)
        tm, ta = measure(imgs["tier"], x, y, r)
        zm, za = measure(imgs["zmode"], x, y, r)
        print("check_defocus: %6.3f  %6.2f  %6.2f   %6.2f  %6.2f   %6.2f  %6.2f" %
              (z, coc, lattice_radius(coc), tm, ta, zm, za))
    row = 90 * W
    prof = ["%.2f" % imgs["tier"][row + 320 + d] for d in range(-13, 13)]
    print("check_defocus: edge, white card blurred by %g px in front of a black card in focus, "
          "x = 307..332 (edge at 320): %s" % (EDGE_R, " ".join(prof)))


main()
