"""Headless MuJoCo renderer for textured boxes, cylinders and ellipsoids (RGB, depth, segmentation).

Host-side (numpy) data generation, not a jax function: it builds one MuJoCo model per scene with
``MjSpec``, compiles it once and renders any number of views of it through MuJoCo's offscreen
OpenGL context (``MUJOCO_GL=egl`` runs it headless on the CPU through Mesa llvmpipe).

Camera conventions are jaxsem's (OpenCV): ``camera_T_world`` (4, 4) maps world points into the
camera frame, x right, y down, z forward, and ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in
pixel-centre coordinates (pixel ``i`` covers ``[i - 0.5, i + 0.5]``, so the image centre is
``((W - 1) / 2, (H - 1) / 2)``). MuJoCo cameras look along their -z axis with y up, so the MuJoCo
camera frame is ``world_R_cam @ diag(1, -1, -1)``. Any ``fx, fy > 0`` and principal point are
rendered exactly through MuJoCo's camera intrinsics (sensor size ``(W, H)`` in pixel units,
focal ``(fx, fy)``, principal offset ``-(cx - (W - 1) / 2), -(cy - (H - 1) / 2)``: the signs were
measured against :func:`jaxsem.quadrics.project_bbox`); skew must be zero (MuJoCo has none).
With ``fx == fy`` and a centred principal point this is MuJoCo's ``fovy = 2 atan(0.5 H / f)``.

``MUJOCO_GL`` must name a headless backend (``egl``) before ``mujoco`` is first imported;
``import jaxsem`` sets it by default, but not if ``mujoco`` was imported earlier.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._checks import require_type
from ..quadrics import Camera, invert_pose

os.environ.setdefault("MUJOCO_GL", "egl")


class _LazyMujoco:
    """``mujoco``, imported at first use: MuJoCo is an optional dependency (the ``sim`` extra),
    and ``jaxsem.data`` also holds what needs no renderer (the BOP and FAT readers), so
    importing it must work without MuJoCo installed."""

    def __getattr__(self, name: str) -> Any:
        try:
            import mujoco as module  # deferred: mujoco is optional (the sim extra)
        except ImportError as exc:
            raise ImportError("rendering needs MuJoCo: pip install 'jaxsem[sim]' (or mujoco>=3.1)") from exc
        globals()["mujoco"] = module
        return getattr(module, name)


mujoco: Any = _LazyMujoco()

__all__ = ["SceneObject", "SceneRenderer", "render_views", "SHAPES", "bounding_ellipsoid_radii"]

SHAPES = ("box", "cylinder", "ellipsoid")

# MuJoCo draws ellipsoids and cylinders as polygons with vertices on the surface, so a silhouette
# is short of the true one by up to r (1 - cos(pi / n)) for n slices: 48 slices (and 24 stacks)
# leave 0.2 % (0.2 px on a 100 px radius) at a third of the cost of 96 on llvmpipe.
_TESSELLATION = 48
_TEXTURE_SIZE = 64


@dataclasses.dataclass(frozen=True)
class SceneObject:
    """One rigid object to render.

    Attributes:
      class_name: free-form class label (kept for the caller; the renderer ignores it).
      shape: one of ``'box'``, ``'cylinder'`` (axis along the object's z, diameter
        ``extents[0] == extents[1]``), ``'ellipsoid'`` (semi-axes ``extents / 2``).
      extents: (3,) full extents in metres along the object's x, y, z axes.
      rotation: (3, 3) object-to-world rotation.
      center: (3,) centre in the world frame, metres.
      texture_seed: seed of the object's random block texture (colours and pattern).
      rgb: optional (3,) base colour in [0, 1]; the texture is drawn around it. ``None``: random.
    """

    class_name: str
    shape: str
    extents: np.ndarray
    rotation: np.ndarray
    center: np.ndarray
    texture_seed: int = 0
    rgb: np.ndarray | None = None

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f"SceneObject.shape: expected one of {SHAPES}, got {self.shape!r}")
        ext = np.asarray(self.extents, dtype=np.float64)
        if ext.shape != (3,) or not np.all(np.isfinite(ext)) or np.any(ext <= 0):
            raise ValueError(
                f"SceneObject.extents: expected 3 positive finite lengths (m), got {np.asarray(self.extents).tolist()}"
            )
        if self.shape == "cylinder" and not math.isclose(ext[0], ext[1], rel_tol=1e-6):
            raise ValueError(
                f"SceneObject.extents: a cylinder needs extents[0] == extents[1] (its diameter), got {ext.tolist()}"
            )
        rot = np.asarray(self.rotation, dtype=np.float64)
        if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or np.linalg.det(rot) < 0:
            raise ValueError(f"SceneObject.rotation: expected a (3, 3) rotation matrix, got {rot.tolist()}")
        cen = np.asarray(self.center, dtype=np.float64)
        if cen.shape != (3,) or not np.all(np.isfinite(cen)):
            raise ValueError(
                f"SceneObject.center: expected a finite (3,) point, got {np.asarray(self.center).tolist()}"
            )
        object.__setattr__(self, "extents", ext)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "center", cen)
        if self.rgb is not None:
            object.__setattr__(self, "rgb", np.clip(np.asarray(self.rgb, dtype=np.float64).reshape(3), 0, 1))

    def corners(self) -> np.ndarray:
        """(8, 3) world corners of the object's bounding cuboid."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return (signs * self.extents / 2) @ self.rotation.T + self.center


