"""Ray-cast rendering of the simulated world: raw RGB, ground-truth labels and z-depth.

The world is one triangle soup in an Open3D CPU :class:`open3d.t.geometry.RaycastingScene`; every
triangle carries a semantic :class:`~bimcap.labels.Label`, a :class:`~bimcap.sim.texture.Material`
and the index of the element it belongs to. A pixel's ray is ``Camera.rays(uv, distorted=True)``,
i.e. the inverse of the plumb_bob distortion, so the image is *raw* (distorted) like a real
camera's. The rays have z = 1 in the camera frame, so Open3D's ray parameter ``t_hit`` is the
pixel's z-depth directly.

Shading: albedo from :class:`~bimcap.sim.texture.TextureBank` at the hit point (view-consistent),
Lambertian (two-sided, because IFC tessellations do not orient faces consistently) under a lamp
at the camera centre with inverse-square-like fall-off plus ambient light, a mild vignette, then
gamma and Gaussian read + shot noise.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bimcap.errors import BimcapError, InputError
from bimcap.geometry.camera import Camera
from bimcap.geometry.local_frame import local_origin
from bimcap.geometry.poses import quat_to_rotmat
from bimcap.labels import Label
from bimcap.sim.texture import GRIME_PERIOD_M, Material, TextureBank

if TYPE_CHECKING:
    import open3d as o3d

F64 = NDArray[np.float64]


class SimError(BimcapError):
    """The simulator cannot run (empty world, no free space to walk in, bad configuration)."""


class SimConfigError(SimError, InputError):
    """A simulator setting out of range; names the setting (``field``)."""


#: Default material of each label (indexed by label id).
LABEL_MATERIAL: dict[Label, Material] = {
    Label.UNKNOWN: Material.CONCRETE,
    Label.WALL: Material.PLASTER,
    Label.FLOOR: Material.TILES,
    Label.CEILING: Material.CEILING,
    Label.COLUMN: Material.CONCRETE,
    Label.DOOR: Material.WOOD,
    Label.WINDOW: Material.GLASS,
    Label.CLUTTER: Material.CARDBOARD,
}

#: Colour of rays that leave the building (through windows or openings), RGB in [0, 1].
SKY_RGB = np.array([0.78, 0.84, 0.92], dtype=np.float32)


@dataclass
class MeshPart:
    """One element of the world.

    Attributes
    ----------
    name: GUID or a descriptive name (clutter).
    label: semantic class of every triangle (slabs are split into floor/ceiling by
        :meth:`World.from_parts` when ``split_slabs`` is set).
    vertices: (V, 3) float64 world metres.
    faces: (F, 3) int32 vertex indices.
    material: appearance; ``None`` = the label's default.
    """

    name: str
    label: Label
    vertices: F64
    faces: NDArray[np.int32]
    material: Material | None = None


@dataclass
class World:
    """A triangle soup with per-triangle semantics, ready for ray casting.

    Open3D casts rays in float32, whose steps are 0.5 m at 5·10⁶ m (a georeferenced model's
    northing): the triangles are held relative to ``origin``
    (:func:`~bimcap.geometry.local_frame.local_origin`), and
    :meth:`cast` and :meth:`distance` take world coordinates in float64 and subtract it first.

    Attributes
    ----------
    vertices: (V, 3) float32 metres relative to ``origin`` (world = ``vertices + origin``).
    faces: (F, 3) int32.
    tri_label: (F,) uint8 :class:`Label` ids.
    tri_material: (F,) uint8 :class:`Material` ids.
    tri_element: (F,) int32 index into ``names``.
    names: element names / GUIDs.
    element_offset: (E, 2) float64 texture offsets (metres) per element.
    origin: (3,) float64 world metres of the vertices' zero (zero for a model near the origin).
    """

    vertices: NDArray[np.float32]
    faces: NDArray[np.int32]
    tri_label: NDArray[np.uint8]
    tri_material: NDArray[np.uint8]
    tri_element: NDArray[np.int32]
    names: list[str]
    element_offset: F64
    origin: F64 = field(default_factory=lambda: np.zeros(3))
    _scene: Any = field(default=None, repr=False, compare=False)

    @classmethod
    def from_parts(
        cls, parts: Iterable[MeshPart], seed: int = 0, split_slabs: bool = True
    ) -> World:
        """Concatenate parts into one world.

        With ``split_slabs``, the downward-facing triangles (n_z < -0.5) of FLOOR parts become
        CEILING: a floor slab is the ceiling of the storey below (and a one-storey building's slab
        seen from underneath). Texture offsets per element come from ``seed``.
        """
        verts: list[F64] = []
        faces: list[NDArray[np.int32]] = []
        labels: list[NDArray[np.uint8]] = []
        mats: list[NDArray[np.uint8]] = []
        elems: list[NDArray[np.int32]] = []
        names: list[str] = []
        n_v = 0
        for part in parts:
            v = np.asarray(part.vertices, np.float64).reshape(-1, 3)
            f = np.asarray(part.faces, np.int64).reshape(-1, 3)
            if len(f) == 0:
                continue
            if f.min() < 0 or f.max() >= len(v):
                raise SimError(f"element {part.name}: face index out of range")
            lab = np.full(len(f), int(part.label), np.uint8)
            if split_slabs and part.label == Label.FLOOR:
                n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
                nz = n[:, 2] / np.maximum(np.linalg.norm(n, axis=1), 1e-12)
                lab[nz < -0.5] = Label.CEILING
            mat = part.material if part.material is not None else LABEL_MATERIAL[part.label]
            mat_arr = np.full(len(f), int(mat), np.uint8)
            if part.material is None:
                mat_arr[lab == Label.FLOOR] = Material.TILES
                mat_arr[lab == Label.CEILING] = Material.CEILING
            verts.append(v)
            faces.append((f + n_v).astype(np.int32))
            labels.append(lab)
            mats.append(mat_arr)
            elems.append(np.full(len(f), len(names), np.int32))
            names.append(part.name)
            n_v += len(v)
        if not faces:
            raise SimError("the world has no triangles")
        rng = np.random.default_rng([seed, 31337])
        offsets = rng.uniform(0.0, 4096.0, size=(len(names), 2))
        all_verts = np.concatenate(verts)
        origin = local_origin(all_verts)
        return cls(
            (all_verts - origin).astype(np.float32),
            np.concatenate(faces),
            np.concatenate(labels),
            np.concatenate(mats),
            np.concatenate(elems),
            names,
            offsets,
            origin,
        )

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_scene"] = None  # an Open3D scene cannot be pickled; rebuilt on demand
        return state

    @property
    def n_triangles(self) -> int:
        return len(self.faces)

    def world_vertices(self) -> F64:
        """(V, 3) float64 world metres."""
        return self.vertices.astype(np.float64) + self.origin

    def scene(self) -> o3d.t.geometry.RaycastingScene:
        """The (cached) Open3D raycasting scene; geometry id 0, primitive id = triangle index."""
        if self._scene is None:
            import open3d as o3d

            scene = o3d.t.geometry.RaycastingScene()
            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = o3d.core.Tensor(np.ascontiguousarray(self.vertices))
            mesh.triangle.indices = o3d.core.Tensor(np.ascontiguousarray(self.faces))
            scene.add_triangles(mesh)
            self._scene = scene
        return self._scene

    def cast(self, origins: F64, directions: F64, nthreads: int = 0) -> dict[str, NDArray[Any]]:
        """Cast rays (M, 3) + (M, 3) in world metres; returns Open3D's result as numpy arrays.

        Keys: ``t_hit`` (M,) float32 in units of the direction's length (inf = no hit),
        ``primitive_ids`` (M,) uint32 triangle index (``INVALID_ID`` = no hit),
        ``primitive_normals`` (M, 3) float32.
        """
        import open3d as o3d

        rays = np.empty((len(origins), 6), dtype=np.float32)
        rays[:, :3] = np.asarray(origins, np.float64) - self.origin
        rays[:, 3:] = directions
        res = self.scene().cast_rays(o3d.core.Tensor(rays), nthreads=nthreads)
        return {
            "t_hit": res["t_hit"].numpy(),
            "primitive_ids": res["primitive_ids"].numpy(),
            "primitive_normals": res["primitive_normals"].numpy(),
        }

    def distance(self, points: F64, nthreads: int = 0) -> NDArray[np.float32]:
        """(M,) unsigned distance in metres from each point (M, 3) to the nearest triangle."""
        import open3d as o3d

        local = np.asarray(points, np.float64) - self.origin
        q = o3d.core.Tensor(np.ascontiguousarray(local, dtype=np.float32))
        return self.scene().compute_distance(q, nthreads=nthreads).numpy()


@dataclass(frozen=True)
class ShadingConfig:
    """Photometric model of the simulated camera.

    Attributes
    ----------
    ambient: ambient light level (fraction of albedo).
    light_gain: gain of the point light near the camera.
    falloff_m: distance at which the light has dropped to half.
    gamma: display gamma applied after shading.
    vignette: relative darkening at the image corner.
    noise_dn: Gaussian read noise std in 8-bit digital numbers.
    shot_noise: shot-noise std factor (× sqrt(DN)).
    """

    ambient: float = 0.22
    light_gain: float = 1.0
    falloff_m: float = 7.0
    gamma: float = 1.0 / 1.8
    vignette: float = 0.25
    noise_dn: float = 1.5
    shot_noise: float = 0.25


@dataclass
class RenderedFrame:
    """One rendered raw camera frame.

    Attributes
    ----------
    rgb: (H, W, 3) uint8 raw (distorted) image.
    labels: (H, W) uint8 :class:`Label` ids (UNKNOWN where no surface was hit).
    depth: (H, W) float32 z-depth in metres in the raw image (0 where no surface was hit).
    """

    rgb: NDArray[np.uint8]
    labels: NDArray[np.uint8]
    depth: NDArray[np.float32]


def rotate_rows(v: NDArray[np.float32], rot: NDArray[np.floating]) -> NDArray[np.float32]:
    """``v @ rot.T`` for (M, 3) float32 rows, through ``cv2.transform``.

    numpy's matmul sends this skinny product to BLAS, which costs ~10× more CPU here.
    """
    import cv2

    out = cv2.transform(v.reshape(-1, 1, 3), np.asarray(rot, np.float32))
    return out.reshape(-1, 3)


class Renderer:
    """Renders raw images of a :class:`World` through one :class:`Camera`.

    Computed once: the per-pixel camera-frame rays (inverse distortion, z = 1), the vignette, and
    per triangle the texture projection axis and texture offset, so that a frame costs one
    ``cast_rays`` call plus a few float32 array passes.
    """

    def __init__(
        self,
        world: World,
        camera: Camera,
        textures: TextureBank,
        shading: ShadingConfig | None = None,
    ) -> None:
        self.world = world
        self.camera = camera
        self.textures = textures
        self.shading = shading or ShadingConfig()
        uv = camera.pixel_grid()
        self.rays_in_cam = camera.rays(uv, distorted=True).astype(np.float32)  # (H·W, 3), z = 1
        ray_norm = np.linalg.norm(self.rays_in_cam, axis=1)
        # one pixel subtends ~ 1/f radians along the ray (ignoring distortion's small stretch):
        # footprint = z·|ray|·(1/f) / cos(view) = z·|ray|²/f / |ray·n|  (n unit)
        self._foot_scale = (ray_norm**2 / min(camera.fx, camera.fy)).astype(np.float32)
        self._min_dot = (0.15 * ray_norm).astype(np.float32)  # cos(view) >= 0.15
        self._ray_norm2 = (ray_norm**2).astype(np.float32)
        levels = np.arange(4096, dtype=np.float32) / 4095.0
        self._gamma_lut = (255.0 * np.power(levels, self.shading.gamma)).astype(np.float32) + 0.5
        sh = self.shading
        noise_var = sh.noise_dn**2 + sh.shot_noise**2 * self._gamma_lut
        self._noise_lut = np.sqrt(noise_var).astype(np.float32)
        r2 = ((uv[:, 0] - camera.cx) / camera.width) ** 2
        r2 += ((uv[:, 1] - camera.cy) / camera.height) ** 2
        vig = 1.0 - self.shading.vignette * np.clip(r2 / 0.5, 0.0, 1.0)
        self.vignette = vig.astype(np.float32)
        # per triangle: dominant axis of the geometric normal and the element's texture offset
        tri = world.vertices[world.faces].astype(np.float64)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self._tri_axis = np.argmax(np.abs(n), axis=1).astype(np.int8)
        # offsets reduced modulo the grime period keep float32 texture coordinates exact enough
        off = np.mod(world.element_offset, GRIME_PERIOD_M)[world.tri_element]
        self._tri_offset = off.astype(np.float32)

    def render(
        self,
        world_from_cam: Sequence[float] | F64,
        rng: np.random.Generator,
        nthreads: int = 0,
        timings: dict[str, float] | None = None,
    ) -> RenderedFrame:
        """Render one frame at pose ``world_from_cam`` (7,) TUM order; ``rng`` draws sensor noise.

        The light is a lamp at the camera centre:
        irradiance = ambient + gain·cos(θ)/(1 + d²/d0²), θ the angle between the ray and the
        face normal, d the distance.
        """
        import time

        t0 = time.perf_counter()
        pose = np.asarray(world_from_cam, np.float64)
        r_wc = quat_to_rotmat(pose[3:7]).astype(np.float32)
        origin = (pose[:3] - self.world.origin).astype(np.float32)  # in the world's local frame
        dirs_w = rotate_rows(self.rays_in_cam, r_wc)  # (P, 3) float32
        hit = self.world.cast(np.broadcast_to(pose[:3], dirs_w.shape), dirs_w, nthreads)
        t1 = time.perf_counter()
        depth = hit["t_hit"]
        valid = np.isfinite(depth)
        all_valid = bool(valid.all())
        # shade every pixel and patch the misses afterwards: cheaper than gathering subsets
        if all_valid:
            z = depth
            prim = hit["primitive_ids"].astype(np.intp)
        else:
            z = np.where(valid, depth, np.float32(0.0))
            prim = np.where(valid, hit["primitive_ids"], 0).astype(np.intp)
        normal = hit["primitive_normals"]  # unit for hits (Open3D normalises them)
        labels = self.world.tri_label[prim]
        if not all_valid:
            labels[~valid] = Label.UNKNOWN
        p_w = dirs_w * z[:, None]
        p_w += origin  # hit points relative to world.origin (textures follow them)
        # surface coordinates: drop the dominant axis (z → (x, y), x → (y, z), y → (x, z))
        axis = self._tri_axis[prim]
        st = self._tri_offset[prim]
        st[:, 0] += np.where(axis == 0, p_w[:, 1], p_w[:, 0])
        st[:, 1] += np.where(axis == 2, p_w[:, 1], p_w[:, 2])
        dot = np.abs(np.einsum("ij,ij->i", dirs_w, normal))
        footprint = z * self._foot_scale / np.maximum(dot, self._min_dot)
        albedo = self.textures.sample(st, self.world.tri_material[prim], footprint)
        t2 = time.perf_counter()

        sh = self.shading
        dist2 = z * z * self._ray_norm2
        cos_l = dot / np.sqrt(self._ray_norm2)
        irr = sh.ambient + sh.light_gain * cos_l / (1.0 + dist2 * np.float32(1.0 / sh.falloff_m**2))
        irr *= self.vignette
        albedo *= irr[:, None]
        if not all_valid:
            albedo[~valid] = SKY_RGB * self.vignette[~valid, None]
        # gamma through a 4096-entry look-up table, then read and shot noise
        albedo *= np.float32(4095.0)
        np.minimum(albedo, np.float32(4095.0), out=albedo)
        q = albedo.astype(np.int16)
        dn = self._gamma_lut[q]  # includes the +0.5 of rounding
        noise = rng.standard_normal(dn.shape, dtype=np.float32)
        noise *= self._noise_lut[q]
        dn += noise
        np.clip(dn, 0.0, 255.0, out=dn)
        cam = self.camera
        rgb = dn.astype(np.uint8).reshape(cam.height, cam.width, 3)
        depth_img = z.reshape(cam.height, cam.width)
        t3 = time.perf_counter()
        if timings is not None:
            timings["raycast"] = timings.get("raycast", 0.0) + (t1 - t0)
            timings["texture"] = timings.get("texture", 0.0) + (t2 - t1)
            timings["shade"] = timings.get("shade", 0.0) + (t3 - t2)
        return RenderedFrame(rgb, labels.reshape(cam.height, cam.width), depth_img)
