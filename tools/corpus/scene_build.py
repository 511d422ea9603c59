"""Procedural geometry, materials and lights for tools/corpus/scene.py (Blender 3.4 bpy).

World frame: Z up, ground at z = 0, the hero (subject or prop) at the origin, the camera's start
at (0, -d_h, h_c) looking along +Y. Sizes and texture scales follow the pixel footprint
px_m(D) = D * sensor_w / (f * W_px) at an object's distance D, so every surface carries detail a
few pixels across whatever the lens and the scene's scale.
"""

import colorsys
import math

import bpy
from mathutils import Vector

SUBJECT_INDEX = 1  # object pass index of the subject's parts (-> alpha_%04d.png)
_lens = {"focal_px": 1000.0}


def set_lens(focal_px):
    """Focal length in pixels: texture scales are set in pixels at an object's distance."""
    _lens["focal_px"] = focal_px


def _color(rng, v_lo=0.08, v_hi=0.75):
    h, sat, v = rng.random(), rng.uniform(0.1, 0.8), rng.uniform(v_lo, v_hi)
    return colorsys.hsv_to_rgb(h, sat, v) + (1.0,)


def _contrast_pair(rng):
    """Two colours 0.15-0.35 apart in (linear) value: detail that reads clearly, yet not so
    harsh that a blur disk sampled 16-64 times turns to speckle."""
    v0, dv = rng.uniform(0.18, 0.55), rng.uniform(0.15, 0.35)
    h = rng.random()
    h2 = (h + rng.choice([0.0, 0.05, 0.5, rng.random()])) % 1.0
    a = colorsys.hsv_to_rgb(h, rng.uniform(0.1, 0.8), max(0.02, v0 - dv / 2)) + (1.0,)
    b = colorsys.hsv_to_rgb(h2, rng.uniform(0.1, 0.8), v0 + dv / 2) + (1.0,)
    return (a, b) if rng.random() < 0.5 else (b, a)


def _texture(rng, nt, vec, kind, pair):
    """A texture node fed by vec (coordinates in pixels at the object's depth): its colour.

    Feature sizes stay at 2 px or more (few octaves) and hard edges (checker, brick) 6 px or
    more apart: finer detail only aliases into sampling noise at 16-32 samples a pixel."""
    n = nt.nodes
    if kind in ("checker", "brick"):
        if kind == "checker":
            t = n.new("ShaderNodeTexChecker")
            t.inputs["Scale"].default_value = 1.0 / rng.uniform(6, 14)  # square side, px
        else:
            t = n.new("ShaderNodeTexBrick")
            t.inputs["Scale"].default_value = 1.0
            t.inputs["Brick Width"].default_value = rng.uniform(10, 24)
            t.inputs["Row Height"].default_value = rng.uniform(6, 12)
            t.inputs["Mortar Size"].default_value = rng.uniform(1.2, 2.0)
            t.inputs["Mortar"].default_value = _color(rng, 0.3, 0.7)
            t.offset = rng.uniform(0.3, 0.6)
        t.inputs["Color1"].default_value, t.inputs["Color2"].default_value = pair
        nt.links.new(vec, t.inputs["Vector"])
        return t.outputs["Color"]
    if kind == "noise":
        t = n.new("ShaderNodeTexNoise")
        t.inputs["Scale"].default_value = 1.0 / rng.uniform(5, 12)
        t.inputs["Detail"].default_value = 2.0
        t.inputs["Roughness"].default_value = rng.uniform(0.5, 0.65)
        t.inputs["Distortion"].default_value = rng.uniform(0, 1.0)
    elif kind == "voronoi":
        t = n.new("ShaderNodeTexVoronoi")
        t.feature = rng.choice(["F1", "DISTANCE_TO_EDGE", "F2"])
        t.inputs["Scale"].default_value = 1.0 / rng.uniform(5, 14)
    elif kind == "wave":  # period = 2 pi / (10 scale) px
        t = n.new("ShaderNodeTexWave")
        t.wave_type = rng.choice(["BANDS", "RINGS"])
        t.inputs["Scale"].default_value = 0.63 / rng.uniform(5, 12)
        t.inputs["Distortion"].default_value = rng.uniform(1, 5)
        t.inputs["Detail"].default_value = 1.0
    else:  # magic
        t = n.new("ShaderNodeTexMagic")
        t.inputs["Scale"].default_value = 1.0 / rng.uniform(14, 28)
        t.turbulence_depth = 2
    nt.links.new(vec, t.inputs["Vector"])
    fac = t.outputs["Fac"] if "Fac" in t.outputs else t.outputs["Distance"]
    ramp = n.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = pair
    ramp.color_ramp.elements[0].position = rng.uniform(0.2, 0.45)
    ramp.color_ramp.elements[1].position = rng.uniform(0.55, 0.8)
    nt.links.new(fac, ramp.inputs["Fac"])
    return ramp.outputs["Color"]


