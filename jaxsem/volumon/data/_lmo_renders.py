"""Rendered desk scenes of the LM-O objects: training data that looks like the LM-O photographs.

:func:`render_desk_frames` renders, with MuJoCo (``MUJOCO_GL=egl``; Mesa's llvmpipe on a CPU),
frames of a cluttered desk like LM-O's: the eight LM-O meshes (:data:`LMO_OBJECT_IDS`) with their
own vertex colours, standing upright at random yaw (a few degrees of tilt) in a cluster on a
textured desk in front of textured walls, YCB meshes and textured primitives as distractors among
and in front of them (so objects occlude one another), 1-3 random lights, and a camera 0.6-1.4 m
from the cluster looking down at it 5-70 degrees, with the LM-O intrinsics by default
(:data:`LMO_K`, 640 x 480). Each frame is post-processed like a cheap RGB camera (blur, noise,
gain and gamma).

Vertex colours: MuJoCo colours meshes by material or texture only, so each mesh is *baked* into a
texture atlas with one texel per triangle (the mean of its three vertex colours), every corner of
a triangle mapped to the centre of its texel (:func:`face_color_atlas`). The texture coordinates
are constant over a triangle, so the sampler returns exactly the texel (no bleeding, mip level
0), and a triangle of these dense meshes covers about a pixel at desk distance: what the camera
sees is the vertex colours at the meshes' own resolution, shaded by MuJoCo's lights. (A
per-triangle colour is what the Linemod scans hold at that resolution; chosen over clustering
faces into a few materials, which loses the printed detail, and over a new rasteriser, which would
be a second renderer to test.)

:func:`detections_from_frames` turns rendered frames into the arrays VoluMon trains on, with weak
labels only: the network inputs of each object's *visible* box (the box of its pixels in the
segmentation; the input the real evaluation gives, :func:`jaxsem.volumon.data.bop_eval_batch`), the
object's full (amodal) boxes in the left and the right image of a stereo pair (baseline
``baseline``; the boxes of its projected mesh vertices, 2D labels of the renders), and points of
its visible surface from the rendered depth. The 3D truth (pose, mesh extent) is stored beside
them for the fully supervised oracle and for scoring, never for the weak losses.

Host-side numpy + MuJoCo, not jittable.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import zipfile

import numpy as np

from ... import quadrics as Q
from ..._files import MAX_NPZ_ELEMENTS, check_npz
from ...data import LINEMOD_NAMES, Mesh, load_ply, mujoco_quaternion, mujoco_view
from ...training import check_stamp
from .._inputs import prepare_inputs
from ._objects import _LightRig, _material, _mujoco, _random_lights

os.environ.setdefault("MUJOCO_GL", "egl")

__all__ = [
    "LMO_CLASS_NAMES",
    "LMO_CLASS_SHAPES",
    "LMO_IMAGE_SIZE",
    "LMO_K",
    "LMO_OBJECT_IDS",
    "DeskConfig",
    "detections_from_frames",
    "desk_batch_source",
    "desk_eval_batch",
    "face_color_atlas",
    "is_desk_detections",
    "load_desk_detections",
    "load_distractor_meshes",
    "load_lmo_meshes",
    "render_desk_frames",
    "write_desk_detections",
]

#: The eight objects of LM-O (Linemod ids) and their class names, in class-row order.
LMO_OBJECT_IDS = (1, 5, 6, 8, 9, 10, 11, 12)
LMO_CLASS_NAMES = tuple(LINEMOD_NAMES[i] for i in LMO_OBJECT_IDS)
#: The shape each class is drawn as by VoluMon's shape-aware losses (0 cuboid, 1 ellipsoid,
#: 2 cylinder, the ids of :data:`jaxsem.volumon.data.SHAPE_IDS`): the can and the glue stand as
#: cylinders about their z axis, the driller, egg box and hole puncher are box-like, the animals round.
LMO_CLASS_SHAPES = {
    "ape": 1,
    "can": 2,
    "cat": 1,
    "driller": 0,
    "duck": 1,
    "eggbox": 0,
    "glue": 2,
    "holepuncher": 0,
}
#: LM-O's camera (``camera.json`` of the BOP data set) and image size (W, H).
LMO_K = np.array([[572.4114, 0.0, 325.2611], [0.0, 573.57043, 242.04899], [0.0, 0.0, 1.0]])
LMO_IMAGE_SIZE = (640, 480)


@dataclasses.dataclass(frozen=True)
class DeskConfig:
    """How desk frames are drawn (distances in metres, angles in degrees).

    Attributes:
      distance: range of the camera's distance to the cluster centre.
      elevation: range of the camera's angle above the desk plane.
      cluster_radius: the LM-O objects stand within this radius of the cluster centre.
      objects: (min, max) LM-O objects per frame.
      distractors: (min, max) distractors per frame (YCB meshes and primitives).
      tilt: maximum tilt of an object away from upright.
      frames_per_scene: frames per compiled scene (one desk, wall and light set per scene).
      distractor_meshes: YCB meshes per scene (drawn from those given).
    """

    distance: tuple = (0.7, 1.3)
    elevation: tuple = (5.0, 70.0)
    cluster_radius: float = 0.2
    objects: tuple = (4, 8)
    distractors: tuple = (2, 7)
    tilt: float = 12.0
    frames_per_scene: int = 8
    distractor_meshes: int = 6

    def __post_init__(self):
        lo, hi = self.distance
        if not 0.2 <= lo <= hi <= 5.0:
            raise ValueError(f"distance: expected 0.2 <= min <= max <= 5 m, got {self.distance}")
        lo, hi = self.elevation
        if not 0.0 <= lo <= hi <= 89.0:
            raise ValueError(f"elevation: expected 0 <= min <= max <= 89 degrees, got {self.elevation}")
        lo, hi = self.objects
        if not 1 <= lo <= hi <= len(LMO_OBJECT_IDS):
            raise ValueError(f"objects: expected 1 <= min <= max <= {len(LMO_OBJECT_IDS)}, got {self.objects}")
        if int(self.frames_per_scene) < 1:
            raise ValueError(f"frames_per_scene: expected >= 1, got {self.frames_per_scene}")


def load_lmo_meshes(models_dir) -> dict:
    """The eight LM-O meshes (object id -> :class:`Mesh`, metres, vertex colours) of a BOP
    ``models/`` folder; ValueError naming a missing file or a mesh without colours or faces."""
    models_dir = pathlib.Path(models_dir)
    out = {}
    for i in LMO_OBJECT_IDS:
        path = models_dir / f"obj_{i:06d}.ply"
        if not path.is_file():
            raise ValueError(f"models_dir: {path} is missing (the LM-O mesh of {LINEMOD_NAMES[i]!r})")
        mesh = load_ply(path)
        if mesh.colors is None or mesh.faces is None:
            raise ValueError(f"{path}: expected vertex colours and faces (an LM-O model)")
        out[i] = mesh
    return out


def load_distractor_meshes(mesh_dir, limit: int | None = None) -> list:
    """Vertices and faces ``[(name, vertices (V, 3) m, faces (F, 3))]`` of the STL meshes in
    ``mesh_dir`` (e.g. the YCB meshes of ``jaxsem data fetch ycb``), sorted by name."""
    paths = sorted(pathlib.Path(mesh_dir).glob("*.stl"))
    if not paths:
        raise ValueError(f"mesh_dir: no .stl meshes in {mesh_dir}")
    out = []
    for p in paths[: limit if limit is not None else len(paths)]:
        v, f = _read_stl(p)
        out.append((p.stem, v, f))
    return out


def _read_stl(path) -> tuple[np.ndarray, np.ndarray]:
    raw = pathlib.Path(path).read_bytes()
    if raw[:5] == b"solid" and b"facet" in raw[:2000]:
        words = raw.decode("ascii", "replace").split()
        xyz = [words[i + 1 : i + 4] for i, w in enumerate(words) if w == "vertex"]
        v = np.asarray(xyz, np.float64).reshape(-1, 3)
    else:
        n = int(np.frombuffer(raw, "<u4", 1, 80)[0])
        dt = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
        v = np.frombuffer(raw, dt, n, 84)["v"].reshape(-1, 3).astype(np.float64)
    if len(v) < 3 or len(v) % 3:
        raise ValueError(f"{path}: not a triangle STL")
    return v, np.arange(len(v)).reshape(-1, 3)


def face_color_atlas(mesh: Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bake per-vertex colours into a texture: ``(texcoord (F, 2), facetexcoord (F, 3), texture
    (S, S, 3) uint8)``: triangle ``i`` 's colour (the mean of its vertices') is texel ``i`` of an
    S x S atlas (S = ceil(sqrt(F))), and all three corners of the triangle use the texture
    coordinate of that texel's centre (``v`` counts rows from the first row of ``texture``, as
    MuJoCo samples texture data given as bytes)."""
    if mesh.colors is None or mesh.faces is None:
        raise ValueError("mesh: expected vertex colours and faces")
    faces = np.asarray(mesh.faces, np.int64)
    F = len(faces)
    S = max(int(np.ceil(np.sqrt(F))), 1)
    col = np.asarray(mesh.colors, np.float64)[faces].mean(1)
    tex = np.zeros((S * S, 3), np.uint8)
    tex[:F] = np.clip(np.round(col), 0, 255).astype(np.uint8)
    idx = np.arange(F)
    row, c = idx // S, idx % S
    uv = np.stack([(c + 0.5) / S, (row + 0.5) / S], -1)
    return uv, np.repeat(idx[:, None], 3, 1), tex.reshape(S, S, 3)


