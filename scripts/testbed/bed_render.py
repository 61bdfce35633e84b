"""Renders one test-bed scene's fluid with Blender's Cycles path tracer (the `bpy` module).

    python bed_render.py <job.json>

The job (written by make_bed.py) names the particle file (T×N×3 `pos`), the cameras (a 4x4
camera-to-world in Blender's convention, which is NeRF's: looks down -z, +y up; the horizontal
field of view), the material, the image size, the samples and the list of renders
(frame, camera, output path). The fluid surface is made per frame by geometry nodes: the
particles as points -> a fog volume of spheres -> a mesh at a density threshold -> a few
position-blur iterations -> smooth shading. Only the fluid is rendered: the container is not
drawn, the film is transparent (alpha 0 on the background), and the world (a sky-like
gradient) lights the scene and shows through the glass water's refraction.
"""

import json
import math
import sys
import time

import bpy
import numpy as np


def reset_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def world_gradient(scene, up_index, strength):
    world = bpy.data.worlds.new("bed_world")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = strength
    coord = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    # the direction's up component in [-1, 1] -> [0, 1]
    mapr = nt.nodes.new("ShaderNodeMapRange")
    mapr.inputs["From Min"].default_value = -1.0
    mapr.inputs["From Max"].default_value = 1.0
    nt.links.new(coord.outputs["Generated"], sep.inputs[0])
    nt.links.new(sep.outputs["XYZ"[up_index]], mapr.inputs["Value"])
    nt.links.new(mapr.outputs["Result"], ramp.inputs["Fac"])
    els = ramp.color_ramp.elements
    els[0].position, els[0].color = 0.35, (0.16, 0.13, 0.10, 1.0)  # ground: dark warm grey
    els[1].position, els[1].color = 0.62, (0.55, 0.70, 0.95, 1.0)  # sky: pale blue
    mid = els.new(0.5)
    mid.color = (0.85, 0.85, 0.82, 1.0)  # horizon: bright
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])


def material(kind):
    m = bpy.data.materials.new(kind)
    m.use_nodes = True
    bsdf = m.node_tree.nodes.get("Principled BSDF")
    inp = bsdf.inputs
    if kind == "water":
        inp["Base Color"].default_value = (0.80, 0.92, 1.0, 1.0)
        inp["Roughness"].default_value = 0.03
        inp["IOR"].default_value = 1.333
        inp["Transmission Weight"].default_value = 1.0
    elif kind == "honey":
        inp["Base Color"].default_value = (0.80, 0.33, 0.03, 1.0)
        inp["Roughness"].default_value = 0.22
        inp["IOR"].default_value = 1.49
        inp["Coat Weight"].default_value = 0.4
        inp["Coat Roughness"].default_value = 0.05
    else:
        raise ValueError(kind)
    return m


def set_enum_or_input(node, prop, socket, value):
    """Blender moved some node enums into menu sockets; set whichever this version has."""
    if hasattr(node, prop):
        setattr(node, prop, value)
    elif socket in node.inputs:
        node.inputs[socket].default_value = value.replace("_", " ").title()


def fluid_object(n, mat, radius, voxel, blur_iters):
    mesh = bpy.data.meshes.new("particles")
    mesh.vertices.add(n)
    obj = bpy.data.objects.new("fluid", mesh)
    bpy.context.scene.collection.objects.link(obj)
    ng = bpy.data.node_groups.new("surface", "GeometryNodeTree")
    ng.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    N = ng.nodes.new
    gin, gout = N("NodeGroupInput"), N("NodeGroupOutput")
    m2p = N("GeometryNodeMeshToPoints")
    p2v = N("GeometryNodePointsToVolume")
    set_enum_or_input(p2v, "resolution_mode", "Resolution Mode", "VOXEL_SIZE")
    p2v.inputs["Voxel Size"].default_value = voxel
    p2v.inputs["Radius"].default_value = radius
    p2v.inputs["Density"].default_value = 1.0
    v2m = N("GeometryNodeVolumeToMesh")
    v2m.inputs["Threshold"].default_value = 0.3
    blur = N("GeometryNodeBlurAttribute")
    blur.data_type = "FLOAT_VECTOR"
    blur.inputs["Iterations"].default_value = blur_iters
    pos = N("GeometryNodeInputPosition")
    setp = N("GeometryNodeSetPosition")
    smooth = N("GeometryNodeSetShadeSmooth")
    setm = N("GeometryNodeSetMaterial")
    setm.inputs["Material"].default_value = mat
    L = ng.links.new
    L(gin.outputs[0], m2p.inputs["Mesh"])
    L(m2p.outputs["Points"], p2v.inputs["Points"])
    L(p2v.outputs["Volume"], v2m.inputs["Volume"])
    L(v2m.outputs["Mesh"], setp.inputs["Geometry"])
    vec_in = [s for s in blur.inputs if s.name == "Value" and s.type == "VECTOR"][0]
    vec_out = [s for s in blur.outputs if s.name == "Value" and s.type == "VECTOR"][0]
    L(pos.outputs["Position"], vec_in)
    L(vec_out, setp.inputs["Position"])
    L(setp.outputs["Geometry"], smooth.inputs["Geometry"])
    L(smooth.outputs["Geometry"], setm.inputs["Geometry"])
    L(setm.outputs["Geometry"], gout.inputs[0])
    mod = obj.modifiers.new("surface", "NODES")
    mod.node_group = ng
    return obj, mesh