def _lod(nt, color, pair, ref_dist):
    """Fades the texture to its mean colour where it lies farther than 1.5x the distance its
    scale was set for (far ground, walls): a procedural mip-map, so no detail falls below
    a pixel."""
    n = nt.nodes
    cam = n.new("ShaderNodeCameraData")
    ratio = n.new("ShaderNodeMath")
    ratio.operation = "DIVIDE"
    ratio.use_clamp = True
    ratio.inputs[0].default_value = 1.5 * ref_dist
    nt.links.new(cam.outputs["View Z Depth"], ratio.inputs[1])
    mix = n.new("ShaderNodeMixRGB")
    mix.inputs["Color1"].default_value = tuple((a + b) / 2 for a, b in zip(*pair))
    nt.links.new(ratio.outputs["Value"], mix.inputs["Fac"])
    nt.links.new(color, mix.inputs["Color2"])
    return mix.outputs["Color"]


def material(rng, name, dist, kind=None, ambient=None):
    """Diffuse (a quarter of them Principled, glossy) with a procedural texture in the colour,
    times a grain about 2-3 px across that also bumps the normal. dist: the distance (m) the
    object is seen from, which sets the texture's scale in pixels.

    Light is direct only (no bounces): an emission of colour x ambient stands in for the sky
    and bounce fill without noise (this Blender build has no denoiser), and Diffuse costs about
    half of Principled per sample on the CPU."""
    kind = kind or rng.choice(["noise", "voronoi", "checker", "brick", "wave", "magic"])
    ambient = rng.uniform(0.12, 0.25) if ambient is None else ambient
    px_m = dist / _lens["focal_px"]
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.cycles.sample_as_light = False  # emission is fill only: not a light to sample
    nt = mat.node_tree
    nt.nodes.clear()
    n = nt.nodes
    coord = n.new("ShaderNodeTexCoord")
    mapping = n.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (1.0 / px_m,) * 3  # texture units = pixels
    mapping.inputs["Rotation"].default_value = tuple(rng.uniform(0, 6.3) for _ in range(3))
    mapping.inputs["Location"].default_value = tuple(rng.uniform(-500, 500) for _ in range(3))
    nt.links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    vec = mapping.outputs["Vector"]
    pair = _contrast_pair(rng)
    color = _lod(nt, _texture(rng, nt, vec, kind, pair), pair, dist)
    grain = n.new("ShaderNodeTexNoise")
    grain.inputs["Scale"].default_value = 1.0 / rng.uniform(2.0, 3.5)
    grain.inputs["Detail"].default_value = 0.0
    nt.links.new(vec, grain.inputs["Vector"])
    mix = n.new("ShaderNodeMixRGB")
    mix.blend_type = "MULTIPLY"
    mix.inputs["Fac"].default_value = rng.uniform(0.1, 0.3)
    nt.links.new(color, mix.inputs["Color1"])
    nt.links.new(grain.outputs["Color"], mix.inputs["Color2"])
    bump = n.new("ShaderNodeBump")  # from the grain alone: the main texture x3 is too slow
    bump.inputs["Strength"].default_value = rng.uniform(0.1, 0.3)
    bump.inputs["Distance"].default_value = px_m
    nt.links.new(grain.outputs["Fac"], bump.inputs["Height"])
    if rng.random() < 0.25:
        bsdf = n.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.3, 0.6)
        bsdf.inputs["Specular"].default_value = rng.uniform(0.3, 0.5)
        nt.links.new(mix.outputs["Color"], bsdf.inputs["Base Color"])
    else:
        bsdf = n.new("ShaderNodeBsdfDiffuse")
        nt.links.new(mix.outputs["Color"], bsdf.inputs["Color"])
    nt.links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
    emit = n.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = ambient
    nt.links.new(mix.outputs["Color"], emit.inputs["Color"])
    add = n.new("ShaderNodeAddShader")
    nt.links.new(bsdf.outputs["BSDF"], add.inputs[0])
    nt.links.new(emit.outputs["Emission"], add.inputs[1])
    out = n.new("ShaderNodeOutputMaterial")
    nt.links.new(add.outputs["Shader"], out.inputs["Surface"])
    return mat


