"""Checks the thin-lens blur formula that tools/corpus/scene.py writes into coc_%04d.exr.

Run:  blender -b --factory-startup -noaudio --python tools/corpus/check_lens.py -- [--out DIR]

Renders tiny emissive spheres at several depths with depth of field on (a black world, a box pixel
filter, a round aperture) and measures the radius of each blur disk two ways: from the disk's
intensity-weighted second moment (a uniform disk of radius R has E[rho^2] = R^2/2) and from the
area of the pixels above half the disk's plateau. Prints both next to
r_px = K*|1/z_f - 1/z|, K = f^2/(2N) * W_px/sensor_w, and a second check that Cycles' Z pass is
the depth along the optical axis (a plane facing the camera reads the same z at its corners).
"""

import math
import os
import sys

import bpy

W, H = 640, 360
FOCAL_MM, FSTOP, SENSOR_MM = 100.0, 1.4, 36.0
FOCUS_M = 2.0
# (depth z in metres, screen position as a fraction of the frame)
SPHERE_PX = 3.0
POINTS = [(1.2, 0.2, 0.3), (3.0, 0.45, 0.7), (5.0, 0.75, 0.3), (20.0, 0.8, 0.75)]


def parse_out():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    return argv[argv.index("--out") + 1] if "--out" in argv else "/tmp/refocus_check_lens"


def setup_scene(sc):
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.use_denoising = False
    sc.cycles.use_adaptive_sampling = False
    sc.cycles.samples = 1024
    sc.cycles.pixel_filter_type = "BOX"
    sc.cycles.filter_width = 1.0
    sc.render.resolution_x, sc.render.resolution_y = W, H
    sc.render.resolution_percentage = 100
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 1
    sc.view_settings.view_transform = "Standard"
    sc.world = bpy.data.worlds.new("black")
    sc.world.color = (0, 0, 0)
    sc.world.use_nodes = False
    cam = bpy.data.cameras.new("cam")
    cam.lens, cam.sensor_width, cam.sensor_fit = FOCAL_MM, SENSOR_MM, "HORIZONTAL"
    cam.clip_start = 0.01
    cam.dof.use_dof = True
    cam.dof.focus_distance = FOCUS_M
    cam.dof.aperture_fstop = FSTOP
    cam.dof.aperture_blades = 0
    co = bpy.data.objects.new("cam", cam)  # at the origin, looking down -Z
    sc.collection.objects.link(co)
    sc.camera = co
    return cam


def emissive_sphere(x, y, z, fpx):
    """A sphere of radius SPHERE_PX px at depth z whose centre projects to pixel (x, y) (y up).

    Not smaller: a ray through a random aperture point must hit it often enough for a clean disk."""
    X = (x - W / 2) * z / fpx
    Y = (y - H / 2) * z / fpx
    bpy.ops.mesh.primitive_uv_sphere_add(radius=SPHERE_PX * z / fpx, location=(X, Y, -z))
    mat = bpy.data.materials.new("emit")
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = 1e4
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs[0], out.inputs[0])
    bpy.context.object.data.materials.append(mat)


def render_exr(sc, path):
    sc.render.image_settings.file_format = "OPEN_EXR"
    sc.render.image_settings.color_depth = "32"
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    c = img.channels
    px = img.pixels[:]
    return [px[i * c] for i in range(W * H)]  # red channel, rows bottom-up


def measure(lum, cx, cy, r_pred):
    win = int(1.6 * r_pred) + 3
    s = m2 = 0.0
    vals = []
    for y in range(max(0, int(cy) - win), min(H, int(cy) + win + 1)):
        for x in range(max(0, int(cx) - win), min(W, int(cx) + win + 1)):
            v = lum[y * W + x]
            d2 = (x + 0.5 - cx) ** 2 + (y + 0.5 - cy) ** 2
            s += v
            m2 += v * d2
            vals.append((v, d2))
    # The sharp image of the sphere (a disk of radius SPHERE_PX, E[rho^2] = s^2/2) and the unit
    # box pixel filter (1/12 px^2 per axis) add to the blur disk's second moment.
    r_moment = math.sqrt(max(0.0, 2.0 * (m2 / s - 1.0 / 6.0) - SPHERE_PX**2))
    inner = [v for v, d2 in vals if d2 < (0.5 * r_pred) ** 2]
    plateau = sum(inner) / len(inner)
    r_area = math.sqrt(sum(1 for v, _ in vals if v >= 0.5 * plateau) / math.pi)
    return r_moment, r_area


def check_depth(sc, cam, out):
    """Z pass of a tilted-free plane at 6 m: planar z reads 6 at every pixel."""
    for o in list(bpy.data.objects):
        if o.type == "MESH":
            bpy.data.objects.remove(o)
    cam.dof.use_dof = False
    bpy.ops.mesh.primitive_plane_add(size=100, location=(0, 0, -6))
    sc.cycles.samples = 1
    sc.view_layers[0].use_pass_z = True
    sc.use_nodes = True
    nt = sc.node_tree
    nt.nodes.clear()
    rl = nt.nodes.new("CompositorNodeRLayers")
    comp = nt.nodes.new("CompositorNodeComposite")
    nt.links.new(rl.outputs["Depth"], comp.inputs["Image"])
    z = render_exr(sc, os.path.join(out, "depth.exr"))
    return z[(H // 2) * W + W // 2], z[0], z[W * H - 1]


def main():
    out = parse_out()
    os.makedirs(out, exist_ok=True)
    sc = bpy.context.scene
    cam = setup_scene(sc)
    fpx = FOCAL_MM / SENSOR_MM * W
    K = (FOCAL_MM * 1e-3) ** 2 / (2 * FSTOP) * W / (SENSOR_MM * 1e-3)
    for z, fx, fy in POINTS:
        emissive_sphere(fx * W, fy * H, z, fpx)
    lum = render_exr(sc, os.path.join(out, "disks.exr"))
    print("check_lens: %dx%d, f=%g mm, N=%g, sensor %g mm, focus %g m, K=%.3f px*m" %
          (W, H, FOCAL_MM, FSTOP, SENSOR_MM, FOCUS_M, K))
    print("check_lens: z_m  predicted_px  moment_px  halfmax_px  ratio(moment/predicted)")
    for z, fx, fy in POINTS:
        r_pred = K * abs(1 / FOCUS_M - 1 / z)
        rm, ra = measure(lum, fx * W, fy * H, r_pred)
        print("check_lens: %5.1f  %8.2f  %8.2f  %8.2f  %.3f" % (z, r_pred, rm, ra, rm / r_pred))
    c, corner0, corner1 = check_depth(sc, cam, out)
    print("check_lens: Z pass of a plane at 6 m: centre %.4f, corners %.4f %.4f "
          "(a ray-length pass would read %.4f at the corners)" %
          (c, corner0, corner1, 6 * math.sqrt(1 + (SENSOR_MM / 2 / FOCAL_MM) ** 2 *
                                            (1 + (H / W) ** 2))))


main()
