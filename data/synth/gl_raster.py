"""The `gl` render backend: the world's triangles rasterised by OpenGL through a headless EGL context.

TinyRenderer (the `tiny` backend, the reference) rasterises in one CPU thread and scans every
triangle's whole screen box; Mesa's llvmpipe compiles the shaders to vector code and bins
triangles into tiles, so the same frame costs a fraction (a GPU, where EGL finds one, less still).
Geometry is the meshes the world built its pybullet bodies from (`Chunk.meshes`), uploaded once
into one vertex buffer; culling picks which bodies' index ranges are drawn. Shading is
TinyRenderer's formula (ambient + (diffuse * max(0, n.l) + specular) * light colour, on the
texel times the body's tint, truncated to integers), with nearest, repeating texture lookups
(images uploaded bottom row first, as TinyRenderer reads them).
Depth is the planar distance itself, interpolated per pixel, and a second float target carries
the body id, so depth and mask need no decoding.

Shadows are TinyRenderer's model, drawn the same way (`light_clip_matrix`): a first pass draws every
body's planar depth seen from the sun (at `lightDistance` along the light direction, looking at the
world origin through the camera's own perspective, into a map of the camera's size, both faces);
the colour pass looks each fragment up in that map (nearest texel, clamped at the edges) and scales
its direct light (diffuse + specular, not ambient) by 0.8 where something lies nearer the sun.
Like TinyRenderer's, the light's pass keeps only what lies between the camera's near and far planes
from the sun: with the sun further than `camera.far` from the scene, nothing is shadowed.

A frame whose colour nobody reads (`shoot_depth_ids`: a learner's mask + depth observations) is
drawn by a second program with no texture or light and one float target: the same vertices and
the same depth expression, so depth and ids are those of the full pass, pixel for pixel. Every
vertex carries its body id there, so all bodies go in one multi-draw call (GL 4.3's indirect
draw; one call per body on a 3.3 driver), in the same front-to-back order as the full pass.

llvmpipe rasterises in as many threads as `LP_NUM_THREADS` says (the machine's cores when unset).
Unset, segmin sets it to this process's share of the cores (`cores_for_this_process`) before the
first context starts: all of them for a process rendering alone (the env, one nav-eval worker:
1.3x the steps of one thread on 2 cores), one each for two workers of a pool on 2 cores.
The colour pass is one multi-draw call: every texture in one array texture and each body's tint
and texture layer in attributes of its vertices, so the driver is given one draw instead of one
per body with its texture and uniforms (about 1 ms a frame less on the CPU).
Waiting for the frame (`_finish`) lets go of the GIL, which moderngl's calls keep: a segmenter on
another thread runs while llvmpipe's threads rasterise.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import functools
import importlib
import importlib.util
import math
import os
from typing import Any

import numpy as np

from segmin.common.machine import cores_for_this_process
from segmin.data.synth.camera import CameraModel
from segmin.data.synth.world import World

# The colour pass's two shaders start with "#define SHADOWS 0|1" (`_colour_program`): a frame without
# shadows neither projects its vertices into the sun's view nor carries that projection to the fragments.
_VERTEX_SHADER = """
uniform mat4 clip_from_world;
uniform mat4 sun_clip_from_world;
uniform vec4 depth_row;  // planar depth = dot(depth_row, (p, 1))
in vec3 in_pos;
in vec3 in_nrm;
in vec2 in_uv;
in float in_body;
in vec4 in_look;  // the body's tint (rgb) and texture layer
in vec2 in_texture_size;
out vec3 v_nrm;
out vec2 v_uv;
out float v_depth;
#if SHADOWS
out vec4 v_sun_clip;
#endif
flat out vec3 v_tint;
flat out ivec3 v_texture;  // width, height, layer
flat out float v_body;
void main() {
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
    v_nrm = in_nrm;
    v_uv = in_uv;
    v_depth = dot(depth_row, vec4(in_pos, 1.0));
#if SHADOWS
    v_sun_clip = sun_clip_from_world * vec4(in_pos, 1.0);
#endif
    v_tint = in_look.rgb;
    v_texture = ivec3(int(in_texture_size.x), int(in_texture_size.y), int(in_look.w));
    v_body = in_body;
}
"""

_FRAGMENT_SHADER = """
uniform sampler2DArray texels;  // every texture, bottom row first, from each layer's corner
uniform vec3 light_dir;
uniform vec3 light_colour;
uniform vec3 terms;  // ambient, diffuse, specular coefficients
uniform vec3 backward;  // world direction from the scene towards the camera (eye-space +z)
in vec3 v_nrm;
in vec2 v_uv;
in float v_depth;
flat in vec3 v_tint;
flat in ivec3 v_texture;
flat in float v_body;
layout(location = 0) out vec4 colour;
layout(location = 1) out vec2 depth_and_body;
#if SHADOWS
uniform sampler2D sun_depth;  // (planar depth from the sun, body + 1; 0 = nothing) per texel
uniform vec2 sun_clip_z;  // the sun projection's clip z = x * planar depth - y
in vec4 v_sun_clip;
float sunlight() {  // TinyRenderer's test: 0.8 where something lies nearer the sun, else 1
    ivec2 size = textureSize(sun_depth, 0);
    vec2 window = vec2(size) * 0.5 * (v_sun_clip.xy / v_sun_clip.w + 1.0);
    vec2 nearest = texelFetch(sun_depth, ivec2(clamp(window, vec2(0.0), vec2(size - 1))), 0).xy;
    if (nearest.y == 0.0) return 1.0;
    float occluder = sun_clip_z.x * nearest.x - sun_clip_z.y;
    return -occluder < -0.5 * (v_sun_clip.z + v_sun_clip.w) + 0.05 ? 1.0 : 0.8;
}
#else
float sunlight() { return 1.0; }
#endif
vec3 texel() {  // nearest texel, repeating: GL's rule (floor of uv times size, wrapped)
    ivec2 size = v_texture.xy;
    ivec2 at = ivec2(floor(v_uv * vec2(size)));
    at -= size * ivec2(floor(vec2(at) / vec2(size)));
    return texelFetch(texels, ivec3(at, v_texture.z), 0).rgb;
}
void main() {
    vec3 n = normalize(v_nrm);
    float diffuse = max(0.0, dot(n, light_dir));
    float reflected = max(dot(normalize(2.0 * dot(n, light_dir) * n - light_dir), backward), 0.0);
    // TinyRenderer's specular exponent comes from a specular map we do not give it; 4 makes the mean
    // colour of every kind of surface agree within a few percent (render-agreement bench). Multiplied
    // out: pow() costs llvmpipe about 0.2 ms a frame.
    float squared = reflected * reflected;
    float specular = squared * squared;
    vec3 base = floor(texel() * 255.0 + 0.5) * v_tint;
    float direct = sunlight();
    vec3 lit = terms.x * base + direct * (terms.y * diffuse + terms.z * specular) * base * light_colour;
    colour = vec4(min(floor(lit), 255.0) / 255.0, 1.0);
    depth_and_body = vec2(v_depth, v_body + 1.0);
}
"""

_IDS_VERTEX_SHADER = """
#version 330
uniform mat4 clip_from_world;
uniform vec4 depth_row;
in vec3 in_pos;
in float in_body;
out float v_depth;
flat out float v_body;
void main() {
    gl_Position = clip_from_world * vec4(in_pos, 1.0);
    v_depth = dot(depth_row, vec4(in_pos, 1.0));
    v_body = in_body;
}
"""

_IDS_FRAGMENT_SHADER = """
#version 330
in float v_depth;
flat in float v_body;
layout(location = 0) out vec2 depth_and_body;
void main() {
    depth_and_body = vec2(v_depth, v_body + 1.0);
}
"""


def _colour_program(ctx, shadows: bool):
    """The colour pass's program, with or without the sun's shadow test compiled in."""
    header = f"#version 330\n#define SHADOWS {int(shadows)}\n"
    return ctx.program(vertex_shader=header + _VERTEX_SHADER, fragment_shader=header + _FRAGMENT_SHADER)


def _context():
    """The process's one headless context: contexts are costly, a process renders one frame at a
    time, and GL objects must be released in the context that made them.

    A process forked from one that had opened it cannot render (llvmpipe's threads stay in the
    parent, and a new context shares the inherited display): its first frame would wait forever,
    so it gets one line saying to spawn instead."""
    ctx, opened_by = _opened_context()
    if opened_by != os.getpid():
        raise OSError(
            "render.backend=gl: this process was forked from one that had already rendered with gl, and "
            "OpenGL does not survive a fork; start the workers with 'spawn' (for Gymnasium's async "
            "vectors: vector_kwargs={'context': 'spawn'})"
        )
    return ctx


def opened_in_this_process() -> bool:
    """Whether this process (or the one it was forked from) has opened its OpenGL context: a
    worker forked from it now could not render with gl, so it must be spawned."""
    return _opened_context.cache_info().currsize > 0


@functools.cache
def _opened_context():
    """The context this process opened first, and the process id that opened it."""
    return open_context(), os.getpid()


class NoHeadlessGl(OSError):
    """No OpenGL 3.3 context through EGL opens in this process (no library, driver or device):
    one line saying what to install; `reason` is what the driver said."""

    def __init__(self, reason: str) -> None:
        super().__init__(
            "render.backend=gl found no headless OpenGL 3.3 through EGL (install Mesa's libegl1 and "
            f"libgl1-mesa-dri, or use render.backend=tiny): {reason}"
        )
        self.reason = reason


@functools.cache
def headless_gl_problem() -> str | None:
    """Why OpenGL through EGL cannot load here, or None where its libraries are found (what
    `render.backend=auto` asks). Found without opening a context: a process that has opened one can
    no longer fork workers that render (`_context`), and an env built only for its spaces (Gymnasium's
    async vectors build one in the parent) must not spoil its workers."""
    if importlib.util.find_spec("moderngl") is None:
        return "moderngl is not installed (the [sim] extra)"
    for library, variable in (("EGL", "GLCONTEXT_LINUX_LIBEGL"), ("GL", "GLCONTEXT_LINUX_LIBGL")):
        if not (os.environ.get(variable) or ctypes.util.find_library(library)):  # what glcontext loads
            return f"no lib{library} found (Mesa's libegl1 and libgl1-mesa-dri provide it)"
    return None


def open_context():
    """A new headless EGL context; a missing EGL or driver becomes one line saying what to install."""
    os.environ.setdefault("LP_NUM_THREADS", str(cores_for_this_process()))
    _load_tritons_llvm_first()
    import moderngl  # the [sim] extra; a missing one is named by the command line

    try:
        # moderngl's stub types each `**settings` value as a dict; the backend name is a string.
        ctx = moderngl.create_context(standalone=True, backend="egl", require=330)  # type: ignore[arg-type]
    except Exception as err:  # moderngl raises plain Exceptions for a missing library or display
        raise NoHeadlessGl(str(err)) from None
    ctx.gc_mode = "auto"  # buffers of a world go with its renderer
    return ctx


def _load_tritons_llvm_first() -> None:
    """Mesa's llvmpipe loads its LLVM with global symbols; triton (which torch imports for compiled
    kernels) links an LLVM of its own whose static constructors, run after Mesa's is loaded, bind
    to Mesa's and crash the process (a segfault in the middle of an import, or a test suite's).
    Loaded first, triton's LLVM keeps to itself. About half a second, once, where triton is installed."""
    if importlib.util.find_spec("triton") is not None:
        with contextlib.suppress(ImportError):
            importlib.import_module("triton._C.libtriton")