def dome_material(rng, dist, strength):
    """Emission-only far backdrop (city blocks / foliage blotches), seen by the camera only."""
    mat = bpy.data.materials.new("dome")
    mat.use_nodes = True
    mat.cycles.sample_as_light = False
    nt = mat.node_tree
    nt.nodes.clear()
    n = nt.nodes
    coord = n.new("ShaderNodeTexCoord")
    mapping = n.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (_lens["focal_px"] / dist,) * 3
    nt.links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    color = _texture(rng, nt, mapping.outputs["Vector"],
                     rng.choice(["voronoi", "brick", "noise", "magic"]), _contrast_pair(rng))
    em = n.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = strength
    nt.links.new(color, em.inputs["Color"])
    out = n.new("ShaderNodeOutputMaterial")
    nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    return mat


def _finish(obj, mat, smooth, pass_index=0):
    obj.data.materials.append(mat)
    obj.pass_index = pass_index
    if smooth:
        for p in obj.data.polygons:
            p.use_smooth = True
        obj.data.use_auto_smooth = True
        obj.data.auto_smooth_angle = math.radians(50)
    return obj


def box(loc, dims, rot_z, mat, pass_index=0):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=loc, rotation=(0, 0, rot_z))
    obj = bpy.context.object
    obj.scale = dims
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    return _finish(obj, mat, False, pass_index)


def sphere(loc, r, mat, pass_index=0):
    bpy.ops.mesh.primitive_uv_sphere_add(radius=r, location=loc, segments=40, ring_count=20)
    return _finish(bpy.context.object, mat, True, pass_index)


def cylinder(loc, r, h, mat, rot=(0, 0, 0), pass_index=0):
    bpy.ops.mesh.primitive_cylinder_add(radius=r, depth=h, location=loc, rotation=rot,
                                        vertices=40)
    return _finish(bpy.context.object, mat, True, pass_index)


def cone(loc, r, h, mat):
    bpy.ops.mesh.primitive_cone_add(radius1=r, radius2=r * 0.15, depth=h, location=loc,
                                    vertices=40)
    return _finish(bpy.context.object, mat, True)


def plane(loc, size, rot, mat):
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=loc, rotation=rot)
    obj = bpy.context.object
    obj.scale = (size[0], size[1], 1)
    bpy.ops.object.transform_apply(location=False, rotation=False, scale=True)
    return _finish(obj, mat, False)