def _noise_texture(rng, size=128) -> np.ndarray:
    """A cluttered procedural texture (S, S, 3) uint8: random rectangles, stripes and blobs."""
    img = np.empty((size, size, 3), np.float64)
    img[:] = rng.uniform(0.1, 0.9, 3)
    for _ in range(int(rng.integers(3, 25))):
        colour = rng.uniform(0.0, 1.0, 3)
        kind = int(rng.integers(3))
        if kind == 0:
            u0, v0 = rng.integers(0, size, 2)
            w, h = rng.integers(2, size // 2, 2)
            img[v0 : v0 + h, u0 : u0 + w] = colour
        elif kind == 1:
            period = int(rng.integers(4, 32))
            phase = np.arange(size) % period < period // 2
            if rng.random() < 0.5:
                img[phase] = 0.5 * img[phase] + 0.5 * colour
            else:
                img[:, phase] = 0.5 * img[:, phase] + 0.5 * colour
        else:
            yy, xx = np.mgrid[:size, :size]
            cy, cx = rng.uniform(0, size, 2)
            r = rng.uniform(3, size / 4)
            img[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = colour
    img += rng.normal(0, rng.uniform(0.0, 0.08), img.shape)
    return np.clip(img * 255, 0, 255).astype(np.uint8)


def _add_texture(spec, name, data: np.ndarray):
    mj = _mujoco()
    h, w = data.shape[:2]
    tex = spec.add_texture(name=name, type=mj.mjtTexture.mjTEXTURE_2D, width=w, height=h, nchannel=3)
    tex.data = np.ascontiguousarray(data, np.uint8).tobytes()
    return name


#: The desk scenes' lights: 1-3 above the desk (MuJoCo's default attenuation, as the rooms').
_DESK_LIGHTS = _LightRig((0.1, 0.35), 4, (1.5, 1.5), 1.0, (1.0, 2.5), 0.4, 0.3, 0.2, 0.5)


@dataclasses.dataclass
class _Item:
    body: int
    geom: int
    vertices: np.ndarray  # (V, 3) in the body frame
    half_xy: float  # footprint radius
    z_min: float  # lowest vertex in the body frame (to stand on the desk)


class _DeskScene:
    """One compiled MuJoCo model: desk, walls, the LM-O meshes, distractor meshes and primitives, lights."""

    def __init__(self, meshes: dict, distractors: list, rng, width, height, max_primitives=4):
        mj = _mujoco()
        spec = mj.MjSpec()
        spec.visual.global_.offwidth = width
        spec.visual.global_.offheight = height
        spec.visual.quality.shadowsize = 1024
        spec.visual.map.znear = 0.01
        spec.visual.map.zfar = 20.0
        spec.stat.extent = 5.0
        _add_texture(spec, "desk_tex", _noise_texture(rng))
        rep = float(rng.uniform(0.5, 3.0))
        _material(spec, "desk_mat", "desk_tex", (rep, rep), specular=float(rng.uniform(0.0, 0.4)))
        desk = spec.worldbody.add_geom(name="desk", type=mj.mjtGeom.mjGEOM_BOX, size=[1.2, 0.8, 0.02])
        desk.pos = [0.0, 0.0, -0.02]
        desk.material = "desk_mat"
        spec.worldbody.add_geom(
            name="floor", type=mj.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], pos=[0, 0, -0.75], rgba=[0.3, 0.3, 0.3, 1]
        )
        for k in range(4):
            _add_texture(spec, f"wall_tex{k}", _noise_texture(rng))
            rep = float(rng.uniform(1.0, 4.0))
            _material(spec, f"wall_mat{k}", f"wall_tex{k}", (rep, rep), specular=float(rng.uniform(0.0, 0.2)))
            a = k * np.pi / 2
            d = float(rng.uniform(1.5, 3.0))
            spec.worldbody.add_geom(
                name=f"wall{k}",
                type=mj.mjtGeom.mjGEOM_BOX,
                size=[0.02, d + 1.0, 2.0],
                pos=[d * np.cos(a), d * np.sin(a), 1.0],
                euler=[0.0, 0.0, 90.0 * k],  # degrees (MuJoCo's default angle unit)
                material=f"wall_mat{k}",
            )
        self.objects: dict[int, _Item] = {}
        for i, mesh in meshes.items():
            uv, fuv, tex = face_color_atlas(mesh)
            m = spec.add_mesh(name=f"lmo{i}")
            m.uservert = np.asarray(mesh.vertices, np.float32).ravel().tolist()
            m.userface = np.asarray(mesh.faces, np.int32).ravel().tolist()
            m.usertexcoord = uv.astype(np.float32).ravel().tolist()
            m.userfacetexcoord = fuv.astype(np.int32).ravel().tolist()
            _add_texture(spec, f"lmo_tex{i}", tex)
            mat = spec.add_material(name=f"lmo_mat{i}", specular=float(rng.uniform(0.1, 0.5)))
            mat.textures[mj.mjtTextureRole.mjTEXROLE_RGB] = f"lmo_tex{i}"
            body = spec.worldbody.add_body(name=f"lmo{i}", pos=[0, 0, -50])
            body.add_geom(name=f"lmo{i}", type=mj.mjtGeom.mjGEOM_MESH, meshname=f"lmo{i}", material=f"lmo_mat{i}")
        self._distractor_specs = []
        pick = rng.choice(len(distractors), size=min(len(distractors), 6), replace=False) if distractors else []
        for j, d in enumerate(pick):
            name, v, f = distractors[int(d)]
            m = spec.add_mesh(name=f"dis{j}")
            m.uservert = np.asarray(v, np.float32).ravel().tolist()
            m.userface = np.asarray(f, np.int32).ravel().tolist()
            _add_texture(spec, f"dis_tex{j}", _noise_texture(rng, 64))
            # STL meshes have no texture coordinates: a random colour over the (cube-mapped) texture
            rgba = (*rng.uniform(0.15, 1.0, 3), 1.0)
            _material(spec, f"dis_mat{j}", f"dis_tex{j}", (float(rng.uniform(1, 6)),) * 2, rgba=rgba, specular=0.3)
            body = spec.worldbody.add_body(name=f"dis{j}", pos=[0, 0, -50])
            body.add_geom(name=f"dis{j}", type=mj.mjtGeom.mjGEOM_MESH, meshname=f"dis{j}", material=f"dis_mat{j}")
            self._distractor_specs.append(("mesh", f"dis{j}"))
        shapes = (mj.mjtGeom.mjGEOM_BOX, mj.mjtGeom.mjGEOM_CYLINDER, mj.mjtGeom.mjGEOM_ELLIPSOID)
        self._primitive_half = []
        for j in range(max_primitives):
            _add_texture(spec, f"prim_tex{j}", _noise_texture(rng, 64))
            _material(spec, f"prim_mat{j}", f"prim_tex{j}", (float(rng.uniform(1, 4)),) * 2, specular=0.3)
            kind = int(rng.integers(3))
            half = rng.uniform(0.02, 0.1, 3)
            if kind == 1:
                half[1] = half[0]
            size = [half[0], half[2], 0.0] if kind == 1 else list(half)
            body = spec.worldbody.add_body(name=f"prim{j}", pos=[0, 0, -50])
            body.add_geom(name=f"prim{j}", type=shapes[kind], size=size, material=f"prim_mat{j}")
            self._primitive_half.append(half)
            self._distractor_specs.append(("prim", f"prim{j}"))
        self._light_diffuse = _random_lights(spec, rng, _DESK_LIGHTS)
        spec.worldbody.add_camera(name="view", pos=[0, 0, 1], quat=[1, 0, 0, 0], fovy=45.0)
        self.model = spec.compile()
        self.data = mj.MjData(self.model)
        self.width, self.height = int(width), int(height)
        for i in meshes:
            self.objects[i] = self._item(f"lmo{i}")
        self.distractors = [self._item(name) for _, name in self._distractor_specs]
        self.renderer = mj.Renderer(self.model, self.height, self.width)

    def _item(self, name) -> _Item:
        mj = _mujoco()
        m = self.model
        gid = m.geom(name).id
        if m.geom_type[gid] == mj.mjtGeom.mjGEOM_MESH:
            mid = int(m.geom_dataid[gid])
            a, n = int(m.mesh_vertadr[mid]), int(m.mesh_vertnum[mid])
            R = np.zeros(9)
            mj.mju_quat2Mat(R, m.geom_quat[gid])
            v = m.mesh_vert[a : a + n].astype(np.float64) @ R.reshape(3, 3).T + m.geom_pos[gid]
        else:
            half = self._primitive_half[int(name[4:])]
            v = Q.cuboid_corners(np.eye(3), np.zeros(3), np.asarray(half, np.float64), xp=np)
        return _Item(m.body(name).id, gid, v, float(np.max(np.linalg.norm(v[:, :2], axis=-1))), float(v[:, 2].min()))

    def place(self, item: _Item, R=None, p=None):
        if R is None:
            self.model.body_pos[item.body] = [0.0, 0.0, -50.0]
            self.model.body_quat[item.body] = [1.0, 0.0, 0.0, 0.0]
        else:
            self.model.body_pos[item.body] = p
            self.model.body_quat[item.body] = mujoco_quaternion(R)

    def render(self, K, camera_T_world, outputs=("rgb", "depth")) -> dict:
        return mujoco_view(self.model, self.data, self.renderer, 0, K, camera_T_world, outputs)

    def close(self):
        self.renderer.close()


def _rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _tilt(rng, max_deg):
    axis = np.array([*rng.normal(size=2), 0.0])
    axis /= np.linalg.norm(axis) + 1e-12
    ang = np.deg2rad(rng.uniform(0, max_deg))
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(ang) * Kx + (1 - np.cos(ang)) * Kx @ Kx


def _look_at(eye, target, roll) -> np.ndarray:
    """camera_T_world (4, 4), OpenCV axes, camera at ``eye`` looking at ``target`` (the core's
    :func:`~jaxsem.quadrics.look_at`, z up), then rolled by ``roll`` about its optical axis."""
    T = np.array(Q.look_at(np.asarray(eye, float), np.asarray(target, float), xp=np))
    c, s = np.cos(roll), np.sin(roll)
    T[:3] = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ T[:3]
    return T


def _place_cluster(rng, items, radius, placed=None, tries=40, ring=(0.0, 1.0)):
    """xy positions of ``items`` in a disc of ``radius`` (annulus ``ring`` of it), footprints apart."""
    placed = [] if placed is None else placed
    out = []
    for it in items:
        for _ in range(tries):
            r = radius * np.sqrt(rng.uniform(ring[0] ** 2, ring[1] ** 2))
            a = rng.uniform(0, 2 * np.pi)
            xy = np.array([r * np.cos(a), r * np.sin(a)])
            if all(np.linalg.norm(xy - q) > 0.85 * (it.half_xy + h) for q, h in placed):
                placed.append((xy, it.half_xy))
                out.append((it, xy))
                break
    return out, placed


def _camera_effects(rng, rgb: np.ndarray) -> np.ndarray:
    """Blur, gain, gamma and sensor noise of a cheap RGB camera (uint8 in, uint8 out)."""
    import cv2  # deferred: cv2 is slow to import and only this function needs it

    img = rgb.astype(np.float32) / 255.0
    sigma = float(rng.uniform(0.0, 1.3))
    if sigma > 0.3:
        img = cv2.GaussianBlur(img, (0, 0), sigma)
    img = img * rng.uniform(0.75, 1.3, 3).astype(np.float32) ** 0.3 * float(rng.uniform(0.7, 1.35))
    img = np.clip(img, 0, 1) ** float(rng.uniform(0.75, 1.3))
    img = img + rng.normal(0, rng.uniform(0.0, 0.035), img.shape).astype(np.float32)
    return np.clip(np.round(img * 255), 0, 255).astype(np.uint8)


def _vertex_box(vertices_cam, K) -> np.ndarray:
    uv, z = Q.project_points(vertices_cam, K, np.eye(4), xp=np)
    if np.any(z <= 0.01):
        return np.full(4, np.nan)
    return np.concatenate([uv.min(0), uv.max(0)])


def render_desk_frames(
    meshes: dict,
    num_frames: int,
    seed: int,
    *,
    distractors: list | None = None,
    config: DeskConfig = DeskConfig(),
    K=LMO_K,
    image_size: tuple = LMO_IMAGE_SIZE,
    baseline: float = 0.06,
):
    """Yield ``num_frames`` rendered desk frames (a generator; deterministic in ``seed``).

    Args:
      meshes: object id -> :class:`Mesh` with colours (e.g. :func:`load_lmo_meshes`); the ids
        must be LM-O's (:data:`LMO_OBJECT_IDS`).
      num_frames: frames to render; seed: fixes every random choice.
      distractors: ``[(name, vertices, faces)]`` meshes (:func:`load_distractor_meshes`) or None.
      config: :class:`DeskConfig`; K: (3, 3) pinhole; image_size: (W, H); baseline: metres of
        the stereo pair whose right-image boxes are labelled.

    Yields:
      dict: ``rgb`` (H, W, 3) uint8 (camera effects applied), ``depth`` (H, W) float32 metres
      (0: no surface), ``seg`` (H, W) int16 (the LM-O object id per visible pixel, 0 elsewhere),
      ``K``, ``objects``: per LM-O object in view ``obj_id``, ``class_name``, ``rotation`` (3, 3)
      object-to-camera, ``translation`` (3,) the mesh origin in the camera frame, ``center``,
      ``radii`` (3,) the mesh extent's box, ``box_left``, ``box_right`` (4,) amodal boxes (projected
      vertices; the right camera ``baseline`` along +x), ``visible_box`` (4,) (NaN if unseen),
      ``visible_fraction`` (visible pixels over the pixels of the object rendered alone).
    """
    bad = sorted(set(meshes) - set(LMO_OBJECT_IDS))
    if bad or not meshes:
        raise ValueError(f"meshes: expected LM-O object ids {LMO_OBJECT_IDS}, got {sorted(meshes)}")
    num_frames = int(num_frames)
    if num_frames < 0:
        raise ValueError(f"num_frames: expected >= 0, got {num_frames}")
    K = np.asarray(K, np.float64)
    W, H = (int(x) for x in image_size)
    distractors = list(distractors or [])
    centers = {i: m.center for i, m in meshes.items()}
    radii = {i: m.radii for i, m in meshes.items()}
    done, scene_index = 0, 0
    while done < num_frames:
        rng = np.random.default_rng([int(seed), scene_index, 0x1A0])
        scene = _DeskScene(meshes, distractors, rng, W, H)
        try:
            for _ in range(min(int(config.frames_per_scene), num_frames - done)):
                yield _render_frame(rng, scene, config, K, (W, H), float(baseline), centers, radii)
                done += 1
        finally:
            scene.close()
        scene_index += 1


def _render_frame(rng, scene: _DeskScene, config: DeskConfig, K, size, baseline, centers, radii) -> dict:
    W, H = size
    ids = sorted(scene.objects)
    n = int(rng.integers(config.objects[0], min(config.objects[1], len(ids)) + 1))
    chosen = [ids[k] for k in rng.choice(len(ids), n, replace=False)]
    for item in list(scene.objects.values()) + scene.distractors:
        scene.place(item)
    placed_objs, taken = _place_cluster(rng, [scene.objects[i] for i in chosen], config.cluster_radius)
    poses = {}
    for it, xy in placed_objs:
        R = _tilt(rng, config.tilt) @ _rot_z(rng.uniform(0, 2 * np.pi))
        p = np.array([xy[0], xy[1], 0.0])
        p[2] = -np.min(it.vertices @ R.T, 0)[2] + 0.001
        scene.place(it, R, p)
        oid = next(i for i in chosen if scene.objects[i] is it)
        poses[oid] = (R, p)
    nd = int(rng.integers(config.distractors[0], config.distractors[1] + 1))
    ditems = [scene.distractors[k] for k in rng.choice(len(scene.distractors), min(nd, len(scene.distractors)), False)]
    placed_d, _ = _place_cluster(rng, ditems, config.cluster_radius * 2.2, taken, ring=(0.2, 1.0))
    for it, xy in placed_d:
        R = _rot_z(rng.uniform(0, 2 * np.pi))
        if rng.random() < 0.3:
            R = _tilt(rng, 90.0) @ R
        p = np.array([xy[0], xy[1], 0.0])
        p[2] = -np.min(it.vertices @ R.T, 0)[2] + 0.001
        scene.place(it, R, p)
    # camera around the cluster
    dist = rng.uniform(*config.distance)
    elev = np.deg2rad(rng.uniform(*config.elevation))
    azim = rng.uniform(0, 2 * np.pi)
    target = np.array([*rng.normal(0, 0.06, 2), rng.uniform(0.0, 0.08)])
    eye = target + dist * np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    T = _look_at(eye, target, np.deg2rad(rng.normal(0, 4)))
    for j, d in enumerate(scene._light_diffuse):
        scene.model.light_diffuse[j] = d * rng.uniform(0.6, 1.4)
    view = scene.render(K, T, ("rgb", "depth"))
    geom_to_obj = {scene.objects[i].geom: i for i in poses}
    seg = np.zeros(view["geom"].shape, np.int16)
    for g, i in geom_to_obj.items():
        seg[view["geom"] == g] = i
    objects = []
    right = np.array([baseline, 0.0, 0.0])
    for i, (Rw, pw) in poses.items():
        R_cam = T[:3, :3] @ Rw
        t_cam = T[:3, :3] @ pw + T[:3, 3]
        v_cam = scene.objects[i].vertices @ R_cam.T + t_cam
        box_l = _vertex_box(v_cam, K)
        box_r = _vertex_box(v_cam - right, K)
        if not np.all(np.isfinite(box_l)) or box_l[2] < 0 or box_l[0] > W - 1 or box_l[3] < 0 or box_l[1] > H - 1:
            continue
        visible = seg == i
        count = int(visible.sum())
        full = _alone_pixels(scene, i, poses, K, T)
        if count:
            vv, uu = np.nonzero(visible)
            vbox = np.array([uu.min() - 0.5, vv.min() - 0.5, uu.max() + 0.5, vv.max() + 0.5])
        else:
            vbox = np.full(4, np.nan)
        objects.append(
            {
                "obj_id": int(i),
                "class_name": LINEMOD_NAMES[i],
                "rotation": R_cam,
                "translation": t_cam,
                "center": R_cam @ centers[i] + t_cam,
                "radii": np.asarray(radii[i], np.float64),
                "box_left": box_l,
                "box_right": box_r,
                "visible_box": vbox,
                "visible_fraction": float(count / max(full, 1)),
            }
        )
    rgb = _camera_effects(rng, view["rgb"])
    return {"rgb": rgb, "depth": view["depth"], "seg": seg, "K": K.copy(), "objects": objects}


def _alone_pixels(scene: _DeskScene, i, poses, K, T) -> int:
    """Pixels of object ``i`` rendered with nothing else in the way (a segmentation pass)."""
    m = scene.model
    saved = m.geom_rgba.copy()
    others = [it.geom for j, it in scene.objects.items() if j != i] + [d.geom for d in scene.distractors]
    # park every other object for the pass and put it back after
    keep = {g: (m.body_pos[m.geom_bodyid[g]].copy()) for g in others}
    for g in others:
        m.body_pos[m.geom_bodyid[g]] = [0.0, 0.0, -50.0]
    try:
        geom = mujoco_view(m, scene.data, scene.renderer, 0, K, T, ("seg",))["geom"]
    finally:
        for g, pos in keep.items():
            m.body_pos[m.geom_bodyid[g]] = pos
        m.geom_rgba[:] = saved
    return int(np.sum(geom == scene.objects[i].geom))


def detections_from_frames(
    frames,
    *,
    input_size: int,
    global_padding: float,
    num_points: int,
    min_visible: float = 0.3,
    min_pixels: int = 64,
    baseline: float = 0.06,
    seed: int = 0,
    class_names: tuple = LMO_CLASS_NAMES,
) -> dict:
    """The VoluMon arrays of rendered frames (:func:`render_desk_frames`): one row per object at
    least ``min_visible`` visible with at least ``min_pixels`` visible pixels.

    Keys: ``local``, ``global`` (B, S, S, 3) uint8 (:func:`jaxsem.volumon.prepare_inputs` of the
    visible box, times 255); ``box_input`` (B, 4) the visible box; ``box_left``, ``box_right``
    (B, 4) the amodal stereo boxes; ``K`` (B, 3, 3); ``baseline`` (B,); ``points`` (B, J, 3)
    visible surface points from the rendered depth (camera frame), ``point_mask`` (B, J);
    ``class_id`` (B,) the row in ``class_names``; ``class_shape`` (B,) (:data:`LMO_CLASS_SHAPES`);
    ``visible_fraction`` (B,); and the 3D truth for the oracle and for scoring only:
    ``gt_rotation``, ``gt_center``, ``gt_half_extents``, ``gt_shape_id`` (0: scored against the
    mesh extent's cuboid, as :func:`jaxsem.volumon.data.bop_eval_batch`).
    """
    rng = np.random.default_rng([int(seed), 0xDE7])
    names = tuple(class_names)
    rows: dict[str, list] = {
        k: []
        for k in (
            "local", "global", "box_input", "box_left", "box_right", "K", "points", "point_mask", "class_id",
            "class_shape", "visible_fraction", "gt_rotation", "gt_center", "gt_half_extents",
        )
    }  # fmt: skip
    J = int(num_points)
    for fr in frames:
        K = np.asarray(fr["K"], np.float64)
        H, W = fr["seg"].shape
        objs = [
            o
            for o in fr["objects"]
            if o["class_name"] in names
            and o["visible_fraction"] >= min_visible
            and np.all(np.isfinite(o["visible_box"]))
            and int(np.sum(fr["seg"] == o["obj_id"])) >= min_pixels
        ]
        if not objs:
            continue
        lo, hi = np.array([-0.5, -0.5]), np.array([W - 0.5, H - 0.5])
        boxes = []
        for o in objs:
            b = np.asarray(o["visible_box"], np.float64)
            b = np.concatenate([np.clip(b[:2], lo, hi - 1.0), np.clip(b[2:], lo + 1.0, hi)])
            boxes.append(b)
        boxes = np.stack(boxes)
        local, glob = prepare_inputs(fr["rgb"], boxes, int(input_size), float(global_padding))
        rows["local"].append(np.round(np.asarray(local) * 255).astype(np.uint8))
        rows["global"].append(np.round(np.asarray(glob) * 255).astype(np.uint8))
        Kinv = np.linalg.inv(K)
        for o, b in zip(objs, boxes):
            vv, uu = np.nonzero((fr["seg"] == o["obj_id"]) & (fr["depth"] > 0))
            pts = np.zeros((J, 3))
            mask = np.zeros(J, bool)
            if len(vv):
                pick = rng.choice(len(vv), size=min(J, len(vv)), replace=False)
                z = fr["depth"][vv[pick], uu[pick]].astype(np.float64)
                pix = np.stack([uu[pick], vv[pick], np.ones(len(pick))], -1)
                pts[: len(pick)] = (pix @ Kinv.T) * z[:, None]
                mask[: len(pick)] = True
            rows["box_input"].append(b)
            rows["box_left"].append(np.asarray(o["box_left"], np.float64))
            rows["box_right"].append(np.asarray(o["box_right"], np.float64))
            rows["K"].append(K)
            rows["points"].append(pts)
            rows["point_mask"].append(mask)
            rows["class_id"].append(names.index(o["class_name"]))
            rows["class_shape"].append(LMO_CLASS_SHAPES.get(o["class_name"], 0))
            rows["visible_fraction"].append(float(o["visible_fraction"]))
            rows["gt_rotation"].append(np.asarray(o["rotation"], np.float64))
            rows["gt_center"].append(np.asarray(o["center"], np.float64))
            rows["gt_half_extents"].append(np.asarray(o["radii"], np.float64))
    if not rows["box_input"]:
        raise ValueError(f"frames: no object is at least {min_visible:g} visible with {min_pixels} pixels")
    out = {k: np.concatenate(rows[k]) for k in ("local", "global")}
    for k in rows:
        if k not in out:
            out[k] = np.stack(rows[k]) if isinstance(rows[k][0], np.ndarray) else np.asarray(rows[k])
    B = len(out["box_input"])
    out["baseline"] = np.full(B, float(baseline))
    out["class_id"] = out["class_id"].astype(np.int32)
    out["class_shape"] = out["class_shape"].astype(np.int32)
    out["gt_shape_id"] = np.zeros(B, np.int32)
    out["sample_mask"] = np.ones(B, bool)
    return out


def mesh_listing(folder) -> list | None:
    """The mesh files of a folder as ``name:size`` (what a stamp records of the meshes a render used)."""
    if folder is None:
        return None
    return sorted(f"{p.name}:{p.stat().st_size}" for p in pathlib.Path(folder).iterdir() if p.is_file())


def write_desk_chunks(
    out: pathlib.Path, stem: str, num_frames: int, chunk: int, stamp: dict, chunk_arrays, *, desc: str, progress: bool
) -> list:
    """Writes ``num_frames`` rendered frames as ``out/<stem>_NNNN.npz`` files of ``chunk`` frames
    each: ``chunk_arrays(c, n, tick)`` returns the arrays of chunk ``c`` (its ``n`` frames, seeded
    per chunk) and calls ``tick()`` once a frame for the progress bar (``desc``). A chunk already
    written is skipped, so an interrupted call resumes; each is written atomically.
    ``out/stamp.json`` records ``stamp`` (what makes the chunks): a call with another stamp into
    the same folder is refused (:func:`jaxsem.training.check_stamp`). Returns the chunk paths."""
    from tqdm.auto import tqdm  # deferred: slow to import; only the writers need it

    check_stamp(out / "stamp.json", stamp, adopt=True, hint="write to another folder")
    n_chunks = -(-int(num_frames) // int(chunk))
    paths = []
    bar = tqdm(total=int(num_frames), disable=not progress, unit="frame", desc=desc)
    for c in range(n_chunks):
        path = out / f"{stem}_{c:04d}.npz"
        n = min(int(chunk), int(num_frames) - c * int(chunk))
        paths.append(path)
        if path.exists():
            bar.update(n)
            continue
        arrays = chunk_arrays(c, n, lambda: bar.update(1))
        tmp = out / f"{stem}_{c:04d}.tmp.npz"
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)
    bar.close()
    return paths


def write_desk_detections(
    out_dir,
    num_frames: int,
    seed: int,
    *,
    models_dir,
    distractor_dir=None,
    chunk: int = 100,
    input_size: int = 48,
    global_padding: float = 0.1,
    num_points: int = 64,
    min_visible: float = 0.3,
    config: DeskConfig = DeskConfig(),
    previews: int = 4,
    progress: bool = True,
) -> list:
    """Render ``num_frames`` desk frames and write their detections (:func:`detections_from_frames`)
    as ``out_dir/chunk_NNNN.npz`` files of ``chunk`` frames each (frame seeds are per chunk, so an
    interrupted call resumes by skipping the chunks already written; each is written atomically)
    and the first ``previews`` frames of chunk 0 as ``preview_K.jpg``. ``out_dir/stamp.json``
    records the arguments: a call with others into the same folder is refused
    (:func:`jaxsem.training.check_stamp`). Returns the chunk paths.
    """
    import cv2  # deferred: slow to import; only the writer needs it

    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    meshes = load_lmo_meshes(models_dir)
    distractors = load_distractor_meshes(distractor_dir) if distractor_dir is not None else []
    stamp = {
        "what": "desk detections",
        "num_frames": int(num_frames),
        "seed": int(seed),
        "chunk": int(chunk),
        "input_size": int(input_size),
        "global_padding": float(global_padding),
        "num_points": int(num_points),
        "min_visible": float(min_visible),
        "config": dataclasses.asdict(config),
        "models": mesh_listing(models_dir),
        "distractors": mesh_listing(distractor_dir),
    }

    def chunk_arrays(c, n, tick):
        frames = render_desk_frames(meshes, n, seed=int(seed) * 100003 + c, distractors=distractors, config=config)

        def counted():
            for k, fr in enumerate(frames):
                if c == 0 and k < previews:
                    cv2.imwrite(str(out / f"preview_{k}.jpg"), fr["rgb"][..., ::-1])
                tick()
                yield fr

        return detections_from_frames(
            counted(),
            input_size=input_size,
            global_padding=global_padding,
            num_points=num_points,
            min_visible=min_visible,
            seed=int(seed) * 100003 + c,
        )

    return write_desk_chunks(
        out, "chunk", num_frames, chunk, stamp, chunk_arrays, desc="desk renders", progress=progress
    )


def load_desk_detections(path) -> dict:
    """The detections of :func:`write_desk_detections` (a folder of ``chunk_*.npz``, or one file), concatenated."""
    path = pathlib.Path(path)
    files = sorted(path.glob("chunk_[0-9]*.npz")) if path.is_dir() else [path]
    files = [f for f in files if ".tmp" not in f.name]
    if not files:
        raise ValueError(f"path: no chunk_NNNN.npz detections in {path}")
    return concat_npz(files)


def concat_npz(files, keys=None, *, max_elements: int = MAX_NPZ_ELEMENTS) -> dict:
    """The arrays of the ``.npz`` files ``files`` (chunks of :func:`write_desk_chunks`),
    concatenated along their first axis in the files' order; ``keys``: which arrays, in this
    order (default: the first file's).

    Each file's declared array sizes are checked against ``max_elements`` before anything is
    inflated (:func:`jaxsem._files.check_npz`: a few kB of deflated zeros can declare gigabytes),
    and its arrays against ``keys`` and the other chunks (same trailing shape), so a damaged or
    foreign chunk is refused with a ``ValueError`` naming it rather than a shape error later.
    """
    parts: list[dict] = []
    first: dict | None = None
    for f in files:
        shapes = check_npz(f, max_elements=max_elements)
        wanted = list(keys) if keys is not None else list(shapes) if first is None else list(first)
        missing = [k for k in wanted if k not in shapes]
        if missing:
            raise ValueError(f"{f}: not a chunk of this folder's kind: no array {', '.join(map(repr, missing))}")
        if first is None:
            first = {k: shapes[k][1:] for k in wanted}
        odd = [k for k in wanted if not shapes[k] or shapes[k][1:] != first[k]]
        if odd:
            k = odd[0]
            raise ValueError(f"{f}: array {k!r} has shape {shapes[k]}, the first chunk's rows are {first[k]}")
        try:
            with np.load(f) as z:
                parts.append({k: z[k] for k in wanted})
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{f}: not a readable .npz chunk ({exc})") from None
    return {k: np.concatenate([p[k] for p in parts]) for k in (first or {})}


#: Keys of a training batch of desk detections (:data:`jaxsem.volumon._train.TRAIN_KEYS` and the truth for scoring).
_BATCH_KEYS = (
    "local", "global", "box_input", "box_left", "box_right", "K", "baseline", "points", "point_mask", "class_id",
    "sample_mask", "class_shape", "gt_rotation", "gt_center", "gt_half_extents", "gt_shape_id",
)  # fmt: skip


def _as_batch(det: dict, idx) -> dict:
    out = {k: det[k][idx] for k in _BATCH_KEYS}
    out["local"] = out["local"].astype(np.float32) / 255.0
    out["global"] = out["global"].astype(np.float32) / 255.0
    for k in ("box_input", "box_left", "box_right", "K", "baseline", "points", "gt_rotation", "gt_center"):
        out[k] = out[k].astype(np.float32)
    out["gt_half_extents"] = out["gt_half_extents"].astype(np.float32)
    return out


def is_desk_detections(path) -> bool:
    """Whether ``path`` is a folder of :func:`write_desk_detections` chunks."""
    path = pathlib.Path(path)
    return path.is_dir() and any(path.glob("chunk_[0-9]*.npz"))


def desk_batch_source(path, *, batch_size: int, seed: int = 0, min_visible: float = 0.0):
    """``(batch_fn, num_samples)`` for ``jaxsem.volumon.train_and_evaluate`` on the desk
    detections in ``path``: ``batch_fn(step)`` is batch ``step`` of seeded per-epoch
    permutations (a pure function of the step, so a resumed run sees the same batches), keys of
    :data:`jaxsem.volumon._train.TRAIN_KEYS`, images as float32 in [0, 1]. ``min_visible``: keep only
    detections at least this visible."""
    det = load_desk_detections(path)
    keep = np.nonzero(det["visible_fraction"] >= float(min_visible))[0]
    det = {k: v[keep] for k, v in det.items()}
    n = len(keep)
    B = int(batch_size)
    if n < B:
        raise ValueError(f"data: {path} holds {n} detections, fewer than one batch of {B}")

    def batch_fn(step: int) -> dict:
        start = int(step) * B
        idx = []
        while len(idx) < B:
            epoch, offset = divmod(start + len(idx), n)
            perm = np.random.default_rng([int(seed), 0xDE5C, epoch]).permutation(n)
            idx.extend(perm[offset : offset + B - len(idx)].tolist())
        return _as_batch(det, np.asarray(idx))

    return batch_fn, n


def desk_eval_batch(path, num: int | None = None, min_visible: float = 0.0) -> dict:
    """The first ``num`` detections of ``path`` at least ``min_visible`` visible as one batch
    (the keys of :func:`desk_batch_source` plus ``visible_fraction``)."""
    det = load_desk_detections(path)
    keep = np.nonzero(det["visible_fraction"] >= float(min_visible))[0]
    if num is not None:
        keep = keep[: int(num)]
    if len(keep) == 0:
        raise ValueError(f"data: no detection of {path} is at least {min_visible:g} visible")
    out = _as_batch(det, keep)
    out["visible_fraction"] = det["visible_fraction"][keep]
    return out