@functools.cache
def _gl_finish() -> Any:
    """glFinish through ctypes, which lets go of the GIL while it waits (moderngl's calls keep it)."""
    egl = ctypes.CDLL(os.environ.get("GLCONTEXT_LINUX_LIBEGL") or ctypes.util.find_library("EGL"))
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    return ctypes.CFUNCTYPE(None)(egl.eglGetProcAddress(b"glFinish"))


def _finish() -> None:
    """Wait for the frame's rasterisation without the GIL: llvmpipe rasterises in threads of its
    own, and a segmenter on another Python thread (nav-eval's helper) runs meanwhile instead of
    waiting for a read-back that would hold the GIL throughout."""
    _gl_finish()()


def clip_matrix(camera: CameraModel, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-to-clip matrix whose pixel centres look where `camera.intrinsics()` says, and the row
    giving planar depth. The image comes out top row first (y is not flipped), so the read-back
    needs no flip; GL's pixel (u, v) centre sits at window (u + 0.5, v + 0.5)."""
    k = camera.intrinsics()
    w, h, n, f = camera.width, camera.height, camera.near, camera.far
    project = np.array(
        [
            [2 * k["fx"] / w, 0.0, 2 * (k["cx"] + 0.5) / w - 1, 0.0],
            [0.0, 2 * k["fy"] / h, 2 * (k["cy"] + 0.5) / h - 1, 0.0],
            [0.0, 0.0, (f + n) / (f - n), -2 * f * n / (f - n)],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )
    camera_from_world = np.linalg.inv(pose)
    return project @ camera_from_world, camera_from_world[2]


def light_clip_matrix(camera: CameraModel, light: dict) -> tuple[np.ndarray, np.ndarray]:
    """TinyRenderer's view of the scene from the sun: world-to-clip matrix and the planar-depth row.

    The eye sits `lightDistance` along the (normalised) light direction, looks at the world origin
    with z up, through the camera's own OpenGL perspective (vertical field of view, aspect, near,
    far: the matrix `Renderer.set_camera` gives pybullet), as TinyRenderer's shadow pass does."""
    direction = np.asarray(light["lightDirection"], float)
    eye = direction / np.linalg.norm(direction) * float(light["lightDistance"])
    forward = -eye / np.linalg.norm(eye)
    side = np.cross(forward, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    up = np.cross(side, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = side, up, -forward
    view[:3, 3] = -view[:3, :3] @ eye
    near, far = camera.near, camera.far
    tan_v = math.tan(math.radians(camera.vfov_deg) / 2)
    aspect = math.tan(math.radians(camera.hfov_deg) / 2) / tan_v
    project = np.array(
        [
            [1 / (tan_v * aspect), 0.0, 0.0, 0.0],
            [0.0, 1 / tan_v, 0.0, 0.0],
            [0.0, 0.0, (far + near) / (near - far), 2 * far * near / (near - far)],
            [0.0, 0.0, -1.0, 0.0],
        ]
    )
    return project @ view, -view[2]


class GlRasteriser:
    """One world's meshes and textures in GL buffers; draws the bodies it is given from a pose."""

    def __init__(self, world: World) -> None:
        self.ctx = ctx = _context()
        self.programs = {shadows: _colour_program(ctx, shadows) for shadows in (False, True)}
        self.ids_program = ctx.program(vertex_shader=_IDS_VERTEX_SHADER, fragment_shader=_IDS_FRAGMENT_SHADER)
        vertices, body_of_vertex, indices, self.ranges = _pack(world)
        self.centre = np.zeros((max(self.ranges) + 1, 3))
        for chunk in world.chunks:
            self.centre[[b for b in chunk.bodies if b >= 0]] = chunk.centre
        vbo = ctx.buffer(vertices.tobytes())
        ibo = ctx.buffer(indices.tobytes())
        body_vbo = ctx.buffer(body_of_vertex.tobytes())
        # Per vertex, its body's (tint, layer, texture width, height): written by `set_looks`.
        self.body_of_vertex = body_of_vertex.astype(np.int64)
        self.looks = np.zeros((max(self.ranges) + 1, 6), np.float32)
        self.looks_vbo = ctx.buffer(reserve=len(body_of_vertex) * self.looks.shape[1] * 4)
        self.vaos = {
            shadows: ctx.vertex_array(
                program,
                [
                    (vbo, "3f 3f 2f", "in_pos", "in_nrm", "in_uv"),
                    (body_vbo, "1f", "in_body"),
                    (self.looks_vbo, "4f 2f", "in_look", "in_texture_size"),
                ],
                index_buffer=ibo,
                index_element_size=4,
            )
            for shadows, program in self.programs.items()
        }
        self.ids_vao = ctx.vertex_array(
            self.ids_program,
            [(vbo, "3f 20x", "in_pos"), (body_vbo, "1f", "in_body")],
            index_buffer=ibo,
            index_element_size=4,
        )
        # Indirect draw commands (count, instances, first index, base vertex, base instance) per body.
        self.commands = np.zeros((len(self.ranges), 5), np.uint32)
        self.commands[:, 1] = 1
        self.multi_draw = ctx.version_code >= 430
        self.command_buffer = ctx.buffer(reserve=self.commands.nbytes) if self.multi_draw else None
        self.texels, self.layer_of = _texture_array(ctx, world.textures.images)
        self._targets: dict[tuple[int, int, bool], Any] = {}
        self._sun_targets: dict[tuple[int, int], tuple[Any, Any]] = {}
        self.all_bodies = sorted(self.ranges)
        # Every body's vertices lie within this sphere: the sun's pass is skipped where none of them
        # lies between the sun's near and far planes (the worlds' own sun), drawing nothing either way.
        self.bounds = np.array(
            [_bounding_sphere(m.vertices) for chunk in world.chunks for m in chunk.meshes if len(m.vertices)]
        ).reshape(-1, 4)
        for shadows, program in self.programs.items():
            program["texels"].value = 0
            if shadows:
                program["sun_depth"].value = 1

    def set_looks(self, rgba: dict[int, list[float]], texture: dict[int, int]) -> None:
        """Each body's tint and texture (a texture the world does not hold: plain white), given to
        the colour pass as attributes of every vertex: the whole frame is then one draw call, and no
        vertex looks its body up (a per-body table read in the vertex shader cost 0.2-0.4 ms a frame)."""
        for body, tint in rgba.items():
            layer, width, height = self.layer_of.get(texture[body], self.layer_of[None])
            self.looks[body] = (*tint[:3], layer, width, height)
        self.looks_vbo.write(self.looks[self.body_of_vertex].tobytes())

    def _target(self, width: int, height: int, colour: bool):
        """The framebuffer of a frame size: colour, (depth, body) and a depth buffer, or without colour."""
        key = (width, height, colour)
        if key not in self._targets:
            ctx = self.ctx
            attachments = [ctx.renderbuffer((width, height), 4)] if colour else []
            attachments.append(ctx.renderbuffer((width, height), 2, dtype="f4"))
            self._targets[key] = ctx.framebuffer(
                color_attachments=attachments, depth_attachment=ctx.depth_renderbuffer((width, height))
            )
        return self._targets[key]

    def _begin(self, program, camera: CameraModel, pose: np.ndarray, colour: bool):
        """Bind and clear the frame's target and set the camera's uniforms; returns the target."""
        ctx = self.ctx
        fbo = self._target(camera.width, camera.height, colour)
        fbo.use()
        ctx.enable(ctx.DEPTH_TEST)
        ctx.enable(ctx.CULL_FACE)  # TinyRenderer draws front faces only (leaves are one-sided)
        ctx.front_face = "cw"  # our projection keeps the image top row first, which mirrors the winding
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        clip, depth_row = clip_matrix(camera, pose)
        program["clip_from_world"].write(clip.T.astype("f4").tobytes())
        program["depth_row"].value = tuple(depth_row)
        return fbo

    def _sun_target(self, width: int, height: int):
        """The sun's depth map of a frame size (a float texture the colour pass reads) and its framebuffer."""
        key = (width, height)
        if key not in self._sun_targets:
            import moderngl

            ctx = self.ctx
            texture = ctx.texture((width, height), 2, dtype="f4")
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            fbo = ctx.framebuffer(color_attachments=[texture], depth_attachment=ctx.depth_renderbuffer((width, height)))
            self._sun_targets[key] = (texture, fbo)
        return self._sun_targets[key]

    def _sun_sees_something(self, camera: CameraModel, light: dict) -> bool:
        """Whether any body may lie between the near and far planes of the sun's view (its pass,
        and so every shadow, is empty otherwise)."""
        _, depth_row = light_clip_matrix(camera, light)
        depth = self.bounds[:, :3] @ depth_row[:3] + depth_row[3]
        radius = self.bounds[:, 3]
        return bool(((depth + radius >= camera.near) & (depth - radius <= camera.far)).any())

    def _sun_pass(self, camera: CameraModel, light: dict) -> np.ndarray:
        """Draw every body (shown or not, all levels of detail, both faces: TinyRenderer's shadow pass
        draws all it holds) as the sun sees it into the sun's depth map, bound to texture unit 1;
        returns the sun's world-to-clip matrix."""
        ctx = self.ctx
        texture, fbo = self._sun_target(camera.width, camera.height)
        fbo.use()
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        clip, depth_row = light_clip_matrix(camera, light)
        # TinyRenderer fills the map at whole window coordinates, GL at pixel centres: half a texel over.
        shift = np.eye(4)
        shift[0, 3], shift[1, 3] = 1 / camera.width, 1 / camera.height
        self.ids_program["clip_from_world"].write((shift @ clip).T.astype("f4").tobytes())
        self.ids_program["depth_row"].value = tuple(depth_row)
        self._draw(self.ids_vao, self.all_bodies)
        texture.use(1)
        return clip

    def _draw(self, vao, bodies: list[int]) -> None:
        """The bodies, in order, through a program that reads each vertex's body: one indirect
        multi-draw, or one call per body."""
        if self.multi_draw and self.command_buffer is not None and bodies:
            commands = self.commands[: len(bodies)]
            commands[:, [2, 0]] = [self.ranges[b] for b in bodies]
            self.command_buffer.write(commands.tobytes())
            vao.render_indirect(self.command_buffer, count=len(bodies))
        else:
            for b in bodies:
                first, count = self.ranges[b]
                vao.render(first=first, vertices=count)

    def _front_to_back(self, pose: np.ndarray, bodies: list[int]) -> list[int]:
        """`bodies` nearest first: the depth test then skips most hidden fragments' shading."""
        if not bodies:
            return []
        order = np.argsort(np.linalg.norm(self.centre[bodies] - pose[:3, 3], axis=1))
        return np.asarray(bodies)[order].tolist()

    def shoot(
        self,
        camera: CameraModel,
        pose: np.ndarray,
        light: dict,
        bodies: list[int],
        shadow: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """RGB (uint8), planar depth (metres, 0 where nothing was hit) and body ids (-1 = none);
        `shadow` draws TinyRenderer's shadows (module docstring)."""
        shadow = shadow and self._sun_sees_something(camera, light)
        prog = self.programs[shadow]
        if shadow:
            sun_clip = self._sun_pass(camera, light)
            prog["sun_clip_from_world"].write(sun_clip.T.astype("f4").tobytes())
            near, far = camera.near, camera.far
            prog["sun_clip_z"].value = ((far + near) / (far - near), 2 * far * near / (far - near))
        fbo = self._begin(prog, camera, pose, colour=True)
        direction = np.asarray(light["lightDirection"], float)
        prog["light_dir"].value = tuple(direction / np.linalg.norm(direction))
        prog["light_colour"].value = tuple(light["lightColor"])
        prog["terms"].value = (light["lightAmbientCoeff"], light["lightDiffuseCoeff"], light["lightSpecularCoeff"])
        prog["backward"].value = tuple(-pose[:3, 2])
        self.texels.use(0)
        self._draw(self.vaos[shadow], self._front_to_back(pose, bodies))
        _finish()
        w, h = camera.width, camera.height
        rgb = np.frombuffer(fbo.read(components=3, attachment=0), np.uint8).reshape(h, w, 3).copy()
        return (rgb, *_depth_and_ids(fbo, 1, w, h))

    def shoot_depth_ids(
        self, camera: CameraModel, pose: np.ndarray, bodies: list[int]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Planar depth and body ids as `shoot` gives them, without colour (module docstring)."""
        fbo = self._begin(self.ids_program, camera, pose, colour=False)
        self._draw(self.ids_vao, self._front_to_back(pose, bodies))
        _finish()
        return _depth_and_ids(fbo, 0, camera.width, camera.height)


def _depth_and_ids(fbo, attachment: int, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The (depth, body + 1) target read back: float32 depth and int32 body ids (-1 = none)."""
    zid = np.frombuffer(fbo.read(components=2, attachment=attachment, dtype="f4"), np.float32)
    zid = zid.reshape(height, width, 2)
    return zid[..., 0].copy(), zid[..., 1].astype(np.int32) - 1


def _texture_array(ctx, images: dict[int, np.ndarray]) -> tuple[Any, dict[int | None, tuple[int, int, int]]]:
    """Every texture in one array texture (each image bottom row first, from its layer's corner;
    the last layer plain white for bodies without one) and, per texture id (None: the white one),
    its (layer, width, height)."""
    import moderngl

    width = max((img.shape[1] for img in images.values()), default=1)
    height = max((img.shape[0] for img in images.values()), default=1)
    layers = np.zeros((len(images) + 1, height, width, 3), np.uint8)
    layer_of: dict[int | None, tuple[int, int, int]] = {}
    for layer, (tid, img) in enumerate(images.items()):
        layers[layer, : img.shape[0], : img.shape[1]] = img[::-1, :, :3]
        layer_of[tid] = (layer, img.shape[1], img.shape[0])
    layers[-1, 0, 0] = 255
    layer_of[None] = (len(images), 1, 1)
    texels = ctx.texture_array((width, height, len(layers)), 3, layers.tobytes())
    texels.filter = (moderngl.NEAREST, moderngl.NEAREST)
    return texels, layer_of


def _bounding_sphere(vertices: np.ndarray) -> tuple[float, float, float, float]:
    """Centre of the vertices' box and the largest distance from it: a sphere holding them all."""
    centre = (vertices.min(axis=0) + vertices.max(axis=0)) / 2
    return (*centre.tolist(), float(np.linalg.norm(vertices - centre, axis=1).max()))


def _pack(world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[int, tuple[int, int]]]:
    """Every body's mesh in one interleaved float32 vertex array (position, normal, uv), each
    vertex's body id (float32), and one uint32 index array; `ranges[body]` = (first index, index
    count)."""
    vertex_parts, body_parts, index_parts, ranges = [], [], [], {}
    n_vertices = n_indices = 0
    for chunk in world.chunks:
        for body, mesh in zip(chunk.bodies, chunk.meshes):
            vertex_parts.append(np.hstack([mesh.vertices, mesh.normals, mesh.uvs]).astype(np.float32))
            body_parts.append(np.full(len(mesh.vertices), body, np.float32))
            index_parts.append((mesh.indices + n_vertices).astype(np.uint32))
            ranges[body] = (n_indices, len(mesh.indices))
            n_vertices += len(mesh.vertices)
            n_indices += len(mesh.indices)
    return np.concatenate(vertex_parts), np.concatenate(body_parts), np.concatenate(index_parts), ranges