def sun(direction_to_light, strength):
    d = np.asarray(direction_to_light, float)
    d /= np.linalg.norm(d)
    light = bpy.data.lights.new("sun", "SUN")
    light.energy = strength
    light.angle = math.radians(8.0)
    obj = bpy.data.objects.new("sun", light)
    bpy.context.scene.collection.objects.link(obj)
    # a sun shines down its local -z: its local +z points to the light
    z = d
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    from mathutils import Matrix

    obj.matrix_world = Matrix(m.tolist())


def camera(name, c2w, angle_x):
    from mathutils import Matrix

    cam = bpy.data.cameras.new(name)
    cam.sensor_fit = "HORIZONTAL"
    cam.lens_unit = "FOV"
    cam.angle = angle_x
    cam.clip_start = 0.05
    cam.clip_end = 100.0
    obj = bpy.data.objects.new(name, cam)
    bpy.context.scene.collection.objects.link(obj)
    obj.matrix_world = Matrix(c2w)
    return obj


def main():
    with open(sys.argv[1]) as f:
        job = json.load(f)
    t0 = time.time()
    scene = reset_scene()
    pos = np.load(job["particles"])["pos"]
    n = pos.shape[1]
    up = job["up_index"]

    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = job["samples"]
    cy.use_adaptive_sampling = False
    cy.use_denoising = job.get("denoise", False)
    cy.max_bounces = 8
    cy.transmission_bounces = 8
    cy.transparent_max_bounces = 8
    cy.caustics_reflective = False
    cy.caustics_refractive = False
    cy.seed = job.get("seed", 0)
    scene.render.threads_mode = "FIXED"
    scene.render.threads = job.get("threads", 2)
    scene.render.film_transparent = True
    cy.film_transparent_glass = False  # glass opaque on the film, showing the refracted world
    scene.render.resolution_x = job["size"]
    scene.render.resolution_y = job["size"]
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = "8"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"

    world_gradient(scene, up, job.get("world_strength", 0.8))
    to_light = np.array([0.35, -0.45, 0.0])
    to_light[up] = 1.0
    sun(to_light, job.get("sun_strength", 3.0))
    mat = material(job["material"])
    fluid, mesh = fluid_object(n, mat, job["surface_radius"], job["voxel"], job.get("blur_iterations", 3))
    cams = [camera(c["name"], c["c2w"], c["angle_x"]) for c in job["cameras"]]
    print(f"[render] set up in {time.time() - t0:.1f}s; {len(job['renders'])} images of "
          f"{job['size']}² at {job['samples']} samples", flush=True)

    renders = sorted(job["renders"], key=lambda r: (r[0], r[1]))
    current = None
    t1 = time.time()
    for i, (t, k, out) in enumerate(renders):
        if t != current:
            mesh.vertices.foreach_set("co", pos[t].astype(np.float32).ravel())
            mesh.update()
            current = t
        scene.camera = cams[k]
        scene.render.filepath = out
        bpy.ops.render.render(write_still=True)
        if (i + 1) % 20 == 0 or i + 1 == len(renders):
            el = time.time() - t1
            print(f"[render] {i + 1}/{len(renders)} images, {el:.1f}s ({el / (i + 1):.2f}s each)", flush=True)
    print(f"[render] done in {time.time() - t0:.1f}s", flush=True)


if __name__ == "__main__":
    main()
