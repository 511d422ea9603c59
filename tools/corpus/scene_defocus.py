"""The clean tier's renderer for tools/corpus/scene.py (spec "renderer": "defocus").

One Cycles render a frame, without depth of field (the sharp frame, with the Z and object-index
passes), at enough samples that its noise is under one 8-bit level; the misfocused frame is made
from it in the same render by the compositor's Defocus node, a Z-buffer depth of field that
gathers each pixel's neighbours through a round bokeh (see README.md, The clean tier).

The Defocus node's own depth-to-radius conversion (use_zbuffer on) is not the thin lens: its
radius is 1000/sensor_mm times K*|1/z_f - 1/z| for the camera's f-number (focal length in mm
against Z in m) plus a constant offset of a fraction of a pixel, its f-stop stops at 128, and it
blurs the radius map by a gaussian of sigma min(128*aperture, blur_max) px and keeps the smaller
value, which shrinks the radius near depth edges. So the radius is computed here from the Z pass
with the corpus's formula (compositor math nodes) and given to the node as a radius (use_zbuffer
off, z_scale 1): the node applies the coc that is written, clamped at BLUR_MAX.

Per frame the base clip gets sharp_, coc_, depth_, alpha_ (as the Cycles tier) and clean_%04d.png,
the noiseless defocused frame as 16-bit sRGB, to which clean_tier.py adds sensor noise.
"""

import array
import os
import shutil
import time

import bpy

import corpus_io
import scene_build as sb

BLUR_MAX = 48.0  # px; above the corpus's largest radii (about 26 px), so nothing is clipped
FILES = {"sharp": "sharp_%04d.png", "clean": "clean_%04d.png", "coc": "coc_%04d.exr",
         "depth": "depth_%04d.exr", "alpha": "alpha_%04d.png"}
RENDERER = "cycles sharp + compositor defocus"


def add_defocus(nt, image, depth, K, blur_max=BLUR_MAX):
    """Compositor nodes: radius r = K*|1/z_f - 1/z| (px) from the depth socket, and a Defocus
    node that blurs image by it. Returns (defocus node, the math node whose first input is 1/z_f,
    to set per frame)."""
    def math(op, a, b):
        m = nt.nodes.new("CompositorNodeMath")
        m.operation, m.use_clamp = op, False
        for i, v in enumerate((a, b)):
            if isinstance(v, float):
                m.inputs[i].default_value = v
            elif v is not None:
                nt.links.new(v, m.inputs[i])
        return m

    inv_z = math("DIVIDE", 1.0, depth)
    focus = math("SUBTRACT", 1.0, inv_z.outputs[0])  # inputs[0] := 1/z_f each frame
    radius = math("MULTIPLY", math("ABSOLUTE", focus.outputs[0], None).outputs[0], float(K))
    dn = nt.nodes.new("CompositorNodeDefocus")
    dn.bokeh, dn.angle = "CIRCLE", 0.0  # a round bokeh image (disk of radius r)
    dn.use_gamma_correction = False  # blur the linear (scene-referred) light
    dn.use_preview = False  # preview quality gathers every 3rd pixel only
    dn.use_zbuffer, dn.z_scale = False, 1.0  # the Z input is the radius in px
    dn.blur_max = blur_max  # the node clamps the radius here
    dn.threshold = 0.0  # no blend back to the sharp pixel below 2*threshold px
    nt.links.new(image, dn.inputs["Image"])
    nt.links.new(radius.outputs[0], dn.inputs["Z"])
    return dn, focus


def file_output(nt, work, prefix, source, fmt, mode, depth):
    fo = nt.nodes.new("CompositorNodeOutputFile")
    fo.base_path = work
    fo.format.file_format, fo.format.color_mode, fo.format.color_depth = fmt, mode, depth
    if fmt == "PNG":
        fo.format.compression = 15
    fo.file_slots[0].path = prefix
    nt.links.new(source, fo.inputs[0])
    return fo


def setup(s, spec, work):
    """Adds the Defocus branch to the compositor scene.setup_render built (Composite = the
    sharp render, File Output pass_ = Z and index); writes clean_ as 16-bit sRGB PNG."""
    sc = bpy.context.scene
    sc.render.dither_intensity = 0.0  # dither is noise too; 8-bit rounding is enough
    nt = sc.node_tree
    rl = next(n for n in nt.nodes if n.bl_idname == "CompositorNodeRLayers")
    dn, focus = add_defocus(nt, rl.outputs["Image"], rl.outputs["Depth"], s["K"])
    file_output(nt, work, "clean_", dn.outputs["Image"], "PNG", "RGB", "16")
    return focus