def bounding_ellipsoid_radii(shape: str, extents) -> np.ndarray:
    """Semi-axes (3,) of the smallest axis-aligned ellipsoid containing the shape (object frame).

    A box needs ``sqrt(3) / 2`` times its extents (the ellipsoid through the 8 corners), a
    cylinder ``sqrt(2) / 2`` of its diameter and ``sqrt(2) / 2`` of its height (through its two
    rim circles), an ellipsoid is itself (``extents / 2``).
    """
    ext = np.asarray(extents, dtype=np.float64)
    if shape == "box":
        return ext * math.sqrt(3) / 2
    if shape == "cylinder":
        return ext * math.sqrt(2) / 2
    if shape == "ellipsoid":
        return ext / 2
    raise ValueError(f"shape: expected one of {SHAPES}, got {shape!r}")


def _block_texture(rng: np.random.Generator, size: int, faces: int, base=None) -> np.ndarray:
    """(faces * size, size, 3) uint8 texture of random colour blocks with dark grid lines.

    Blocks of 4-16 px give ORB corners at any scale; a base colour keeps objects of a class
    recognisable while textures vary.
    """
    base = rng.uniform(0.2, 0.9, 3) if base is None else np.asarray(base, float)
    out = np.empty((faces * size, size, 3), np.uint8)
    for f in range(faces):
        cells = int(rng.choice([4, 8, 16]))
        n = size // cells
        colours = np.clip(base + rng.normal(0, 0.25, (n, n, 3)), 0, 1)
        face = np.repeat(np.repeat(colours, cells, 0), cells, 1)
        face[::cells, :, :] *= 0.3
        face[:, ::cells, :] *= 0.3
        out[f * size : (f + 1) * size] = (face * 255).astype(np.uint8)
    return out