def dome(center, radius, mat):
    """Closed backdrop so no pixel sees the sky: camera rays only (no shadows, no fill)."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=center, segments=64,
                                         ring_count=32)
    obj = bpy.context.object
    obj.data.materials.append(mat)
    obj.visible_diffuse = obj.visible_glossy = obj.visible_shadow = False
    obj.visible_transmission = obj.visible_volume_scatter = False
    return obj


def prop(rng, x, y, size, dist, name):
    """One clutter object standing on the ground, roughly size across. Returns its radius."""
    mat = material(rng, name, dist)
    kind = rng.choice(["box", "box", "sphere", "cylinder", "cylinder", "cone", "stack", "panel"])
    rz = rng.uniform(0, math.pi)
    if kind == "box":
        w, d, h = size * rng.uniform(0.5, 1), size * rng.uniform(0.5, 1), size * rng.uniform(
            0.4, 1.6)
        box((x, y, h / 2), (w, d, h), rz, mat)
    elif kind == "sphere":
        r = size / 2
        sphere((x, y, r * rng.choice([1.0, 1.0, 2.2])), r, mat)  # some float (lamps, balloons)
    elif kind == "cylinder":
        r, h = size * rng.uniform(0.2, 0.5), size * rng.uniform(0.8, 3.0)
        cylinder((x, y, h / 2), r, h, mat)
    elif kind == "cone":
        h = size * rng.uniform(0.8, 1.8)
        cone((x, y, h / 2), size / 2, h, mat)
    elif kind == "stack":
        h = size * rng.uniform(0.5, 1.0)
        box((x, y, h / 2), (size, size * 0.8, h), rz, mat)
        sphere((x, y, h + size * 0.3), size * 0.3, material(rng, name + "_top", dist))
    else:  # a thin upright panel: a sign, a fence section
        w, h = size * rng.uniform(1.0, 2.0), size * rng.uniform(0.8, 1.8)
        box((x, y, h / 2), (w, size * 0.06, h), rng.uniform(-0.6, 0.6), mat)
        return w / 2
    return size / 2


def person(rng, height, dist):
    """A figure of capsules and spheres (pass index SUBJECT_INDEX on every part).

    Returns the root empty and the hip/shoulder pivots the walk cycle swings."""
    root = bpy.data.objects.new("subject", None)
    bpy.context.scene.collection.objects.link(root)
    H = height
    shirt = material(rng, "shirt", dist, rng.choice(["checker", "wave", "noise", "voronoi"]))
    pants = material(rng, "pants", dist, rng.choice(["wave", "noise", "checker"]))
    skin = material(rng, "skin", dist, "noise")
    parts, pivots = [], {}
    leg_len, hip_z = 0.47 * H, 0.5 * H
    for side, sx in (("l", -1), ("r", 1)):
        pv = bpy.data.objects.new("hip_" + side, None)
        bpy.context.scene.collection.objects.link(pv)
        pv.parent, pv.location = root, (sx * 0.07 * H, 0, hip_z)
        leg = cylinder((0, 0, -leg_len / 2), 0.055 * H, leg_len, pants, pass_index=SUBJECT_INDEX)
        leg.parent = pv
        pivots["hip_" + side] = pv
        sv = bpy.data.objects.new("shoulder_" + side, None)
        bpy.context.scene.collection.objects.link(sv)
        sv.parent, sv.location = root, (sx * 0.165 * H, 0, 0.81 * H)
        arm = cylinder((0, 0, -0.18 * H), 0.035 * H, 0.36 * H, shirt, pass_index=SUBJECT_INDEX)
        arm.parent = sv
        pivots["shoulder_" + side] = sv
    torso = cylinder((0, 0, 0.67 * H), 0.13 * H, 0.26 * H, shirt, pass_index=SUBJECT_INDEX)
    hips = sphere((0, 0, 0.54 * H), 0.13 * H, pants, pass_index=SUBJECT_INDEX)
    chest = sphere((0, 0, 0.8 * H), 0.13 * H, shirt, pass_index=SUBJECT_INDEX)
    neck = cylinder((0, 0, 0.88 * H), 0.035 * H, 0.06 * H, skin, pass_index=SUBJECT_INDEX)
    head = sphere((0, 0, 0.93 * H), 0.065 * H, skin, pass_index=SUBJECT_INDEX)
    for p in (torso, hips, chest, neck, head):
        p.parent = root
    torso.scale = hips.scale = chest.scale = (1.0, 0.65, 1.0)  # flatter front to back
    return root, pivots


def lights(rng, d_h, hero_h, irradiance):
    """One shadow-casting key light: a sun (60%), a small area light (25%) or a point light.

    One and not two: Cycles 3.4 samples a single light per shading point, chosen with equal
    odds, so a second light doubles the noise where the two differ (measured: 5x the
    frame-to-frame noise at 10 samples); the materials' emission is the (noise-free) fill."""
    kind = rng.choices(["SUN", "AREA", "POINT"], [0.6, 0.25, 0.15])[0]
    lamp = bpy.data.lights.new("key", kind)
    obj = bpy.data.objects.new("key", lamp)
    bpy.context.scene.collection.objects.link(obj)
    info = {"key": kind.lower(), "irradiance_at_hero": round(irradiance, 3)}
    if kind == "SUN":
        lamp.energy = irradiance
        lamp.angle = math.radians(rng.uniform(0.5, 2.0))
        elev, azim = math.radians(rng.uniform(25, 60)), rng.uniform(0, 2 * math.pi)
        obj.rotation_euler = (math.pi / 2 - elev, 0, azim)
        info.update({"elevation_deg": round(math.degrees(elev), 1),
                     "azimuth_deg": round(math.degrees(azim), 1)})
        return info
    a = rng.uniform(0, 2 * math.pi)
    pos = Vector((math.cos(a) * 0.7 * d_h, math.sin(a) * 0.5 * d_h - 0.3 * d_h,
                  hero_h * rng.uniform(1.3, 2.5)))
    target = Vector((0, 0, hero_h * 0.5))
    dist2 = (pos - target).length_squared
    obj.location = pos
    if kind == "POINT":  # measured in this Cycles: E = P / (4 pi d^2) head-on
        lamp.energy = irradiance * 4 * math.pi * dist2
        lamp.shadow_soft_size = 0.02 * d_h
    else:  # a small area light facing the hero: E = 0.243 P / d^2 head-on (measured)
        lamp.energy = irradiance * dist2 / 0.243
        lamp.size = 0.1 * d_h
        obj.rotation_euler = (target - pos).to_track_quat("-Z", "Y").to_euler()
    info["position_m"] = [round(v, 4) for v in pos]
    return info