def post_frame(s, out, work, t, z_f):
    """Depth, coc (as the compositor computed it, clamped at BLUR_MAX) and mask from the pass
    EXR; moves the defocused frame into the clip."""
    W, H = s["W"], s["H"]
    buf, w, h = load_pixels(os.path.join(work, "pass_%04d.exr" % t))
    if (w, h) != (W, H):
        raise RuntimeError("%s: pass image is %dx%d, expected %dx%d" % (work, w, h, W, H))
    top = corpus_io.flip_rows(buf, W, H, 4)
    z = list(top[0::4])  # not clamped: the compositor took the radius from the same values
    inv_f, K = 1.0 / z_f, s["K"]
    # the math node's division gives 0 for z = 0 (no pixel: the backdrop closes the scene)
    coc = [min(BLUR_MAX, K * abs(inv_f - (1.0 / v if v else 0.0))) for v in z]
    corpus_io.write_exr_1ch(os.path.join(out, FILES["depth"] % t), W, H, z)
    corpus_io.write_exr_1ch(os.path.join(out, FILES["coc"] % t), W, H, coc)
    mask = bytes(255 if abs(v - sb.SUBJECT_INDEX) < 0.5 else 0 for v in top[1::4])
    corpus_io.write_png(os.path.join(out, FILES["alpha"] % t), W, H, 1, mask)
    os.replace(os.path.join(work, "clean_%04d.png" % t), os.path.join(out, FILES["clean"] % t))
    os.remove(os.path.join(work, "pass_%04d.exr" % t))


def load_pixels(path):
    """An image's pixels as (array of floats RGBA bottom-up, width, height)."""
    img = bpy.data.images.load(path)
    img.colorspace_settings.name = "Non-Color"
    w, h = img.size
    buf = array.array("f", bytes(4 * w * h * 4))
    img.pixels.foreach_get(buf)
    bpy.data.images.remove(img)
    return buf, w, h


def frame_done(out, t):
    return all(os.path.exists(os.path.join(out, v % t)) for v in FILES.values())


def render_frames(s, spec, out, cam_obj, cams, focus, pose):
    """Renders the clip's frames (resuming); pose(t) poses the subject. A spec with
    "noise_check": {"frames": [...], "seed": N} renders only those frames with Cycles seed N
    (for the render-noise measurement) and returns None."""
    sc = bpy.context.scene
    work = os.path.join(out, ".work")
    os.makedirs(work, exist_ok=True)
    focus_node = setup(s, spec, work)
    check = spec.get("noise_check")
    frames = range(s["T"])
    if check:
        sc.cycles.seed, frames = int(check["seed"]), check["frames"]
    sc.cycles.samples = spec["samples"]
    if spec.get("adaptive_threshold"):  # samples go where the noise is (a fine texture)
        sc.cycles.use_adaptive_sampling = True
        sc.cycles.adaptive_threshold = spec["adaptive_threshold"]
        sc.cycles.adaptive_min_samples = spec.get("adaptive_min_samples", 0)
    sc.render.use_compositing = True
    cam_obj.data.dof.use_dof = False
    secs = []
    for t in frames:
        if frame_done(out, t):
            continue
        t0 = time.time()
        sc.frame_set(t)
        cam_obj.matrix_world = cams[t]
        pose(t)
        cam_obj.data.dof.focus_distance = focus[t]
        focus_node.inputs[0].default_value = 1.0 / focus[t]
        sc.render.filepath = os.path.join(out, FILES["sharp"] % t)
        bpy.ops.render.render(write_still=True)
        post_frame(s, out, work, t, focus[t])
        secs.append(time.time() - t0)
        print("scene_defocus.py: %s frame %d in %.1f s" % (spec["name"], t, secs[-1]), flush=True)
    shutil.rmtree(work, ignore_errors=True)
    return None if check else secs


def describe(j, s, spec):
    """clip.json of a base clip: what differs from the Cycles tier."""
    j["generator"] = j["generator"].replace("scene.py", "scene.py + scene_defocus.py")
    j["renderer"] = RENDERER
    j["samples"] = j["samples_sharp"] = spec["samples"]
    j["adaptive_threshold"] = spec.get("adaptive_threshold")  # None: every pixel gets samples
    j["adaptive_min_samples"] = spec.get("adaptive_min_samples")
    j["blur_max_px"] = BLUR_MAX
    j["lens"]["model"] = ("thin-lens radius from the Z pass (coc_formula), applied by Blender's "
                          "compositor Defocus node: a gather through a round bokeh, each "
                          "neighbour within min(its radius, this pixel's radius); checked by "
                          "tools/corpus/check_defocus.py")
    j["files"] = dict(FILES)
    j["passes"]["clean"] = ("the misfocused frame without noise: the sharp render (linear) "
                            "through the compositor's Defocus node with the coc of each pixel, "
                            "sRGB 16-bit")
    j["passes"]["coc"] = ("blur radius px of the visible surface of the sharp frame, coc_formula "
                          "with that frame's focus distance, clamped at blur_max_px: the radius "
                          "the Defocus node applies, 1 channel float")
    j["passes"].pop("input", None)
    for key in ("noise_sigma", "h264"):
        j.pop(key, None)
