"""The mock's camera: the work cell rendered by MuJoCo, with the marker map's markers on the
objects (no ROS).

The scene is the generated MuJoCo model of the robot and its work cell
(:func:`hyperarm_description.mjcf.generate_mjcf`, the same the mock steps), plus each marker
of the marker map as a thin textured plate (the dictionary's image from
``cv2.aruco.generateImageMarker``, with a white margin of one bit) on a mocap body per
object. Rendering only poses the scene, it steps nothing: the arm's joints from the
driver's joint states, the block (a free body) and each object's markers from the given
object poses, a peg's cylinder moved to where its pose says. The picture is MuJoCo's
offscreen render from the description's camera (``camera_link``; MuJoCo's camera looks
along its -z), without shadows, reflections or sky (:data:`_OFF`), blurred and with Gaussian
pixel noise; its pinhole model is
:meth:`RenderedCamera.camera`, ideal (no distortion) with the description's vertical field
of view, as the ``CameraInfo`` a driver would publish.

Needs an OpenGL context: set ``MUJOCO_GL=egl`` (or ``osmesa``) before mujoco is imported on
a machine without a display (``scripts/setup.sh`` installs the EGL packages).

Units: m, rad; poses are 4x4 homogeneous matrices in the robot's root frame; images uint8
RGB, ``height`` x ``width`` x 3.
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import cv2
import mujoco
import numpy as np

from hyperarm_description.mjcf import PhysicsOptions, camera_link_pose, generate_mjcf
from hyperarm_description.model import RobotDescription
from hyperarm_description.world import WorldSpec

from .markers import CameraModel, MarkerMap, PerceptionError

__all__ = ["RenderOptions", "RenderedCamera", "RenderError", "MARKER_LIFT", "cell_poses"]

#: How far (m) a marker plate sits out of the surface it is printed on: it must not be
#: hidden inside that surface by the depth buffer, and is thin as a sticker.
MARKER_LIFT = 2e-4

#: Where the mocap body of an object not in the poses is parked (out of the camera's view).
_PARKED = np.array([0.0, 0.0, -3.0])


#: MuJoCo's scene effects left out: shadows, reflections and the sky cost 3/4 of a picture's
#: time in software rendering (llvmpipe: 75 ms at 640x480 with them, 18 ms without) and
#: none of them is needed to find a marker.
_OFF = (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION,
        mujoco.mjtRndFlag.mjRND_SKYBOX)


class RenderError(PerceptionError):
    """The scene cannot be built or rendered (no OpenGL context, a bad option)."""


@dataclass(frozen=True)
class RenderOptions:
    """``width`` x ``height`` (pixels), ``blur_sigma`` (pixels, the optics; 0: none),
    ``noise_sigma`` (grey levels, the sensor's Gaussian noise per pixel and channel; 0:
    none), ``seed`` of the noise (None: fresh)."""

    width: int = 640
    height: int = 480
    blur_sigma: float = 0.5
    noise_sigma: float = 2.0
    seed: int | None = None

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if not isinstance(value, int) or not 16 <= value <= 4096:
                raise RenderError(f"{name} must be an integer in 16..4096 pixels, got {value!r}")
        for name in ("blur_sigma", "noise_sigma"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0.0):
                raise RenderError(f"{name} must be a finite number >= 0, got {value!r}")


def cell_poses(world: WorldSpec) -> dict[str, np.ndarray]:
    """The work cell's objects at rest, as the mock's truth names them (4x4 in the root
    frame): ``<peg>_peg`` at each peg's top centre, and ``block`` (its centre) threaded on
    its start peg, resting on the table."""
    out = {}
    for p in world.pegs:
        top = np.eye(4)
        top[:3, 3] = [*p.xy, world.table.height + p.height]
        out[f"{p.name}_peg"] = top
    if world.block is not None:
        block = np.eye(4)
        block[:3, 3] = [*world.peg(world.block.start).xy,
                        world.table.height + 0.5 * world.block.size[2]]
        out["block"] = block
    return out


def _marker_png(dictionary: str, marker_id: int, folder: Path) -> tuple[Path, float]:
    """The marker's image with a white margin of one bit, written as a PNG in ``folder``;
    returns its path and the ratio of the whole image's edge to the black square's."""
    aruco = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    bits = aruco.markerSize + 2                      # the data bits and the black border
    cell = 16
    inner = cv2.aruco.generateImageMarker(aruco, marker_id, bits * cell, borderBits=1)
    img = cv2.copyMakeBorder(inner, cell, cell, cell, cell, cv2.BORDER_CONSTANT, value=255)
    path = folder / f"marker{marker_id}.png"
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    return path, (bits + 2) / bits


class RenderedCamera:
    """Renders the description's camera view of ``world`` with ``marker_map``'s markers.

    ``held`` {object: 4x4 of its frame in tool0}: objects the gripper holds (e.g. the hand-eye
    calibration target), drawn where the arm's joints put tool0. Raises :class:`RenderError`
    for a held object that is not in the marker map, or if MuJoCo cannot make an OpenGL
    context (set ``MUJOCO_GL``)."""

    def __init__(self, desc: RobotDescription, world: WorldSpec, marker_map: MarkerMap,
                 options: RenderOptions | None = None,
                 physics: PhysicsOptions | None = None,
                 held: Mapping[str, np.ndarray] | None = None) -> None:
        self.options = opts = options or RenderOptions()
        objects = {m.object for m in marker_map.markers.values()}
        self.held = {}
        for name, pose in (held or {}).items():
            if name not in objects:
                raise RenderError(f"held object {name!r} has no marker in the marker map "
                                  f"(objects: {', '.join(sorted(objects))})")
            pose = np.asarray(pose, dtype=float)
            if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
                raise RenderError(f"held object {name!r}: its pose in tool0 must be a finite "
                                  "4x4 matrix")
            self.held[name] = pose
        self.desc = desc
        self.camera = CameraModel.from_fovy(opts.width, opts.height, desc.camera.fovy)
        #: camera_link in the root frame
        self.camera_pose = camera_link_pose(desc)
        self._rng = np.random.default_rng(opts.seed)
        spec = mujoco.MjSpec.from_string(generate_mjcf(desc, world, physics))
        spec.visual.global_.offwidth = max(opts.width, spec.visual.global_.offwidth)
        spec.visual.global_.offheight = max(opts.height, spec.visual.global_.offheight)
        self._objects = sorted({m.object for m in marker_map.markers.values()})
        with tempfile.TemporaryDirectory(prefix="hyperarm-markers-") as tmp:
            for name in self._objects:
                body = spec.worldbody.add_body(name=f"markers_{name}", mocap=True,
                                               pos=_PARKED)
                for m in marker_map.markers.values():
                    if m.object != name:
                        continue
                    png, ratio = _marker_png(marker_map.dictionary, m.id, Path(tmp))
                    spec.add_texture(name=f"marker{m.id}", type=mujoco.mjtTexture.mjTEXTURE_2D,
                                     file=str(png))
                    mat = spec.add_material(name=f"marker{m.id}", texrepeat=[1.0, 1.0],
                                            texuniform=False, specular=0.0, shininess=0.0,
                                            reflectance=0.0)
                    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"marker{m.id}"
                    lifted = m.offset[:3, 3] + MARKER_LIFT * m.offset[:3, 2]
                    quat = np.empty(4)
                    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(m.offset[:3, :3]).reshape(-1))
                    half = 0.5 * m.size * ratio
                    body.add_geom(name=f"marker{m.id}", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                  size=[half, half, 0.001], pos=lifted, quat=quat,
                                  material=f"marker{m.id}", contype=0, conaffinity=0)
            try:
                self.model = spec.compile()
            except Exception as exc:     # mujoco's own error types
                raise RenderError(f"cannot build the scene: {exc}") from exc
        self.data = mujoco.MjData(self.model)
        self._mocap = {name: int(self.model.body(f"markers_{name}").mocapid[0])
                       for name in self._objects}
        names = [self.model.joint(j).name for j in range(self.model.njnt)]
        self._qadr = {n: int(self.model.jnt_qposadr[j]) for j, n in enumerate(names)
                      if int(self.model.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE),
                                                         int(mujoco.mjtJoint.mjJNT_SLIDE))}
        self._block = (int(self.model.jnt_qposadr[self.model.joint("block").id])
                       if "block" in names else None)
        self._pegs = {f"{p.name}_peg": (self.model.geom(f"peg_{p.name}").id, 0.5 * p.height)
                      for p in world.pegs}
        # joints coupled by equality constraints (the fingers to the gripper): their
        # polynomial, evaluated when posing
        self._coupled = []
        for e in range(self.model.neq):
            if int(self.model.eq_type[e]) == int(mujoco.mjtEq.mjEQ_JOINT):
                a, b = self.model.eq_obj1id[e], self.model.eq_obj2id[e]
                self._coupled.append((int(self.model.jnt_qposadr[a]),
                                      int(self.model.jnt_qposadr[b]),
                                      np.array(self.model.eq_data[e][:5])))
        self._cam_id = self.model.camera(desc.camera.frame).id
        self._tool = self.model.body(desc.tool_frame).id
        self._vopt = mujoco.MjvOption()
        self._vopt.sitegroup[:] = 0          # the model's sites (its camera's) are not seen
        try:
            self._renderer = mujoco.Renderer(self.model, opts.height, opts.width)
        except Exception as exc:         # no OpenGL backend: mujoco raises several kinds
            raise RenderError(f"MuJoCo cannot render here ({type(exc).__name__}: {exc}); set "
                              "MUJOCO_GL=egl or osmesa") from exc

    def close(self) -> None:
        """Free the OpenGL context."""
        self._renderer.close()

    def __enter__(self) -> "RenderedCamera":
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def pose(self, joints: Mapping[str, float], objects: Mapping[str, np.ndarray]) -> None:
        """Pose the scene: ``joints`` {name: position (rad, m)} (others keep theirs),
        ``objects`` {name: 4x4 pose in the root frame}, the held objects on tool0; an object
        of the marker map that is neither given nor held is out of view (its markers parked
        far below)."""
        q = self.data.qpos
        for name, value in joints.items():
            if name in self._qadr:
                q[self._qadr[name]] = float(value)
        for a, b, poly in self._coupled:
            q[a] = float(np.polyval(poly[::-1], q[b]))
        if self.held:
            mujoco.mj_kinematics(self.model, self.data)
            tool = self.tool_pose()
            objects = {**objects, **{n: tool @ t for n, t in self.held.items()}}
        for name in self._objects:
            pose = objects.get(name)
            mid = self._mocap[name]
            if pose is None:
                self.data.mocap_pos[mid] = _PARKED
                continue
            self.data.mocap_pos[mid] = pose[:3, 3]
            mujoco.mju_mat2Quat(self.data.mocap_quat[mid],
                                np.ascontiguousarray(pose[:3, :3]).reshape(-1))
        block = objects.get("block")
        if block is not None and self._block is not None:
            q[self._block:self._block + 3] = block[:3, 3]
            mujoco.mju_mat2Quat(q[self._block + 3:self._block + 7],
                                np.ascontiguousarray(block[:3, :3]).reshape(-1))
        for name, (geom, half) in self._pegs.items():
            if (top := objects.get(name)) is not None:
                self.model.geom_pos[geom] = top[:3, 3] - half * top[:3, 2]
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)

    def tool_pose(self) -> np.ndarray:
        """tool0 in the root frame as last posed (4x4)."""
        out = np.eye(4)
        out[:3, :3] = self.data.xmat[self._tool].reshape(3, 3)
        out[:3, 3] = self.data.xpos[self._tool]
        return out

    def render(self, joints: Mapping[str, float], objects: Mapping[str, np.ndarray]
               ) -> np.ndarray:
        """The camera's picture (uint8 RGB) of the scene posed by :meth:`pose`."""
        self.pose(joints, objects)
        self._renderer.update_scene(self.data, camera=self._cam_id, scene_option=self._vopt)
        flags = self._renderer.scene.flags
        for flag in _OFF:
            flags[flag] = 0
        img = self._renderer.render()
        opts = self.options
        if opts.blur_sigma > 0.0:
            img = cv2.GaussianBlur(img, (0, 0), opts.blur_sigma)
        if opts.noise_sigma > 0.0:
            noisy = img + np.float32(opts.noise_sigma) * self._rng.standard_normal(
                img.shape, dtype=np.float32)
            img = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        return img
