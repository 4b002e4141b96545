"""Stereo scenes of textured object meshes rendered with MuJoCo, written in the FAT layout.

Where :func:`jaxsem.volumon.data.write_synthetic_dataset` draws coloured primitives, this writer renders
real object meshes with their own textures: by default the bread, soda can, cereal box, milk
carton, lemon and bottle of the robosuite 1.5.2 package (MIT licence; the optional extra
``jaxsem[objects]``), inside a room whose floor and walls carry robosuite's wood, plaster and tile
textures, under random lights, with textured distractor objects. Nothing is downloaded: the
assets are read from the installed ``robosuite`` package (located with
``importlib.util.find_spec``, never imported) or from any :class:`ObjectAssets` the caller
builds, e.g. a procedural mesh in a test. Licence: the wheel's only licence is robosuite's MIT
licence (``robosuite-1.5.2.dist-info/licenses/LICENSE``); its asset folders carry no licence of
their own, but ``textures/lemon.png`` has an EXIF artist / copyright tag of a third-party
photographer (stephen gibson, photohome.co.uk) and ``textures/soda.png`` (the can) shows a
branded soda can, so check those two before redistributing rendered images. jaxsem ships none
of these files.

Each scene directory (``<out_dir>/<split>/scene_NNN/``) is one compiled MuJoCo model: the room
(floor at z = 0 and four walls 1.8-3 m from the origin, each with its own texture), 1-4 lights
(directional or spot, random colour, direction, intensity and shadows, re-scaled per frame), every
object mesh of the assets and ``num_distractors`` textured primitives. Per frame a stereo camera
0.5-1.4 m above the floor, at a random yaw and tilted 10-35 degrees down, sees 1 to
``max_objects`` labelled objects at uniformly random orientations (as FAT's falling things), their
centres ``depth_range`` metres in front of it, each entirely inside both images, never occluding
one another, above the floor and inside the room; the distractors are placed so that their
boxes overlap no labelled object's in either image (so the labelled objects are never occluded:
``visibility`` 1) and may leave the image.

Ground truth is read from the compiled MuJoCo model, not from the sampled numbers: an object's
frame is its mesh file's frame (robosuite's: z up), its full ``dimensions`` are the extents of the
compiled mesh's vertices in that frame (after robosuite's scale), its centre is the centre of
that box, posed by the body's ``xpos`` / ``xmat`` after ``mj_forward``. ``bounding_box`` is the box
of the object's projected mesh vertices (the exact amodal box of the rendered silhouette);
``cuboid`` / ``projected_cuboid`` come from :func:`jaxsem.quadrics.cuboid_corners` /
:func:`jaxsem.quadrics.project_points`. The JSON and settings files are those of the synthetic
writer (same fields, FAT's centimetres, corner order and ``[y, x]`` box quirk), plus per object
``mesh_class`` (the class of the mesh itself).

Labels (``labels``): ``'volumon'`` (default) writes each object under the class of
:data:`jaxsem.volumon.VOLUMON_CLASS_NAMES` with the same shape that it stands in for
(:attr:`MeshAsset.volumon_class`: cereal box and milk carton -> ``cracker_box``, soda can and
bottle -> ``soup_can``, lemon and bread -> ``ball``), so that the shipped 4-class VoluMon model can
be scored on, and fine-tuned with, these scenes (``jaxsem volumon eval --data DIR``); per scene
one mesh is drawn for each such class (the loader matches objects by class name, and the
settings file holds one size per class), the other meshes are distractors. ``'own'`` writes each
object under its own class of :mod:`jaxsem.classes`.

Host-side numpy + MuJoCo (``MUJOCO_GL=egl``, Mesa's llvmpipe on a CPU), not jittable. A scene is
written into ``scene_NNN.partial`` and renamed into place when complete.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import os
import pathlib
import xml.etree.ElementTree as ET

import numpy as np

from ... import classes as _classes, quadrics as Q
from ...data import FAT_BASELINE, fat_writer, mujoco_quaternion, mujoco_view, right_T_left
from .._synthetic import VOLUMON_CLASS_NAMES
from ._synthetic import _SPLIT_STREAM, ObjectClass, _camera_pose, synthetic_intrinsics

os.environ.setdefault("MUJOCO_GL", "egl")

__all__ = [
    "MeshAsset",
    "ObjectAssets",
    "ObjectAssetsMissingError",
    "ROBOSUITE_OBJECTS",
    "robosuite_assets",
    "write_object_dataset",
]

OBJECTS_EXTRA = "objects"
ROBOSUITE_VERSION = "1.5.2"

# robosuite object XML (models/assets/objects/<file>.xml) -> (jaxsem class, VoluMon stand-in class)
ROBOSUITE_OBJECTS: dict[str, tuple[str, str]] = {
    "bread": ("bread", "ball"),
    "can": ("soda_can", "soup_can"),
    "cereal": ("cereal_box", "cracker_box"),
    "milk": ("milk_carton", "cracker_box"),
    "lemon": ("lemon", "ball"),
    "bottle": ("bottle", "soup_can"),
}
_FLOOR_TEXTURES = ("light-gray-floor-tile", "wood-tiles", "wood-varnished-panels", "light-wood", "dark-wood")
_WALL_TEXTURES = (
    "cream-plaster",
    "gray-plaster",
    "light-gray-plaster",
    "pink-plaster",
    "white-plaster",
    "yellow-plaster",
    "white-bricks",
    "blue-wood",
    "green-wood",
    "red-wood",
    "gray-woodgrain",
)
_DISTRACTOR_TEXTURES = ("metal", "clay", "brass-ambra", "steel-brushed", "gray-felt", "ceramic", "dirt", "red-wood")
_TEXTURE_TYPES = ("2d", "cube", "skybox")
_PARK = np.array([0.0, 0.0, -1e3])  # where unused bodies wait, far below the floor


class ObjectAssetsMissingError(FileNotFoundError):
    """The object meshes and textures (robosuite's, by default) are not installed."""


@dataclasses.dataclass(frozen=True)
class MeshAsset:
    """One object mesh with its texture.

    Attributes:
      class_name: its class in :mod:`jaxsem.classes` (shape and nominal size).
      mesh_file: a mesh MuJoCo reads (``.obj``, ``.stl``, ``.msh``); the object frame is the file's.
      scale: (3,) scale applied to the vertices (robosuite's ``mesh scale``).
      texture_file: PNG of the texture, or ``None`` for a MuJoCo checker in ``rgb``.
      texture_type: ``'2d'`` (mesh UVs, else MuJoCo's generated coordinates), ``'cube'`` or ``'skybox'``.
      texrepeat, texuniform: the material's texture repetition (robosuite's values).
      volumon_class: the VoluMon class of the same shape it is written as with ``labels='volumon'``.
      rgb: checker colour when ``texture_file`` is ``None``.
    """

    class_name: str
    mesh_file: pathlib.Path
    scale: tuple = (1.0, 1.0, 1.0)
    texture_file: pathlib.Path | None = None
    texture_type: str = "2d"
    texrepeat: tuple = (1.0, 1.0)
    texuniform: bool = False
    volumon_class: str | None = None
    rgb: tuple = (0.8, 0.3, 0.2)

    def __post_init__(self):
        cls = _classes.get(self.class_name)  # ValueError naming the known classes
        object.__setattr__(self, "mesh_file", pathlib.Path(self.mesh_file))
        if not self.mesh_file.is_file():
            raise ObjectAssetsMissingError(f"mesh_file: {self.mesh_file} does not exist")
        if self.texture_file is not None:
            object.__setattr__(self, "texture_file", pathlib.Path(self.texture_file))
            if not self.texture_file.is_file():  # type: ignore[union-attr]
                raise ObjectAssetsMissingError(f"texture_file: {self.texture_file} does not exist")
        scale = tuple(float(s) for s in self.scale)
        if len(scale) != 3 or not all(math.isfinite(s) and s > 0 for s in scale):
            raise ValueError(f"scale: expected three positive numbers, got {self.scale!r}")
        object.__setattr__(self, "scale", scale)
        if self.texture_type not in _TEXTURE_TYPES:
            raise ValueError(f"texture_type: expected one of {_TEXTURE_TYPES}, got {self.texture_type!r}")
        if self.volumon_class is not None and _classes.get(self.volumon_class).shape != cls.shape:
            raise ValueError(
                f"volumon_class: {self.volumon_class!r} is a {_classes.get(self.volumon_class).shape}, "
                f"but {self.class_name!r} is a {cls.shape}"
            )

    @property
    def shape(self) -> str:
        """The class's shape in the synthetic writer's words (``'box'``, ``'cylinder'``, ``'ellipsoid'``)."""
        s = _classes.get(self.class_name).shape
        return "box" if s == "cuboid" else s


@dataclasses.dataclass(frozen=True)
class ObjectAssets:
    """Meshes and background textures for :func:`write_object_dataset`.

    Attributes:
      objects: the :class:`MeshAsset` s (distinct classes).
      floor_textures, wall_textures, distractor_textures: PNG files; empty: MuJoCo's procedural
        checker / gradient textures in random colours.
      source: a line naming where the assets come from and their licence (kept in the settings).
    """

    objects: tuple
    floor_textures: tuple = ()
    wall_textures: tuple = ()
    distractor_textures: tuple = ()
    source: str = "procedural"

    def __post_init__(self):
        objects = tuple(self.objects)
        if not objects or not all(isinstance(o, MeshAsset) for o in objects):
            raise ValueError(f"objects: expected a non-empty sequence of MeshAsset, got {self.objects!r}")
        names = [o.class_name for o in objects]
        if len(set(names)) != len(names):
            raise ValueError(f"objects: class names must be distinct, got {names}")
        object.__setattr__(self, "objects", objects)
        for field in ("floor_textures", "wall_textures", "distractor_textures"):
            paths = tuple(pathlib.Path(p) for p in getattr(self, field))
            missing = [str(p) for p in paths if not p.is_file()]
            if missing:
                raise ObjectAssetsMissingError(f"{field}: missing files {missing}")
            object.__setattr__(self, field, paths)


def _robosuite_root(root) -> pathlib.Path:
    hint = (
        f"install the optional extra: pip install 'jaxsem[{OBJECTS_EXTRA}]' (robosuite=={ROBOSUITE_VERSION}; "
        "only its asset files are read, robosuite is not imported)"
    )
    if root is None:
        try:
            spec = importlib.util.find_spec("robosuite")
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            raise ObjectAssetsMissingError(f"robosuite assets: the robosuite package is not installed; {hint}")
        root = pathlib.Path(list(spec.submodule_search_locations)[0]) / "models" / "assets"
    root = pathlib.Path(root)
    if not (root / "objects").is_dir() or not (root / "textures").is_dir():
        raise ObjectAssetsMissingError(
            f"robosuite assets: {root} has no objects/ and textures/ folders (robosuite {ROBOSUITE_VERSION} "
            f"ships them under robosuite/models/assets); {hint}"
        )
    return root


def _floats(text, n, default):
    return tuple(float(x) for x in text.split()) if text else (default,) * n


def robosuite_assets(root=None) -> ObjectAssets:
    """The six textured robosuite objects and its wood / plaster / tile textures.

    ``root``: robosuite's ``models/assets`` folder (default: the installed package's). Raises
    :class:`ObjectAssetsMissingError` naming the ``objects`` extra when it is missing. Each mesh,
    scale, texture and material setting is read from robosuite's own object XML.
    """
    root = _robosuite_root(root)
    objs = []
    for stem, (cls, volumon) in ROBOSUITE_OBJECTS.items():
        xml = root / "objects" / f"{stem}.xml"
        if not xml.is_file():
            raise ObjectAssetsMissingError(f"robosuite assets: {xml} is missing (robosuite {ROBOSUITE_VERSION}?)")
        asset = ET.parse(xml).getroot().find("asset")
        mesh, tex, mat = (asset.find(t) if asset is not None else None for t in ("mesh", "texture", "material"))
        if mesh is None or tex is None or mat is None:
            raise ObjectAssetsMissingError(f"robosuite assets: {xml} lacks a mesh, texture or material")
        objs.append(
            MeshAsset(
                cls,
                xml.parent / mesh.attrib["file"],
                _floats(mesh.get("scale"), 3, 1.0),
                xml.parent / tex.attrib["file"],
                tex.get("type", "cube"),
                _floats(mat.get("texrepeat"), 2, 1.0),
                mat.get("texuniform", "false") == "true",
                volumon,
            )
        )
    tex = root / "textures"
    return ObjectAssets(
        tuple(objs),
        tuple(tex / f"{n}.png" for n in _FLOOR_TEXTURES),
        tuple(tex / f"{n}.png" for n in _WALL_TEXTURES),
        tuple(tex / f"{n}.png" for n in _DISTRACTOR_TEXTURES),
        source=f"robosuite {ROBOSUITE_VERSION} models/assets (MIT licence, Stanford SVL and UT RPL)",
    )


def _mujoco():
    import mujoco  # deferred: mujoco is optional (the sim extra)

    return mujoco


def _texture(spec, name, rng, files, kind="2d"):
    """A texture from ``files`` (random pick) or a procedural checker / gradient; returns its name."""
    mj = _mujoco()
    ttype = {"2d": mj.mjtTexture.mjTEXTURE_2D, "cube": mj.mjtTexture.mjTEXTURE_CUBE}[kind]
    if files:
        spec.add_texture(name=name, type=ttype, file=str(files[int(rng.integers(len(files)))]))
    else:
        c1, c2 = rng.uniform(0.15, 0.9, 3), rng.uniform(0.15, 0.9, 3)
        builtin = mj.mjtBuiltin.mjBUILTIN_CHECKER if rng.random() < 0.6 else mj.mjtBuiltin.mjBUILTIN_GRADIENT
        spec.add_texture(name=name, type=ttype, builtin=builtin, rgb1=list(c1), rgb2=list(c2), width=64, height=64)
    return name


@dataclasses.dataclass(frozen=True)
class _LightRig:
    """How a scene's random lights are drawn (:func:`_random_lights`): the headlight's ambient
    range; 1 to ``max_count - 1`` lights at ``xy_scale`` times a uniform (x, y) within
    ``xy_half`` and a height in ``height`` (m), aimed at the origin give or take a normal
    ``spread`` and at least ``drop`` downwards; their ``specular`` and shadow probability."""

    ambient: tuple
    max_count: int
    xy_half: tuple
    xy_scale: float
    height: tuple
    spread: float
    drop: float
    specular: float
    shadow: float


def _room_lights(hx: float, hy: float) -> _LightRig:
    """The object rooms' lights: 1-4 under the ceiling of a room of half sizes ``hx``, ``hy``."""
    return _LightRig((0.05, 0.3), 5, (hx, hy), 0.8, (1.8, 2.9), 0.7, 0.5, 0.15, 0.6)


def _random_lights(spec, rng, rig: _LightRig) -> list:
    """Adds the headlight settings and random lights of ``rig`` to ``spec`` (directional or spot,
    random colour temperature, shadows from some), drawing from ``rng`` in a fixed order; returns
    each light's diffuse colour (3,)."""
    mj = _mujoco()
    spec.visual.headlight.ambient = list(rng.uniform(*rig.ambient) * np.ones(3))
    spec.visual.headlight.diffuse = list(rng.uniform(0.0, 0.3) * np.ones(3))
    spec.visual.headlight.specular = [0.05, 0.05, 0.05]
    (ax, ay), k = rig.xy_half, rig.xy_scale
    diffuse = []
    for j in range(int(rng.integers(1, rig.max_count))):
        warm = rng.uniform(-1, 1)
        colour = np.clip(np.array([1.0 + 0.15 * warm, 1.0, 1.0 - 0.2 * warm]), 0, 1) * rng.uniform(0.3, 0.8)
        pos = np.array([rng.uniform(-ax, ax) * k, rng.uniform(-ay, ay) * k, rng.uniform(*rig.height)])
        direction = -pos + rng.normal(0, rig.spread, 3)
        direction[2] = -abs(direction[2]) - rig.drop
        spot = bool(rng.random() < 0.5)
        spec.worldbody.add_light(
            name=f"light{j}",
            type=mj.mjtLightType.mjLIGHT_SPOT if spot else mj.mjtLightType.mjLIGHT_DIRECTIONAL,
            pos=list(pos),
            dir=list(direction / np.linalg.norm(direction)),
            diffuse=list(colour),
            specular=[rig.specular] * 3,
            cutoff=float(rng.uniform(40, 80)),
            attenuation=[1.0, 0.0, 0.0],
            castshadow=bool(rng.random() < rig.shadow),
        )
        diffuse.append(colour)
    return diffuse


def _material(spec, name, tex, texrepeat=(1.0, 1.0), texuniform=True, rgba=(1.0, 1.0, 1.0, 1.0), specular=0.3):
    mj = _mujoco()
    mat = spec.add_material(
        name=name, texrepeat=list(texrepeat), texuniform=bool(texuniform), rgba=list(rgba), specular=specular
    )
    mat.textures[mj.mjtTextureRole.mjTEXROLE_RGB] = tex
    return name


@dataclasses.dataclass
class _Body:
    """A posable body of the scene: its id, the local vertices about its box centre, the box."""

    body: int
    geom: int
    vertices: np.ndarray  # (V, 3) object frame, relative to the box centre
    offset: np.ndarray  # (3,) box centre in the body frame
    dimensions: np.ndarray  # (3,) full extents


class _ObjectScene:
    """One compiled MuJoCo room with the assets' meshes and distractors; stereo renders of it."""

    def __init__(self, assets: ObjectAssets, width, height, rng, num_distractors: int, room_half):
        mj = _mujoco()
        spec = mj.MjSpec()
        spec.visual.global_.offwidth = max(width, 64)
        spec.visual.global_.offheight = max(height, 64)
        spec.visual.quality.shadowsize = 2048
        spec.visual.quality.numslices = 48
        spec.stat.extent = 10.0
        spec.visual.map.znear = 0.001
        spec.visual.map.zfar = 10.0
        sky = rng.uniform(0.3, 0.9, 3)
        spec.add_texture(
            name="sky",
            type=mj.mjtTexture.mjTEXTURE_SKYBOX,
            builtin=mj.mjtBuiltin.mjBUILTIN_GRADIENT,
            rgb1=list(sky),
            rgb2=list(sky * 0.3),
            width=64,
            height=64,
        )
        # room: floor and four walls, 3 m high
        _texture(spec, "floor_tex", rng, assets.floor_textures)
        rep = float(rng.uniform(0.5, 2.0))
        _material(spec, "floor_mat", "floor_tex", (rep, rep), specular=float(rng.uniform(0.05, 0.4)))
        spec.worldbody.add_geom(
            name="floor", type=mj.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05], pos=[0, 0, 0], material="floor_mat"
        )
        hx, hy = (float(h) for h in room_half)
        for k, (pos, half) in enumerate(
            [((hx, 0), (0.02, hy)), ((-hx, 0), (0.02, hy)), ((0, hy), (hx, 0.02)), ((0, -hy), (hx, 0.02))]
        ):
            _texture(spec, f"wall_tex{k}", rng, assets.wall_textures)
            rep = float(rng.uniform(0.4, 1.5))
            _material(spec, f"wall_mat{k}", f"wall_tex{k}", (rep, rep), specular=float(rng.uniform(0.0, 0.3)))
            spec.worldbody.add_geom(
                name=f"wall{k}",
                type=mj.mjtGeom.mjGEOM_BOX,
                size=[half[0] + 0.02, half[1] + 0.02, 1.5],
                pos=[pos[0], pos[1], 1.5],
                material=f"wall_mat{k}",
            )
        # the objects, each in its own body at the origin (posed per frame)
        for i, ob in enumerate(assets.objects):
            spec.add_mesh(name=f"mesh{i}", file=str(ob.mesh_file), scale=list(ob.scale))
            if ob.texture_file is not None:
                ttype = {
                    "2d": mj.mjtTexture.mjTEXTURE_2D,
                    "cube": mj.mjtTexture.mjTEXTURE_CUBE,
                    "skybox": mj.mjtTexture.mjTEXTURE_SKYBOX,
                }[ob.texture_type]
                spec.add_texture(name=f"obj_tex{i}", type=ttype, file=str(ob.texture_file))
            else:
                spec.add_texture(
                    name=f"obj_tex{i}",
                    type=mj.mjtTexture.mjTEXTURE_2D,
                    builtin=mj.mjtBuiltin.mjBUILTIN_CHECKER,
                    rgb1=list(ob.rgb),
                    rgb2=[0.95, 0.95, 0.95],
                    width=64,
                    height=64,
                )
            _material(spec, f"obj_mat{i}", f"obj_tex{i}", ob.texrepeat, ob.texuniform, specular=0.3)
            body = spec.worldbody.add_body(name=f"object{i}", pos=list(_PARK))
            body.add_geom(name=f"object{i}", type=mj.mjtGeom.mjGEOM_MESH, meshname=f"mesh{i}", material=f"obj_mat{i}")
        # distractors: textured primitives of random shape and size
        shapes = (mj.mjtGeom.mjGEOM_BOX, mj.mjtGeom.mjGEOM_CYLINDER, mj.mjtGeom.mjGEOM_ELLIPSOID)
        self._distractor_half = []
        for j in range(int(num_distractors)):
            _texture(spec, f"dis_tex{j}", rng, assets.distractor_textures + assets.wall_textures)
            rep = float(rng.uniform(1.0, 5.0))
            _material(spec, f"dis_mat{j}", f"dis_tex{j}", (rep, rep), specular=float(rng.uniform(0.1, 0.5)))
            kind = int(rng.integers(3))
            half = rng.uniform(0.02, 0.12, 3)
            if kind == 1:
                half[1] = half[0]
                size = [half[0], half[2], 0.0]
            else:
                size = list(half)
            body = spec.worldbody.add_body(name=f"distractor{j}", pos=list(_PARK))
            body.add_geom(name=f"distractor{j}", type=shapes[kind], size=size, material=f"dis_mat{j}")
            self._distractor_half.append(half)
        # lights: 1-4, directional or spot, random colour temperature; shadows from some
        self._light_diffuse = _random_lights(spec, rng, _room_lights(hx, hy))
        spec.worldbody.add_camera(name="view", pos=[0, 0, 0], quat=[1, 0, 0, 0], fovy=45.0)
        try:
            self.model = spec.compile()
        except ValueError as exc:  # MuJoCo's compile error names the file it could not read
            raise ObjectAssetsMissingError(f"object assets: MuJoCo could not compile the scene: {exc}") from None
        self.data = mj.MjData(self.model)
        self.width, self.height = int(width), int(height)
        self.objects = [self._mesh_body(f"object{i}") for i in range(len(assets.objects))]
        self.distractors = [self._primitive_body(f"distractor{j}", h) for j, h in enumerate(self._distractor_half)]
        for b in self.objects + self.distractors:
            self.model.geom_sameframe[b.geom] = 0
        self._label = np.full(self.model.ngeom + 1, -1, np.int32)
        try:
            self._renderer = mj.Renderer(self.model, self.height, self.width)
        except mj.FatalError as exc:
            raise RuntimeError(
                f"MuJoCo could not create an OpenGL context ({exc}); set MUJOCO_GL=egl before mujoco is first "
                f"imported (MUJOCO_GL is {os.environ.get('MUJOCO_GL')!r})"
            ) from None

    def _geom_pose(self, gid):
        mj = _mujoco()
        R = np.zeros(9)
        mj.mju_quat2Mat(R, self.model.geom_quat[gid])
        return R.reshape(3, 3), self.model.geom_pos[gid].copy()

    def _mesh_body(self, name) -> _Body:
        """A mesh object's box, read off the compiled model: the mesh's vertices in its body frame."""
        gid = self.model.geom(name).id
        mid = int(self.model.geom_dataid[gid])
        a, n = int(self.model.mesh_vertadr[mid]), int(self.model.mesh_vertnum[mid])
        R, t = self._geom_pose(gid)
        v = self.model.mesh_vert[a : a + n].astype(np.float64) @ R.T + t
        lo, hi = v.min(0), v.max(0)
        centre = (lo + hi) / 2
        return _Body(self.model.body(name).id, gid, v - centre, centre, hi - lo)

    def _primitive_body(self, name, half) -> _Body:
        gid = self.model.geom(name).id
        corners = Q.cuboid_corners(np.eye(3), np.zeros(3), np.asarray(half, np.float64), xp=np)
        return _Body(self.model.body(name).id, gid, corners, np.zeros(3), 2 * np.asarray(half, np.float64))

    def place(self, b: _Body, world_R_obj, world_centre):
        """Pose body ``b`` so that its box centre is at ``world_centre``; ``None`` parks it."""
        if world_R_obj is None:
            self.model.body_pos[b.body] = _PARK
            self.model.body_quat[b.body] = [1.0, 0.0, 0.0, 0.0]
            return
        self.model.body_pos[b.body] = world_centre - world_R_obj @ b.offset
        self.model.body_quat[b.body] = mujoco_quaternion(world_R_obj)

    def scale_lights(self, factor: float):
        for j, d in enumerate(self._light_diffuse):
            self.model.light_diffuse[j] = d * factor

    def forward(self):
        _mujoco().mj_forward(self.model, self.data)

    def pose_of(self, b: _Body) -> tuple[np.ndarray, np.ndarray]:
        """(world_R_obj (3, 3), box centre (3,)) of body ``b`` from the model after :meth:`forward`."""
        R = self.data.xmat[b.body].reshape(3, 3).copy()
        return R, self.data.xpos[b.body] + R @ b.offset

    def render(self, K, camera_T_world, labels: dict) -> dict:
        """RGB (H, W, 3) uint8, z-depth (H, W) float32 m (0: nothing), seg (H, W) uint8 (``labels``:
        geom id -> segmentation id; 0 elsewhere) of one view."""
        if self._renderer is None:
            raise ValueError("_ObjectScene: render() called after close()")
        view = mujoco_view(self.model, self.data, self._renderer, 0, K, camera_T_world)
        geom = view["geom"]
        seg = np.zeros(geom.shape, np.uint8)
        for gid, sid in labels.items():
            seg[geom == gid] = sid
        return {"rgb": view["rgb"], "depth": view["depth"], "seg": seg, "geom": geom}

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _box(b: _Body, R, c, K) -> np.ndarray:
    """``[u_min, v_min, u_max, v_max]`` of body ``b``'s projected vertices at camera pose (R, c)."""
    uv, z = Q.project_points(b.vertices @ R.T + c, K, np.eye(4), xp=np)
    if np.any(z <= 0.01):
        return np.array([-1e6, -1e6, 1e6, 1e6])
    return np.concatenate([uv.min(0), uv.max(0)])