def _noise_texture(rng: np.random.Generator, size: int, faces: int) -> np.ndarray:
    """Background texture: smooth colour noise plus random blocks (a cluttered, feature-rich scene)."""
    out = np.empty((faces * size, size, 3), np.uint8)
    for f in range(faces):
        coarse = rng.uniform(0, 1, (8, 8, 3))
        face = np.kron(coarse, np.ones((size // 8, size // 8, 1)))
        for _ in range(12):
            y0, x0 = rng.integers(0, size - 8, 2)
            h, w = rng.integers(4, size // 3, 2)
            face[y0 : y0 + h, x0 : x0 + w] = rng.uniform(0, 1, 3)
        out[f * size : (f + 1) * size] = (np.clip(face, 0, 1) * 255).astype(np.uint8)
    return out


def _add_texture(spec, name: str, kind, pixels: np.ndarray):
    tex = spec.add_texture(name=name, type=kind, width=pixels.shape[1], height=pixels.shape[0], nchannel=3)
    tex.data = np.ascontiguousarray(pixels).tobytes()
    return tex


RENDER_OUTPUTS = ("rgb", "depth", "seg")


def _check_outputs(outputs) -> tuple:
    outputs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
    bad = [o for o in outputs if o not in RENDER_OUTPUTS]
    if bad or not outputs:
        raise ValueError(f"outputs: expected a non-empty subset of {RENDER_OUTPUTS}, got {outputs}")
    return outputs


def mujoco_quaternion(R: np.ndarray) -> np.ndarray:
    """MuJoCo's ``quat`` (w, x, y, z) of a rotation, by MuJoCo's own C routine: it runs per object
    per frame, where a jax dispatch would cost more than the conversion."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=np.float64).reshape(9))
    return q


def mujoco_intrinsics(K, width: int, height: int) -> np.ndarray:
    """Validate ``K`` (``ValueError`` naming it) for MuJoCo's pinhole model of a ``width`` x
    ``height`` image; returns MuJoCo's ``cam_intrinsic`` (4,)."""
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise ValueError(f"K: expected a finite (3, 3) intrinsics matrix, got shape {K.shape}")
    fx, fy, s, cx, cy = K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0 or fx <= 0 or fy <= 0:
        raise ValueError(f"K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
    if abs(s) > 1e-9 * fx:
        raise ValueError(f"K: MuJoCo cameras have no skew, expected K[0, 1] == 0, got {s}")
    return np.array([fx, fy, -(cx - (width - 1) / 2), -(cy - (height - 1) / 2)])


def mujoco_view(model, data, renderer, cam: int, K, camera_T_world, outputs: Sequence[str] = RENDER_OUTPUTS) -> dict:
    """Render MuJoCo camera ``cam`` placed at ``camera_T_world`` (4, 4; OpenCV axes: x right, y down,
    z forward) with pinhole ``K`` (3, 3, no skew): the one camera setup and render-pass code of
    jaxsem's MuJoCo scenes (:class:`SceneRenderer`, :class:`jaxsem.mapping.BuildingRenderer`, the
    textured-object writer of :mod:`jaxsem.volumon.data`).

    Checks ``K`` and ``camera_T_world`` (``ValueError`` naming them), runs ``mj_forward`` and the
    passes ``outputs`` asks for (each a render): ``'rgb'`` -> ``rgb`` (H, W, 3) uint8; ``'seg'``
    or ``'depth'`` -> ``geom`` (H, W) int32 geom id per pixel, -1 where no geom (the sky);
    ``'depth'`` -> ``depth`` (H, W) float32 z-depth in metres, 0 where no geom.
    """
    if renderer is None:
        raise ValueError("renderer: the scene's renderer is closed (render() called after close())")
    height, width = int(renderer.height), int(renderer.width)
    intrinsic = mujoco_intrinsics(K, width, height)
    T = np.asarray(camera_T_world, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"camera_T_world: expected a finite (4, 4) transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise ValueError("camera_T_world: its (3, 3) block is not a rotation")
    world_T_cam = invert_pose(T, xp=np)
    model.cam_pos[cam] = world_T_cam[:3, 3]
    # MuJoCo's camera looks along its -z with y up: OpenCV's frame times diag(1, -1, -1).
    model.cam_quat[cam] = mujoco_quaternion(world_T_cam[:3, :3] @ np.diag([1.0, -1.0, -1.0]))
    model.cam_sensorsize[cam] = [width, height]
    model.cam_resolution[cam] = [width, height]
    model.cam_intrinsic[cam] = intrinsic
    mujoco.mj_forward(model, data)
    out: dict = {}
    if "rgb" in outputs:
        renderer.update_scene(data, camera=cam)
        out["rgb"] = renderer.render().copy()
    if "seg" in outputs or "depth" in outputs:
        renderer.enable_segmentation_rendering()
        try:
            renderer.update_scene(data, camera=cam)
            ids = renderer.render().copy()
        finally:
            renderer.disable_segmentation_rendering()
        out["geom"] = np.where(ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), ids[..., 0], -1).astype(np.int32)
    if "depth" in outputs:
        renderer.enable_depth_rendering()
        try:
            renderer.update_scene(data, camera=cam)
            depth = renderer.render().astype(np.float32)
        finally:
            renderer.disable_depth_rendering()
        out["depth"] = np.where(out["geom"] >= 0, depth, np.float32(0.0))
    return out


class MujocoScene:
    """What jaxsem's compiled MuJoCo scenes share (:class:`SceneRenderer`,
    :class:`jaxsem.mapping.BuildingRenderer`): the offscreen renderer's opening and closing, the
    context-manager protocol, and a view with its geom ids turned into object labels.

    A subclass sets ``model``, ``data`` and ``_label`` (geom id -> object index, with a trailing
    -1 that geom id -1, no geom, reads), then calls :meth:`_open_renderer`.
    """

    model: Any
    data: Any
    _label: np.ndarray
    _renderer: Any = None

    def _open_renderer(self, width: int, height: int):
        try:
            self._renderer = mujoco.Renderer(self.model, height, width)
        except mujoco.FatalError as exc:  # pragma: no cover - depends on the machine
            raise RuntimeError(
                f"MuJoCo could not create an OpenGL context ({exc}). On a machine without a display set "
                "MUJOCO_GL=egl (or osmesa) before mujoco is first imported (import jaxsem first, or "
                f"export it); MUJOCO_GL is {os.environ.get('MUJOCO_GL')!r} here."
            ) from None

    def _view(self, cam: int, K, camera_T_world, outputs) -> tuple[dict, dict]:
        """``(out, view)``: ``out`` holds the passes asked for (``rgb``, ``depth``, ``seg`` the
        int32 object index or -1), ``view`` is :func:`mujoco_view`'s dict (``geom`` ids)."""
        if self._renderer is None:
            raise ValueError(f"{type(self).__name__}: render() called after close()")
        outputs = _check_outputs(outputs)
        view = mujoco_view(self.model, self.data, self._renderer, cam, K, camera_T_world, outputs)
        out = {k: view[k] for k in ("rgb", "depth") if k in outputs}
        if "seg" in outputs:
            out["seg"] = self._label[view["geom"]].astype(np.int32)  # index -1 hits the trailing -1
        return out, view

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class SceneRenderer(MujocoScene):
    """One compiled MuJoCo scene and its offscreen renderer; render many views, then ``close()``.

    Use as a context manager. The model is compiled once; each ``render`` only moves the camera.

    Args:
      objects: sequence of :class:`SceneObject`; their index is the segmentation label.
      width, height: image size in pixels.
      background_seed: seed of the skybox and floor textures (different seeds, different scenes).
      light_seed: seed of the number (1-3), directions, colours and intensity of the lights.
      textured: random block textures on objects (True) or flat colours (False).
      floor_z: world height of a textured floor plane (z up), or ``None`` for no floor. Floor and
        skybox are labelled -1 in the segmentation; the floor has depth, the skybox depth 0.
      antialias: 4x multisampling of the RGB pass (about 60 % slower on the CPU renderer).
      tessellation: slices of ellipsoids and cylinders (silhouette error ``1 - cos(pi / n)``).
    """

    def __init__(
        self,
        objects: Sequence[SceneObject],
        width: int,
        height: int,
        *,
        background_seed: int = 0,
        light_seed: int = 0,
        textured: bool = True,
        floor_z: float | None = None,
        antialias: bool = False,
        tessellation: int = _TESSELLATION,
    ):
        width, height = int(width), int(height)
        if int(tessellation) < 8:
            raise ValueError(f"tessellation: expected at least 8 slices, got {tessellation}")
        if width < 8 or height < 8:
            raise ValueError(f"width, height: expected at least 8 px each, got {width}x{height}")
        objects = list(objects)
        for i, ob in enumerate(objects):
            if not isinstance(ob, SceneObject):
                raise ValueError(f"objects[{i}]: expected a SceneObject, got {type(ob).__name__}")
        self.objects = objects
        self.width, self.height = width, height
        spec = mujoco.MjSpec()
        spec.visual.global_.offwidth = max(width, 64)
        spec.visual.global_.offheight = max(height, 64)
        spec.visual.quality.numslices = int(tessellation)
        spec.visual.quality.numstacks = max(4, int(tessellation) // 2)
        spec.visual.quality.shadowsize = 1024
        spec.visual.quality.offsamples = 4 if antialias else 0
        # Clip planes are fractions of the model extent; fix the extent so depth precision does
        # not depend on how large the floor is: near 1 cm, far 100 m.
        spec.stat.extent = 10.0
        spec.visual.map.znear = 0.001
        spec.visual.map.zfar = 10.0

        bg = np.random.default_rng([int(background_seed), 7919])
        sky = _noise_texture(bg, 128, 6)
        _add_texture(spec, "sky", mujoco.mjtTexture.mjTEXTURE_SKYBOX, sky)
        if floor_z is not None:
            floor_px = _block_texture(bg, 128, 1)
            _add_texture(spec, "floor_tex", mujoco.mjtTexture.mjTEXTURE_2D, floor_px)
            mat = spec.add_material(
                name="floor_mat",
                texrepeat=[2, 2],
                texuniform=True,
                specular=0.1,
                shininess=0.1,
                rgba=[*bg.uniform(0.4, 0.8, 3), 1.0],
            )
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "floor_tex"
            spec.worldbody.add_geom(
                name="floor",
                type=mujoco.mjtGeom.mjGEOM_PLANE,
                size=[0, 0, 0.05],
                pos=[0, 0, float(floor_z)],
                material="floor_mat",
            )

        self._geom_names = []
        for i, ob in enumerate(objects):
            tr = np.random.default_rng([int(ob.texture_seed), 104729])
            base = ob.rgb if ob.rgb is not None else tr.uniform(0.2, 0.9, 3)
            kwargs = {}
            if textured:
                px = _block_texture(tr, _TEXTURE_SIZE, 6, base)
                _add_texture(spec, f"tex{i}", mujoco.mjtTexture.mjTEXTURE_CUBE, px)
                mat = spec.add_material(name=f"mat{i}")
                mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"tex{i}"
                kwargs["material"] = f"mat{i}"
            else:
                kwargs["rgba"] = [*base, 1.0]
            if ob.shape == "box":
                gtype, size = mujoco.mjtGeom.mjGEOM_BOX, ob.extents / 2
            elif ob.shape == "cylinder":
                gtype, size = mujoco.mjtGeom.mjGEOM_CYLINDER, [ob.extents[0] / 2, ob.extents[2] / 2, 0]
            else:
                gtype, size = mujoco.mjtGeom.mjGEOM_ELLIPSOID, ob.extents / 2
            spec.worldbody.add_geom(
                name=f"object{i}",
                type=gtype,
                size=list(map(float, size)),
                pos=list(map(float, ob.center)),
                quat=list(map(float, mujoco_quaternion(ob.rotation))),
                **kwargs,
            )
            self._geom_names.append(f"object{i}")

        lr = np.random.default_rng([int(light_seed), 15485863])
        spec.visual.headlight.ambient = list(lr.uniform(0.15, 0.35, 3))
        spec.visual.headlight.diffuse = list(lr.uniform(0.1, 0.4, 3))
        centre = np.mean([ob.center for ob in objects], axis=0) if objects else np.zeros(3)
        for j in range(int(lr.integers(1, 4))):
            direction = lr.normal(size=3)
            direction[2] = -abs(direction[2]) - 0.5  # from above, so floors and tops are lit
            direction /= np.linalg.norm(direction)
            spec.worldbody.add_light(
                name=f"light{j}",
                type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                pos=list(map(float, centre - 3 * direction)),
                dir=list(map(float, direction)),
                diffuse=list(lr.uniform(0.25, 0.6, 3)),
                specular=[0.1, 0.1, 0.1],
                castshadow=bool(lr.random() < 0.5),
            )
        spec.worldbody.add_camera(name="view", pos=[0, 0, 0], quat=[1, 0, 0, 0], fovy=45.0)

        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        # Geom id -> object index (or -1 for the floor and anything else).
        self._label = np.full(self.model.ngeom + 1, -1, np.int32)
        for i, name in enumerate(self._geom_names):
            gid = self.model.geom(name).id
            self._label[gid] = i
            # The compiler marks geoms posed like their body (here: identity rotation) to skip
            # their own pose in kinematics; move_object changes poses, so always use them.
            self.model.geom_sameframe[gid] = 0
        self._open_renderer(width, height)

    def move_object(self, index: int, rotation, center, extents=None, *, hidden: bool = False):
        """Change object ``index``'s pose (and extents) without recompiling; ``hidden`` parks it
        far below the scene so that one compiled model can render frames with fewer objects."""
        ob = self.objects[index]
        new = SceneObject(
            ob.class_name,
            ob.shape,
            ob.extents if extents is None else extents,
            rotation,
            center,
            ob.texture_seed,
            ob.rgb,
        )
        self.objects[index] = new
        gid = self.model.geom(self._geom_names[index]).id
        pos = new.center if not hidden else np.array([0.0, 0.0, -1e4])
        self.model.geom_pos[gid] = pos
        self.model.geom_quat[gid] = mujoco_quaternion(new.rotation)
        if new.shape == "cylinder":
            self.model.geom_size[gid] = [new.extents[0] / 2, new.extents[2] / 2, 0.0]
        else:
            self.model.geom_size[gid] = new.extents / 2
        # MuJoCo's visualiser culls geoms by their bounding radius; keep it in step with the size.
        self.model.geom_rbound[gid] = float(np.linalg.norm(new.extents) / 2)

    def render(self, K, camera_T_world, *, outputs: Sequence[str] = RENDER_OUTPUTS) -> dict:
        """Render one view. ``K`` (3, 3), ``camera_T_world`` (4, 4).

        ``outputs`` picks the passes (each costs a render): any of ``'rgb'``, ``'depth'``,
        ``'seg'`` (depth also renders the segmentation pass, to zero the skybox).

        Returns:
          dict with ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 z-depth in metres (0 where
          nothing, i.e. the skybox), ``seg`` (H, W) int32 object index or -1 (those asked for).
        """
        return self._view(0, K, camera_T_world, outputs)[0]


def render_views(
    objects: Sequence[SceneObject],
    camera: Camera,
    width: int,
    height: int,
    *,
    background_seed: int = 0,
    light_seed: int = 0,
    textured: bool = True,
    floor_z: float | None = None,
    outputs: Sequence[str] = RENDER_OUTPUTS,
    antialias: bool = False,
    tessellation: int = _TESSELLATION,
) -> dict:
    """Render N views of one scene (one compiled model, one renderer, closed on return).

    Args:
      objects: sequence of :class:`SceneObject` (segmentation label = index in this list).
      camera: the N views as one :class:`jaxsem.quadrics.Camera`: ``K`` (3, 3) or (N, 3, 3)
        intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (no skew) and ``camera_T_world``
        (N, 4, 4) or (4, 4) world-to-camera transforms, OpenCV axes.
      width, height: image size in pixels.
      background_seed, light_seed, textured, floor_z, antialias, tessellation: see
        :class:`SceneRenderer`.
      outputs: the passes to render (default all three; see :meth:`SceneRenderer.render`).

    Returns:
      dict of numpy arrays: ``rgb`` (N, H, W, 3) uint8, ``depth`` (N, H, W) float32 metres
      (z-depth, 0 where nothing), ``seg`` (N, H, W) int32 object index or -1.
    """
    K, camera_T_world = require_type("camera", camera, Camera)
    poses = np.asarray(camera_T_world, dtype=np.float64)
    if poses.ndim == 2:
        poses = poses[None]
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"camera_T_world: expected shape (N, 4, 4), got {np.asarray(camera_T_world).shape}")
    Ks = np.asarray(K, dtype=np.float64)
    if Ks.shape == (3, 3):
        Ks = np.broadcast_to(Ks, (len(poses), 3, 3))
    if Ks.shape != (len(poses), 3, 3):
        raise ValueError(f"K: expected shape (3, 3) or ({len(poses)}, 3, 3), got {np.asarray(K).shape}")
    for i in range(len(poses)):
        mujoco_intrinsics(Ks[i], int(width), int(height))
    outputs = _check_outputs(outputs)
    out = {k: [] for k in outputs}
    with SceneRenderer(
        objects,
        width,
        height,
        background_seed=background_seed,
        light_seed=light_seed,
        textured=textured,
        floor_z=floor_z,
        antialias=antialias,
        tessellation=tessellation,
    ) as scene:
        for Ki, Ti in zip(Ks, poses):
            view = scene.render(Ki, Ti, outputs=outputs)
            for k in out:
                out[k].append(view[k])
    return {
        k: np.stack(v)
        if v
        else np.zeros(
            (0, int(height), int(width)) + ((3,) if k == "rgb" else ()),
            {"rgb": np.uint8, "depth": np.float32, "seg": np.int32}[k],
        )
        for k, v in out.items()
    }
