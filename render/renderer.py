"""Offscreen rendering of simulated cloth clips with pyrender over EGL (the only pyrender user).

:class:`ClothRenderer` owns one ``pyrender.OffscreenRenderer`` and one pyrender ``Scene``
(camera, key light, ambient) for its lifetime and renders clips into uint8 RGB frames of shape
(K, H, W, 3). Per clip it uploads the texture once; per frame it computes area-weighted vertex
normals and writes them and the positions into the cloth's vertex buffer in place (a new mesh
only when the material changes, as between render passes). Rasterisation and read-back take
most of a 112 x 112 frame's ~5 ms on Mesa's llvmpipe, so a rolling shutter's row bands are
each rasterised inside a scissor box around their own rows, which gives the same bytes for
about half the time of a whole frame (``benchmarks/render_bench.py``). The cloth is
two-sided: every triangle is drawn twice, once with the reversed winding and negated normals,
and back faces are culled, so whichever side faces the camera is shaded with the normal facing
the camera (pyrender's shader does not flip normals of back faces itself). Antialiasing:
pyrender already renders into a 4x multisampled framebuffer; ``supersample > 1`` additionally
renders at that factor and downsamples with ``cv2.INTER_AREA``. The cloth is rendered over a
transparent clear colour and composited over the background with the resolved coverage alpha
(premultiplied, so the antialiased silhouette blends instead of a hard depth > 0 mask).
Default size 112 x 112: see :mod:`render.camera`. The process-wide environment default
``PYOPENGL_PLATFORM=egl`` (and with it ``PYGLET_HEADLESS=1``) is set here before pyrender is
imported, so callers need none.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os

import cv2
import numpy as np
import scipy.sparse

from .camera import CameraSpec
from .capsules import capsule_mesh, capsule_pose
from .effects import (
    VisualEffects,
    apply_image_effects,
    effect_streams,
    rolling_shutter_offsets,
    shake_offsets,
)
from .lights import LightSpec

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
if os.environ["PYOPENGL_PLATFORM"] == "egl":
    # pyrender imports pyglet's window module (for its viewer, which we never open); outside
    # headless mode that loads X11 libraries, absent on a bare GPU server (seen on an H100).
    os.environ.setdefault("PYGLET_HEADLESS", "1")
# PyOpenGL logs at INFO that its optional C speed-up is not installed; on a command's console
# that line lands in the middle of the progress bars and says nothing a user can act on.
logging.getLogger("OpenGL.acceleratesupport").setLevel(logging.WARNING)


def _load_triton_before_mesa() -> None:
    """Import triton (if installed) before Mesa's llvmpipe loads its own LLVM.

    Both bundle LLVM; importing triton *after* an EGL context exists segfaults the
    process (seen with torch 2.15 + Mesa EGL: any later ``torch._dynamo`` import,
    e.g. from a double backward, crashes). Loading triton first is safe.
    """
    try:
        import triton  # noqa: F401
    except ImportError:
        pass


_load_triton_before_mesa()

import pyrender  # noqa: E402
from OpenGL import GL  # noqa: E402
from pyrender.constants import GLTF  # noqa: E402

from .passes import GREY_TEXEL, PASS_NAMES, srgb_to_linear, uv_ramp_texture  # noqa: E402

__all__ = ["ClothRenderer"]

SKIN_RGB = (0.87, 0.68, 0.56)
"""sRGB colour of the arm capsules."""


def _set_mesh_bounds(mesh: pyrender.Mesh, bounds: np.ndarray) -> None:
    # pyrender 0.1.45's Mesh.bounds uses np.infty, removed in NumPy 2; pre-setting the cached
    # value sidesteps it (the shadow pass needs scene bounds, which read every mesh's bounds).
    mesh._bounds = np.asarray(bounds, np.float64)


def _delete_offscreen_renderer(renderer: pyrender.OffscreenRenderer) -> None:
    """Like ``OffscreenRenderer.delete`` but leaves the process's EGL display initialised.

    pyrender 0.1.45's EGL platform calls ``eglTerminate`` on close, and the display is shared
    by every context of the process, so closing one renderer would break all others
    (``EGL_BAD_DISPLAY`` on their next render). Only the context is destroyed here; the
    display stays initialised for later renderers, as EGL allows.
    """
    platform = renderer._platform
    if type(platform).__name__ != "EGLPlatform":
        renderer.delete()
        return
    from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

    platform.make_current()
    renderer._renderer.delete()
    display, context = platform._egl_display, platform._egl_context
    eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
    eglDestroyContext(display, context)
    platform._egl_context = None
    platform._egl_display = None
    renderer._renderer = None
    renderer._platform = None


def _rotation(vector: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector [rad] (Rodrigues), shape (3, 3)."""
    angle = float(np.linalg.norm(vector))
    if angle < 1e-15:
        return np.eye(3)
    k = vector / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx


@dataclasses.dataclass
class _ClothGeometry:
    """Per-clip static data of the double-sided cloth."""

    indices: np.ndarray
    """Front then back triangles, uint32, shape (2F, 3)."""
    texcoord: np.ndarray
    """Texture coordinates, float32, shape (2V, 2)."""
    incidence: scipy.sparse.csr_matrix
    """Vertex-triangle incidence (V, F): summing face normals onto vertices."""
    tri_indices: np.ndarray
    """Triangles, int64, shape (F, 3)."""


class ClothRenderer:
    """Renders cloth clips (and the arm's capsules) with one reused offscreen context.

    Use as a context manager or call :meth:`close`. Rendering is deterministic: the same
    inputs and the same Generator state give the same bytes (checked across processes on
    Mesa's llvmpipe; a GPU EGL device gives its own, equally repeatable, bytes). For
    parallel generation create one renderer per worker process, after the fork (an EGL
    context does not survive ``fork``), and consider ``LP_NUM_THREADS=1`` per worker so
    llvmpipe's rasteriser threads do not oversubscribe the cores. PyOpenGL picks its platform
    when ``OpenGL`` is first imported: if another module imported it before this one with a
    different ``PYOPENGL_PLATFORM``, that choice stands.

    Args:
        camera: View and output size.
        lights: Key and ambient light (default :meth:`LightSpec.default`).
        effects: Visual effects (default: all off).
        supersample: Render at this integer factor and downsample with INTER_AREA (on top of
            pyrender's 4x MSAA); 1 is enough for training data, 2 gives cleaner texture
            detail at 4x the fragment cost.
    """

    def __init__(
        self,
        camera: CameraSpec,
        lights: LightSpec | None = None,
        effects: VisualEffects | None = None,
        *,
        supersample: int = 1,
    ):
        if not isinstance(camera, CameraSpec):
            raise TypeError(f"camera must be a CameraSpec, got {type(camera).__name__}")
        lights = LightSpec.default() if lights is None else lights
        if not isinstance(lights, LightSpec):
            raise TypeError(f"lights must be a LightSpec, got {type(lights).__name__}")
        effects = VisualEffects() if effects is None else effects
        if not isinstance(effects, VisualEffects):
            raise TypeError(f"effects must be VisualEffects, got {type(effects).__name__}")
        if isinstance(supersample, bool) or not isinstance(supersample, int) or supersample < 1:
            raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")
        self.camera, self.lights, self.effects = camera, lights, effects
        self._camera_pose = camera.pose()
        self.supersample = supersample
        self._flags = pyrender.RenderFlags.RGBA
        if effects.shadows:
            self._flags |= pyrender.RenderFlags.SHADOWS_DIRECTIONAL
        self._scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
        yfov = math.radians(camera.yfov_deg)
        self._camera_node = self._scene.add(
            pyrender.PerspectiveCamera(
                yfov=yfov, znear=camera.znear, zfar=camera.zfar, aspectRatio=camera.aspect
            ),
            pose=camera.pose(),
        )
        self._light = pyrender.DirectionalLight(color=lights.color, intensity=lights.intensity)
        self._light_node = self._scene.add(self._light, pose=lights.pose(camera.pose()))
        self._skin = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=(*srgb_to_linear(SKIN_RGB), 1.0),
            metallicFactor=0.0,
            roughnessFactor=0.7,
        )
        self._capsule_meshes: dict[tuple[float, float], pyrender.Mesh] = {}
        self._plain = {
            name: pyrender.MetallicRoughnessMaterial(
                baseColorTexture=pyrender.Texture(
                    source=np.full((8, 8, 4), (value, value, value, 255), np.uint8),
                    source_channels="RGBA",
                ),
                metallicFactor=0.0,
                roughnessFactor=effects.specular_roughness if effects.specular else 1.0,
            )
            for name, value in (("grey", GREY_TEXEL), ("black", 0))
        }
        self._uv_ramp = pyrender.MetallicRoughnessMaterial(
            baseColorTexture=pyrender.Texture(
                source=uv_ramp_texture(),
                source_channels="RGBA",
                sampler=pyrender.Sampler(
                    magFilter=GLTF.LINEAR,
                    minFilter=GLTF.LINEAR_MIPMAP_LINEAR,
                    wrapS=GLTF.CLAMP_TO_EDGE,
                    wrapT=GLTF.CLAMP_TO_EDGE,
                ),
            ),
            metallicFactor=0.0,
        )
        self._renderer = pyrender.OffscreenRenderer(
            camera.width * supersample, camera.height * supersample
        )
        self.band_scissor = True
        """Rasterise each rolling-shutter band inside a scissor box around its rows (same
        bytes as whole frames; ``False`` renders whole frames, the reference path)."""
        self.update_in_place = True
        """Write each frame's vertices into the cloth's vertex buffer instead of building a new
        mesh (same bytes; ``False`` builds a new mesh a frame, the reference path)."""
        self._scissor: slice | None = None

    # ----------------------------------------------------------------------------- lifecycle

    def close(self) -> None:
        """Free the OpenGL resources and the context (idempotent)."""
        renderer, self._renderer = getattr(self, "_renderer", None), None
        if renderer is not None:
            _delete_offscreen_renderer(renderer)

    def __enter__(self) -> ClothRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # interpreter shutdown may have torn down OpenGL already
            pass

    # ------------------------------------------------------------------------------ public

    def render_clip(
        self,
        pos: np.ndarray,
        tri_indices: np.ndarray,
        uv: np.ndarray,
        texture: np.ndarray,
        background: np.ndarray | None,
        *,
        capsules: np.ndarray | None = None,
        rng: np.random.Generator,
        coverage: bool = False,
        passes: bool = False,
        lead: int = 0,
        trail: int = 0,
    ):
        """Render one clip.

        Args:
            pos: Vertex positions [m] per frame, shape (K, V, 3).
            tri_indices: Triangles, integer, shape (F, 3).
            uv: Material coordinates [m] (any affine frame; the extent is mapped onto the
                texture, keeping the aspect ratio), shape (V, 2).
            texture: Cloth texture, uint8 RGB, shape (h, w, 3); row 0 lies along the cloth's
                smallest v, column 0 along its smallest u.
            background: Background, uint8 RGB, shape (H, W, 3) (other sizes are resized
                with INTER_AREA); ``None`` for black.
            capsules: Arm capsules per frame, rows ``[p0, p1, radius]`` [m], shape (K, C, 7).
            rng: Randomness of the enabled effects (see :func:`render.effects.effect_streams`).
            coverage: Also return the cloth's (and arm's) coverage of every pixel: the
                resolved alpha the frame was composited with, 0 = background only, 255 =
                covered (what lets training swap the background, see
                :class:`datasets.augment.BackgroundSwap`).
            passes: Also render what re-texturing needs (:mod:`render.passes`): the same
                frame with a mid-grey and with a black cloth and, unlit, the cloth's texture
                coordinates and its own coverage (``uvm``); four renders per frame instead
                of one. Implies ``coverage``; refused with the ``frame_rate`` effect.
            lead: The first ``lead`` frames of ``pos`` (and ``capsules``) lie before the
                clip: not rendered, only what a rolling shutter's first rows see (0 or 1).
                Without them, times before the clip's first frame are clamped to it.
            trail: Likewise the last ``trail`` frames, after the clip (its last rows).

        Returns:
            Frames, uint8 RGB, shape (K, H, W, 3) (K changes only with ``frame_rate``); with
            ``coverage``, the pair ``(frames, coverage uint8 (K, H, W))``; with ``passes``,
            ``(frames, coverage, passes)`` with ``passes`` ``{name: uint8 (K, H, W, 3)}`` for
            each name of :data:`render.passes.PASS_NAMES`, premultiplied by coverage like
            the frames (nothing behind the cloth).
        """
        if self._renderer is None:
            raise RuntimeError("ClothRenderer is closed")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
        pos, tri_indices, uv = self._check_mesh(pos, tri_indices, uv)
        texture = self._check_texture(texture)
        background = self._check_background(background)
        capsules = self._check_capsules(capsules, pos.shape[0])
        streams = effect_streams(rng)
        effects = self.effects
        if passes and effects.frame_rate:
            raise ValueError(
                "render passes (render.store_passes) need render.effects.frame_rate=false: "
                "resampled frames have no passes to match"
            )

        lights = self.lights
        if effects.lighting_variation:
            lights = lights.jittered(
                streams["lighting_variation"],
                direction_deg=effects.light_direction_jitter_deg,
                intensity_rel=effects.light_intensity_jitter,
            )
        self._light.intensity = lights.intensity
        self._light.color = lights.color
        self._scene.set_pose(self._light_node, lights.pose(self._camera_pose))
        self._scene.ambient_light = np.asarray(lights.ambient_rgb)

        geometry = self._cloth_geometry(tri_indices, uv)
        material = pyrender.MetallicRoughnessMaterial(
            baseColorTexture=pyrender.Texture(
                source=np.concatenate(
                    [texture, np.full((*texture.shape[:2], 1), 255, np.uint8)], axis=-1
                ),
                source_channels="RGBA",
            ),
            metallicFactor=0.0,
            roughnessFactor=effects.specular_roughness if effects.specular else 1.0,
        )
        # Bounds of the whole clip: what the shadow pass frames (kept fixed over the clip).
        lo, hi = pos.min(axis=(0, 1)), pos.max(axis=(0, 1))
        if capsules is not None:
            ends = capsules[..., :6].reshape(-1, 3)
            radius = float(capsules[..., 6].max())
            lo, hi = np.minimum(lo, ends.min(0) - radius), np.maximum(hi, ends.max(0) + radius)
        bounds = np.stack([lo, hi]).astype(np.float64)

        if lead not in (0, 1) or trail not in (0, 1) or lead + trail >= pos.shape[0]:
            raise ValueError(
                f"lead and trail must be 0 or 1 and leave frames to render, got {lead!r} and "
                f"{trail!r} for {pos.shape[0]} frames"
            )
        frame_count = pos.shape[0] - lead - trail
        if effects.motion_blur:
            fractions = np.linspace(-effects.motion_blur_shutter, 0.0, effects.motion_blur_samples)
        else:
            fractions = np.zeros(1)
        # times[k, j, s]: sample s of row band j of frame k, in frames of the clip
        bands = rolling_shutter_offsets(effects)
        times = np.maximum(
            np.arange(frame_count)[:, None, None] + bands[None, :, None] + fractions[None, None],
            -lead,
        )
        if effects.camera_shake:
            shake = shake_offsets(streams["camera_shake"], times.reshape(-1), effects)
            shake = shake.reshape(*times.shape, 6)
        else:
            shake = None

        height, width = self.camera.height, self.camera.width
        frames = np.empty((frame_count, height, width, 3), np.uint8)
        alphas = np.empty((frame_count, height, width), np.uint8)
        extra = {name: np.empty_like(frames) for name in PASS_NAMES} if passes else {}
        bg = background.astype(np.float32) if background is not None else None
        nodes: dict[str, pyrender.Node | None] = {"cloth": None}
        # Not with shadows: the box would also crop the shadow map, rendered in the same call.
        scissor = self.band_scissor and not effects.shadows
        capsule_nodes: list[tuple[pyrender.Node, tuple[float, float]]] = []
        try:
            for k in range(frame_count):
                layers = None
                for j, band_times in enumerate(times[k]):
                    accum = None
                    rows = slice(*(round(height * (j + e) / len(times[k])) for e in (0, 1)))
                    self._scissor = rows if len(times[k]) > 1 and scissor else None
                    for s, t in enumerate(band_times):
                        frame_pos = _interpolate(pos, t + lead)
                        self._set_cloth(nodes, frame_pos, geometry, material, bounds)
                        if capsules is not None:
                            self._set_capsules(capsule_nodes, _interpolate(capsules, t + lead))
                        cam_pose = self._camera_pose
                        if shake is not None:
                            delta = np.eye(4)
                            delta[:3, :3] = _rotation(shake[k, j, s, :3])
                            delta[:3, 3] = shake[k, j, s, 3:]
                            cam_pose = cam_pose @ delta
                        self._scene.set_pose(self._camera_node, cam_pose)
                        rgba = self._render(self._flags)
                        band = [rgba]
                        if passes:
                            band += self._render_passes(nodes, frame_pos, geometry, bounds)
                        band = np.concatenate(band, axis=-1).astype(np.float32)
                        accum = band if accum is None else accum + band
                    band = accum / len(band_times)
                    if self.supersample > 1:
                        band = cv2.resize(band, (width, height), interpolation=cv2.INTER_AREA)
                    if layers is None:
                        layers = band
                    else:  # the rows of band j (output rows, cut after the supersampling)
                        layers[rows] = band[rows]
                rgba = layers[..., :4]
                for p, name in enumerate(extra):
                    rgb = layers[..., 4 + 3 * p : 7 + 3 * p]
                    extra[name][k] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
                alpha = rgba[..., 3:] / 255.0
                # MSAA resolve averages with the transparent clear colour: rgb is premultiplied.
                out = rgba[..., :3] if bg is None else rgba[..., :3] + (1.0 - alpha) * bg
                frames[k] = np.clip(np.rint(out), 0, 255).astype(np.uint8)
                alphas[k] = np.clip(np.rint(rgba[..., 3]), 0, 255).astype(np.uint8)
        finally:
            self._scissor = None
            if nodes["cloth"] is not None:
                self._scene.remove_node(nodes["cloth"])
            for node, _ in capsule_nodes:
                self._scene.remove_node(node)
            self._scene.set_pose(self._camera_node, self._camera_pose)
        if passes:
            return (*apply_image_effects(frames, effects, streams, alphas), extra)
        return apply_image_effects(frames, effects, streams, alphas if coverage else None)

    def render_sequence(
        self,
        seq,
        instance: int,
        texture: np.ndarray,
        background: np.ndarray | None,
        rng: np.random.Generator,
        *,
        capsules: np.ndarray | None = None,
    ) -> np.ndarray:
        """Render one instance of a :class:`simulator.sequence.MeshSequence`.

        Args:
            seq: The sequence.
            instance: Which of its B instances.
            texture: As in :meth:`render_clip`.
            background: As in :meth:`render_clip`.
            rng: As in :meth:`render_clip`.
            capsules: The arm's capsules of all instances, shape (B, K, C, 7); ``None``: the
                ones the sequence recorded (``seq.capsules``). Other scenes have none.

        Returns:
            Frames, uint8 RGB, shape (K, H, W, 3).
        """
        if not 0 <= instance < seq.pos.shape[0]:
            raise ValueError(f"instance must be in [0, {seq.pos.shape[0] - 1}], got {instance}")
        if capsules is None:
            capsules = seq.capsules
        if capsules is None and seq.meta.get("scene") == "arm":
            raise ValueError(
                "this arm sequence carries no capsules (written before sequences recorded "
                "them); load it through simulator.cloth.rollout.with_capsules, or re-simulate"
            )
        return self.render_clip(
            seq.pos[instance],
            seq.tri_indices,
            seq.uv,
            texture,
            background,
            capsules=None if capsules is None else capsules[instance],
            rng=rng,
        )

    # ----------------------------------------------------------------------------- helpers

    @staticmethod
    def _check_mesh(pos, tri_indices, uv) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pos = np.asarray(pos, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[-1] != 3 or pos.shape[0] < 1 or pos.shape[1] < 3:
            raise ValueError(f"pos must have shape (K, V, 3) with K >= 1, got {pos.shape}")
        if not np.isfinite(pos).all():
            raise ValueError("pos contains NaN or inf")
        tri = np.asarray(tri_indices)
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] < 1:
            raise ValueError(f"tri_indices must have shape (F, 3), got {tri.shape}")
        if not np.issubdtype(tri.dtype, np.integer):
            raise ValueError(f"tri_indices must be integers, got {tri.dtype}")
        if tri.min() < 0 or tri.max() >= pos.shape[1]:
            raise ValueError(
                f"tri_indices must lie in [0, {pos.shape[1] - 1}], got [{tri.min()}, {tri.max()}]"
            )
        uv = np.asarray(uv, dtype=np.float64)
        if uv.shape != (pos.shape[1], 2) or not np.isfinite(uv).all():
            raise ValueError(f"uv must be finite with shape ({pos.shape[1]}, 2), got {uv.shape}")
        return pos, tri.astype(np.int64), uv

    @staticmethod
    def _check_texture(texture) -> np.ndarray:
        texture = np.asarray(texture)
        if texture.dtype != np.uint8 or texture.ndim != 3 or texture.shape[-1] != 3:
            raise ValueError(
                f"texture must be uint8 with shape (h, w, 3), got {texture.dtype} {texture.shape}"
            )
        return np.ascontiguousarray(texture)

    def _check_background(self, background) -> np.ndarray | None:
        if background is None:
            return None
        background = np.asarray(background)
        if background.dtype != np.uint8 or background.ndim != 3 or background.shape[-1] != 3:
            raise ValueError(
                "background must be uint8 with shape (H, W, 3), "
                f"got {background.dtype} {background.shape}"
            )
        size = (self.camera.width, self.camera.height)
        if background.shape[1::-1] != size:
            background = cv2.resize(background, size, interpolation=cv2.INTER_AREA)
        return background

    @staticmethod
    def _check_capsules(capsules, frame_count: int) -> np.ndarray | None:
        if capsules is None:
            return None
        capsules = np.asarray(capsules, dtype=np.float64)
        if capsules.ndim != 3 or capsules.shape[0] != frame_count or capsules.shape[2] != 7:
            raise ValueError(
                f"capsules must have shape ({frame_count}, C, 7), got {capsules.shape}"
            )
        if capsules.shape[1] == 0:
            return None
        if not np.isfinite(capsules).all() or not (capsules[..., 6] > 0).all():
            raise ValueError("capsules must be finite with radius (column 6) > 0")
        return capsules

    @staticmethod
    def _cloth_geometry(tri: np.ndarray, uv: np.ndarray) -> _ClothGeometry:
        vert_count, tri_count = uv.shape[0], tri.shape[0]
        extent = max(float(np.ptp(uv, axis=0).max()), 1e-12)
        unit = (uv - uv.min(axis=0)) / extent
        # pyrender uploads textures bottom row first: t = 1 - v puts texture row 0 at v = 0.
        texcoord = np.stack([unit[:, 0], 1.0 - unit[:, 1]], axis=-1).astype(np.float32)
        incidence = scipy.sparse.csr_matrix(
            (np.ones(3 * tri_count), (tri.reshape(-1), np.repeat(np.arange(tri_count), 3))),
            shape=(vert_count, tri_count),
        )
        return _ClothGeometry(
            indices=np.concatenate([tri, tri[:, ::-1] + vert_count]).astype(np.uint32),
            texcoord=np.concatenate([texcoord, texcoord]),
            incidence=incidence,
            tri_indices=tri,
        )

    def _render(self, flags) -> np.ndarray:
        """RGBA of the scene as it stands (uint8, (H, W, 4) at the supersampled size).

        While a band's rows are set (``self._scissor``, output rows), only those rows are
        rasterised, cleared and resolved; the other rows hold whatever an earlier render left
        and must not be used. Inside the box the bytes are the whole frame's: the scissor test
        drops fragments, it does not change how they are computed.
        """
        rows = self._scissor
        if rows is None:
            return self._renderer.render(self._scene, flags=flags)[0]
        s = self.supersample
        self._renderer._platform.make_current()  # scissor state belongs to this context
        GL.glEnable(GL.GL_SCISSOR_TEST)
        GL.glScissor(
            0,
            (self.camera.height - rows.stop) * s,  # GL counts rows from the bottom
            self.camera.width * s,
            (rows.stop - rows.start) * s,
        )
        try:
            return self._renderer.render(self._scene, flags=flags)[0]
        finally:
            GL.glDisable(GL.GL_SCISSOR_TEST)

    def _set_cloth(self, nodes, frame_pos, geometry: _ClothGeometry, material, bounds) -> None:
        tri = geometry.tri_indices
        p0, p1, p2 = frame_pos[tri[:, 0]], frame_pos[tri[:, 1]], frame_pos[tri[:, 2]]
        face_normals = np.cross(p1 - p0, p2 - p0)  # length = 2 x area: area weighting
        normals = geometry.incidence @ face_normals
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.where(length > 1e-20, normals / np.maximum(length, 1e-20), [0.0, 0.0, 1.0])
        positions = np.concatenate([frame_pos, frame_pos]).astype(np.float32)
        normals = np.concatenate([normals, -normals]).astype(np.float32)
        node = nodes["cloth"]
        if node is not None and self.update_in_place:
            primitive = node.mesh.primitives[0]
            if primitive.material is material and primitive._vaid is not None:
                # pyrender's vertex buffer interleaves position, normal and texcoord_0 per
                # vertex (Primitive._add_to_context); the primitive's own arrays go stale.
                data = np.ascontiguousarray(
                    np.hstack([positions, normals, geometry.texcoord]), np.float32
                )
                self._renderer._platform.make_current()
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, primitive._buffers[0])
                GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
                return
        primitive = pyrender.Primitive(
            positions=positions,
            normals=normals,
            texcoord_0=geometry.texcoord,
            indices=geometry.indices,
            material=material,
        )
        mesh = pyrender.Mesh([primitive])
        _set_mesh_bounds(mesh, bounds)
        if nodes["cloth"] is not None:
            self._scene.remove_node(nodes["cloth"])
        nodes["cloth"] = self._scene.add(mesh)

    def _render_passes(self, nodes, frame_pos, geometry, bounds) -> list[np.ndarray]:
        """RGB of every pass of :data:`PASS_NAMES` at the current pose, in that order.

        The cloth is drawn grey, then black (lit as the frame), then with the uv ramp and no
        lighting while the arm's capsules are drawn black, so that the ramp's constant blue
        measures the cloth's own coverage apart from the arm's. The caller's next frame sets
        its own cloth again.
        """
        out = []
        for name in ("grey", "black"):
            self._set_cloth(nodes, frame_pos, geometry, self._plain[name], bounds)
            out.append(self._render(self._flags)[..., :3])
        self._set_cloth(nodes, frame_pos, geometry, self._uv_ramp, bounds)
        skin = self._skin.baseColorFactor
        self._skin.baseColorFactor = np.array([0.0, 0.0, 0.0, 1.0])
        try:
            flat = pyrender.RenderFlags.RGBA | pyrender.RenderFlags.FLAT
            uvm = self._render(flat)
        finally:
            self._skin.baseColorFactor = skin
        return [*out, uvm[..., :3]]

    def _capsule_mesh(self, key: tuple[float, float]) -> pyrender.Mesh:
        mesh = self._capsule_meshes.get(key)
        if mesh is None:
            if len(self._capsule_meshes) >= 64:  # varying lengths: keep the cache bounded
                self._capsule_meshes.clear()
            tm = capsule_mesh(*key)
            mesh = pyrender.Mesh.from_trimesh(tm, material=self._skin, smooth=True)
            _set_mesh_bounds(mesh, tm.bounds)
            self._capsule_meshes[key] = mesh
        return mesh

    def _set_capsules(self, capsule_nodes: list, rows: np.ndarray) -> None:
        for c, row in enumerate(rows):
            # Millimetre-rounded keys: a rigid arm reuses one mesh per capsule for the clip.
            key = (round(float(np.linalg.norm(row[3:6] - row[:3])), 4), round(float(row[6]), 4))
            pose = capsule_pose(row[:3], row[3:6])
            if c < len(capsule_nodes) and capsule_nodes[c][1] == key:
                self._scene.set_pose(capsule_nodes[c][0], pose)
                continue
            node = self._scene.add(self._capsule_mesh(key), pose=pose)
            if c < len(capsule_nodes):
                self._scene.remove_node(capsule_nodes[c][0])
                capsule_nodes[c] = (node, key)
            else:
                capsule_nodes.append((node, key))


def _interpolate(values: np.ndarray, time: float) -> np.ndarray:
    """Linear interpolation along axis 0 at fractional index ``time`` (clamped)."""
    last = values.shape[0] - 1
    lo = min(math.floor(time), last)
    hi = min(lo + 1, last)
    weight = time - lo
    if weight <= 0.0 or hi == lo:
        return values[lo]
    return (1.0 - weight) * values[lo] + weight * values[hi]