def _overlap(a, b, margin=2.0) -> bool:
    return not (a[2] + margin < b[0] or b[2] + margin < a[0] or a[3] + margin < b[1] or b[3] + margin < a[1])


def _inside(box, width, height, border=1.0) -> bool:
    return bool(
        box[0] >= border and box[1] >= border and box[2] <= width - 1 - border and box[3] <= height - 1 - border
    )


def _sample_frame(
    rng, scene, bodies, K, size, baseline, depth_range, room_half, num_distractors, max_objects, tries=60
):
    """Camera pose and placements: labelled ``[(k, R_cam, c_cam, box_l, box_r)]``, distractors
    ``[(body, R_cam, c_cam)]``; ``bodies`` are the labelled candidates (one is drawn per class)."""
    width, height = size
    offset = right_T_left(baseline)[:3, 3]
    limit = np.asarray(room_half) - 0.1
    for _ in range(30):
        T = _camera_pose(rng)
        world_T_cam = Q.invert_pose(T, xp=np)

        def ok_world(c_cam, half_diag):
            w = Q.transform_points(world_T_cam, c_cam, xp=np)
            return w[2] - half_diag > 0.01 and np.all(np.abs(w[:2]) + half_diag < limit)

        n = int(rng.integers(1, min(max_objects, len(bodies)) + 1))
        placed = []
        for k in rng.choice(len(bodies), size=n, replace=False):
            b = bodies[k]
            half_diag = float(np.linalg.norm(b.dimensions) / 2)
            for _ in range(tries):
                R = Q.quaternion_wxyz_to_rotation(rng.normal(size=4), xp=np)
                uv = np.array([rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height])
                c = Q.back_project(uv, rng.uniform(*depth_range), K, np.eye(4), xp=np)
                if c[2] - half_diag < 0.1 or not ok_world(c, half_diag):
                    continue
                bl, br = _box(b, R, c, K), _box(b, R, c + offset, K)
                if not (_inside(bl, width, height) and _inside(br, width, height)):
                    continue
                if any(_overlap(bl, p[3]) or _overlap(br, p[4]) for p in placed):
                    continue
                placed.append((int(k), R, c, bl, br))
                break
        if not placed:
            continue
        distractors = []
        for d in scene.distractors[: int(rng.integers(0, num_distractors + 1))]:
            half_diag = float(np.linalg.norm(d.dimensions) / 2)
            for _ in range(tries // 3):
                R = Q.quaternion_wxyz_to_rotation(rng.normal(size=4), xp=np)
                uv = np.array([rng.uniform(-0.1, 1.1) * width, rng.uniform(-0.1, 1.1) * height])
                c = Q.back_project(uv, rng.uniform(depth_range[0], depth_range[1] + 0.8), K, np.eye(4), xp=np)
                if c[2] - half_diag < 0.1 or not ok_world(c, half_diag):
                    continue
                bl, br = _box(d, R, c, K), _box(d, R, c + offset, K)
                if any(_overlap(bl, p[3], 4.0) or _overlap(br, p[4], 4.0) for p in placed):
                    continue
                distractors.append((d, R, c))
                break
        return T, placed, distractors
    raise RuntimeError("could not place any object in 30 camera poses; image too small for the objects?")


def write_object_dataset(
    out_dir,
    num_scenes: int,
    seed: int = 0,
    split: str = "train",
    *,
    assets: ObjectAssets | None = None,
    frames_per_scene: int = 10,
    image_size: tuple = (256, 192),
    labels: str = "volumon",
    max_objects: int = 3,
    num_distractors: int = 3,
    depth_range: tuple = (0.45, 1.1),
    baseline: float = FAT_BASELINE,
    image_format: str = "jpg",
    bbox_order: str = "yx",
    progress: bool = True,
) -> list:
    """Render ``num_scenes`` scenes of ``frames_per_scene`` stereo frames into ``<out_dir>/<split>/``.

    Args:
      out_dir: root directory (created).
      num_scenes: scene directories ``scene_000`` ... to write (each one room, light set and
        choice of textures).
      seed: dataset seed; with ``split`` and the assets it fixes every random choice (same
        arguments, same files).
      split: ``'train'``, ``'val'`` or ``'test'`` (disjoint seed streams).
      assets: meshes and textures (default: :func:`robosuite_assets`, which needs the
        ``objects`` extra).
      frames_per_scene: stereo frames per scene.
      image_size: ``(W, H)`` pixels; K is :func:`jaxsem.volumon.data.synthetic_intrinsics` (FAT's 64
        degree horizontal field of view, centred principal point).
      labels: ``'volumon'`` (each object written as its VoluMon stand-in class) or ``'own'``
        (its own class); see the module docstring.
      max_objects: at most this many labelled objects per frame.
      num_distractors: distractor primitives per scene (0 to this many are shown per frame).
      depth_range: (min, max) metres of labelled object centres in front of the camera.
      baseline: stereo baseline in metres (right camera at +x of the left one, FAT's convention).
      image_format: ``'jpg'`` (as FAT) or ``'png'`` (exact).
      bbox_order: ``'yx'`` (FAT's ``[y, x]`` box quirk) or ``'xy'``.
      progress: show a tqdm bar.

    Returns:
      The scene directories written (``pathlib.Path``).
    """
    fat_writer.check_split(split, _SPLIT_STREAM)
    if labels not in ("volumon", "own"):
        raise ValueError(f"labels: expected 'volumon' or 'own', got {labels!r}")
    num_scenes, frames_per_scene = fat_writer.check_scenes(num_scenes, frames_per_scene)
    max_objects = int(max_objects)
    if max_objects < 1:
        raise ValueError(f"max_objects: expected >= 1, got {max_objects}")
    if int(num_distractors) < 0:
        raise ValueError(f"num_distractors: expected >= 0, got {num_distractors}")
    width, height = fat_writer.check_image_size(image_size)
    lo, hi = (float(x) for x in depth_range)
    if not 0.2 <= lo <= hi <= 5.0:
        raise ValueError(f"depth_range: expected 0.2 <= min <= max <= 5 m, got {depth_range}")
    if not (math.isfinite(float(baseline)) and 0 <= float(baseline) <= 1):
        raise ValueError(f"baseline: expected 0 to 1 m, got {baseline}")
    fat_writer.check_formats(image_format, bbox_order)
    if assets is None:
        assets = robosuite_assets()
    if not isinstance(assets, ObjectAssets):
        raise ValueError(f"assets: expected an ObjectAssets, got {type(assets).__name__}")
    if labels == "volumon":
        bad = [o.class_name for o in assets.objects if o.volumon_class not in VOLUMON_CLASS_NAMES]
        if bad:
            raise ValueError(f"assets: labels='volumon' needs a volumon_class in {VOLUMON_CLASS_NAMES} for {bad}")

    from tqdm.auto import tqdm  # deferred: tqdm.auto is slow to import and only the writer needs it

    K = synthetic_intrinsics(width, height)
    T_rl = right_T_left(baseline)
    root = pathlib.Path(out_dir) / split
    root.mkdir(parents=True, exist_ok=True)
    stream = _SPLIT_STREAM[split]
    bar = tqdm(total=num_scenes * frames_per_scene, desc=f"objects {split}", disable=not progress, unit="frame")
    scene_dirs = []
    for s in range(num_scenes):
        rng = np.random.default_rng([int(seed), stream, s, 0x0B1EC7])
        final = root / f"scene_{s:03d}"
        with fat_writer.partial_dir(final) as tmp:
            _write_scene(
                tmp, rng, assets, K, T_rl, (width, height), labels, max_objects, int(num_distractors),
                (lo, hi), float(baseline), frames_per_scene, image_format, bbox_order, bar,
            )  # fmt: skip
        scene_dirs.append(final)
    bar.close()
    return scene_dirs


def _write_scene(
    scene_dir, rng, assets, K, T_rl, size, labels, max_objects, num_distractors, depth_range, baseline, frames,
    image_format, bbox_order, bar,
):  # fmt: skip
    width, height = size
    room_half = rng.uniform(1.8, 3.0, 2)
    # which meshes are labelled here, and under which class (one mesh per written class)
    order = rng.permutation(len(assets.objects))
    written: dict[str, int] = {}
    for i in order:
        ob = assets.objects[i]
        written.setdefault(ob.volumon_class if labels == "volumon" else ob.class_name, int(i))
    names = sorted(written)
    labelled = [written[n] for n in names]
    scene = _ObjectScene(assets, width, height, rng, num_distractors, room_half)
    try:
        bodies = [scene.objects[i] for i in labelled]
        table = [
            ObjectClass(n, assets.objects[i].shape, tuple(b.dimensions), (0.5, 0.5, 0.5), fat_writer.segmentation_id(n))
            for n, i, b in zip(names, labelled, bodies)
        ]
        fat_writer.write_settings(scene_dir, table, K, width, height)
        unused = [scene.objects[i] for i in range(len(assets.objects)) if i not in labelled]
        for f in range(frames):
            T, placed, distractors = _sample_frame(
                rng, scene, bodies, K, size, baseline, depth_range, room_half, num_distractors, max_objects
            )
            world_T_cam = Q.invert_pose(T, xp=np)
            Rwc = world_T_cam[:3, :3]
            shown = {p[0] for p in placed}
            for k, b in enumerate(bodies):
                if k not in shown:
                    scene.place(b, None, None)
            for b in unused + scene.distractors:
                scene.place(b, None, None)
            for k, R, c, _, _ in placed:
                scene.place(bodies[k], Rwc @ R, Q.transform_points(world_T_cam, c, xp=np))
            for d, R, c in distractors:
                scene.place(d, Rwc @ R, Q.transform_points(world_T_cam, c, xp=np))
            scene.scale_lights(float(rng.uniform(0.7, 1.3)))
            scene.forward()
            # ground truth from the model: pose of each labelled body, its box from its vertices
            truth = []
            for k, *_ in placed:
                wR, wc = scene.pose_of(bodies[k])
                R_cam, c_cam = T[:3, :3] @ wR, Q.transform_points(T, wc, xp=np)
                b = bodies[k]
                truth.append(
                    (k, R_cam, c_cam, b.dimensions, _box(b, R_cam, c_cam, K), _box(b, R_cam, c_cam + T_rl[:3, 3], K))
                )
            seg_ids = {bodies[k].geom: table[k].segmentation_class_id for k, *_ in placed}
            stem = f"{f:06d}"
            for side, pose, offset in (("left", T, np.zeros(3)), ("right", T_rl @ T, T_rl[:3, 3])):
                view = scene.render(K, pose, seg_ids)
                frame = fat_writer.frame_json(truth, table, K, pose, offset, bbox_order)
                for ob, (k, *_) in zip(frame["objects"], truth):
                    ob["mesh_class"] = assets.objects[labelled[k]].class_name
                fat_writer.write_camera(
                    scene_dir / f"{stem}.{side}", image_format, view["rgb"], view["depth"], view["seg"], frame
                )
            bar.update(1)
    finally:
        scene.close()
    meta = {
        "source": assets.source,
        "labels": labels,
        "objects": {n: assets.objects[i].class_name for n, i in zip(names, labelled)},
    }
    (scene_dir / "_objects.json").write_text(json.dumps(meta, indent=1))
