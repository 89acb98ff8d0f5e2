"""The browser viewer's 3-D scene on viser: robot, work cell, tool path, wrench (no ROS).

:class:`RobotScene` draws into a ``viser`` scene (``viser.ViserServer().scene``):

- the robot from the URDF that ``hyperarm_description`` generates (the one source of truth):
  pinocchio reads its links and visual primitives (boxes and cylinders with their material
  colours); each link is a scene node ``/robot/<link>`` posed in the root frame by forward
  kinematics of the joint state (:meth:`RobotScene.set_joints`), its visuals are children;
- the work cell: the table, pegs and poles of an optional :class:`WorldSpec`, and the
  objects the camera reports (:meth:`RobotScene.set_detections`, poses in ``camera_link``),
  shown as ``/objects/<name>``; an object not reported for ``object_max_age`` s is hidden;
- the tool path: the polyline ``/tool_path`` of the last ``path_length`` positions of tool0
  (a new point once tool0 moved at least ``path_min_step`` m);
- the wrench: the force at tool0 as the arrow ``/wrench`` (``wrench_scale`` m per N), from
  a force expressed in ``base_link`` (``ee_wrench_base``) or in the root frame.

Units: m, rad, N, s. Coordinates of the scene are the robot's root frame (``base_link`` for
``arm``, ``world`` for ``rail_arm``), z up. Bad input raises :class:`SceneInputError` and
leaves the scene as it was.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import pinocchio as pin

from hyperarm_description.contract import BASE_FRAME
from hyperarm_description.joints import JointStateCache, JointStateError
from hyperarm_description.model import RobotDescription
from hyperarm_description.urdf import generate_urdf
from hyperarm_description.world import WorldSpec

__all__ = ["ViewerError", "SceneInputError", "SceneConfig", "RobotScene", "wxyz_of",
           "frame_view", "project", "visible_box"]

ROBOT = "/robot"
OBJECTS = "/objects"
WORLD = "/workcell"
TOOL_PATH = "/tool_path"
WRENCH = "/wrench"

PATH_COLOR = (230, 120, 0)
WRENCH_COLOR = (220, 30, 30)
OBJECT_COLORS = {"block": (40, 110, 230), "peg": (40, 170, 70)}
OTHER_OBJECT_COLOR = (160, 60, 200)
TABLE_COLOR = (205, 185, 150)


# The first view (:func:`frame_view`): from the front right, above; a browser window of
# VIEW_SIZE px (half of a 1920 x 1200 screen: a browser beside a terminal) whose right
# PANEL_PX are covered by viser's control panel ("medium": 20 em of 16 px, floating 15 px
# from the edge), the scene kept MARGIN (normalised image coordinates, -1..1) off the edges.
# A wider window only adds room on the left.
VIEW_DIRECTION = (-0.2, 0.85, -0.5)     # camera to target, any length (root frame)
VIEW_FOV = math.radians(75.0)           # viser's default vertical field of view
VIEW_SIZE = (960, 600)                  # px, width x height
PANEL_PX = 335
MARGIN = 0.15
APPROACH = 0.10     # m above each peg's top: where the tool comes and goes (also framed)


def _camera_axes(direction: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, right, up) unit vectors of a camera looking along ``direction``, z up."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    r = np.cross(d, (0.0, 0.0, 1.0))
    r = r / np.linalg.norm(r)
    return d, r, np.cross(r, d)


def project(points: np.ndarray, position: Sequence[float], look_at: Sequence[float],
            fov_y: float = VIEW_FOV, size: tuple[int, int] = VIEW_SIZE) -> np.ndarray:
    """(N, 2) normalised image coordinates (x right, y up; -1..1 is the window) of
    ``points`` (N, 3; m) seen by a pinhole camera at ``position`` looking at ``look_at``
    (z up) with vertical field of view ``fov_y`` (rad) in a window of ``size`` px;
    points behind the camera come out as inf."""
    pos = np.asarray(position, dtype=float)
    d, r, u = _camera_axes(np.asarray(look_at, dtype=float) - pos)
    rel = np.asarray(points, dtype=float).reshape(-1, 3) - pos
    z = rel @ d
    ky = math.tan(fov_y / 2)
    kx = ky * size[0] / size[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.stack([(rel @ r) / (z * kx), (rel @ u) / (z * ky)], axis=1)
    out[z <= 1e-6] = np.inf
    return out


def visible_box(size: tuple[int, int] = VIEW_SIZE, panel_px: int = PANEL_PX,
                margin: float = MARGIN) -> tuple[float, float, float, float]:
    """(x_lo, x_hi, y_lo, y_hi) in normalised image coordinates: the part of the window
    the control panel does not cover, less ``margin``."""
    x_hi = 1.0 - 2.0 * panel_px / size[0]
    return -1.0 + margin, x_hi - margin, -1.0 + margin, 1.0 - margin


def frame_view(points: np.ndarray, direction: Sequence[float] = VIEW_DIRECTION,
               fov_y: float = VIEW_FOV, size: tuple[int, int] = VIEW_SIZE,
               panel_px: int = PANEL_PX, margin: float = MARGIN
               ) -> tuple[np.ndarray, np.ndarray]:
    """(position, look_at) of the nearest camera looking along ``direction`` that shows
    every one of ``points`` (N, 3; m) in :func:`visible_box` (left of the control panel).

    Along the view axis the distance is bisected; across it the camera slides so that the
    points' extremes sit inside the box (each axis is a pair of linear bounds on the
    shift, since the depth of a point does not change with a sideways shift)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if pts.size == 0 or not np.isfinite(pts).all():
        raise ViewerError("frame_view: need one or more finite points")
    d, r, u = _camera_axes(direction)
    centre = (pts.min(axis=0) + pts.max(axis=0)) / 2
    rel = pts - centre
    a, b, depth = rel @ r, rel @ u, rel @ d
    ky = math.tan(fov_y / 2)
    kx = ky * size[0] / size[1]
    x_lo, x_hi, y_lo, y_hi = visible_box(size, panel_px, margin)

    def shifts(dist: float) -> tuple[float, float] | None:
        z = depth + dist
        if (z <= 1e-3).any():
            return None
        s_lo, s_hi = np.max(a - x_hi * z * kx), np.min(a - x_lo * z * kx)
        t_lo, t_hi = np.max(b - y_hi * z * ky), np.min(b - y_lo * z * ky)
        if s_lo > s_hi or t_lo > t_hi:
            return None
        return (s_lo + s_hi) / 2, (t_lo + t_hi) / 2

    lo, hi = 0.0, 1.0
    while shifts(hi) is None:
        lo, hi = hi, hi * 2
        if hi > 1e6:
            raise ViewerError("frame_view: no camera distance shows every point")
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if shifts(mid) is not None else (mid, hi)
    s, t = shifts(hi)
    position = centre - hi * d + s * r + t * u
    return position, position + hi * d


class ViewerError(Exception):
    """Root of the viewer's errors."""


class SceneInputError(ViewerError):
    """A joint state, detection or wrench given to the scene is malformed."""


@dataclass(frozen=True)
class SceneConfig:
    """``path_length``: tool positions kept; ``path_min_step`` (m): distance tool0 moves
    before a new path point; ``wrench_scale`` (m/N): arrow length per newton;
    ``object_size`` (m): cube side of a detected object the work cell gives no size for;
    ``object_max_age`` (s): an object not reported for that long is hidden."""

    path_length: int = 500
    path_min_step: float = 0.002
    wrench_scale: float = 0.02
    object_size: float = 0.03
    object_max_age: float = 1.0

    def __post_init__(self) -> None:
        if not (isinstance(self.path_length, int) and self.path_length >= 2):
            raise ViewerError(f"path_length must be an integer >= 2, got {self.path_length!r}")
        for name in ("path_min_step", "wrench_scale", "object_size", "object_max_age"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ViewerError(f"{name} must be a positive number, got {value!r}")


def wxyz_of(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a 3x3 rotation matrix (viser's convention)."""
    q = pin.Quaternion(np.asarray(rotation, dtype=float))
    q.normalize()
    return np.array([q.w, q.x, q.y, q.z])


def _finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


def _finite_vector(values: Sequence[float], n: int, what: str) -> np.ndarray:
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise SceneInputError(f"{what}: expected {n} finite numbers, got {list(values)!r}")
    return v


class RobotScene:
    """The viewer's scene in ``scene`` (a ``viser.SceneApi``), for the robot ``desc`` and
    the optional work cell ``world``; see the module docstring."""

    def __init__(self, scene: Any, desc: RobotDescription, world: WorldSpec | None = None,
                 config: SceneConfig | None = None) -> None:
        self.scene = scene
        self.desc = desc
        self.config = config if config is not None else SceneConfig()
        urdf = generate_urdf(desc)
        self.model = pin.buildModelFromXML(urdf)
        self.data = self.model.createData()
        geoms = pin.buildGeomFromUrdfString(self.model, urdf, pin.VISUAL)
        self.joint_names = [self.model.names[i] for i in range(1, self.model.njoints)]
        self._q = pin.neutral(self.model)
        self._cache = JointStateCache()
        self._tool_id = self.model.getFrameId(desc.tool_frame)
        self._root = desc.root_frame
        self._frames = {f.name: i for i, f in enumerate(self.model.frames)
                        if f.type == pin.FrameType.BODY}
        camera = np.eye(4)
        camera[:3, :3] = pin.rpy.rpyToMatrix(*[float(a) for a in desc.camera.rpy])
        camera[:3, 3] = desc.camera.xyz
        self.camera_pose = camera
        self._world = world
        self._path: deque[np.ndarray] = deque(maxlen=self.config.path_length)
        self._objects: dict[str, tuple[Any, float]] = {}
        self.wrench_force: np.ndarray | None = None  # N, root frame, of the drawn arrow

        pin.forwardKinematics(self.model, self.data, self._q)
        pin.updateFramePlacements(self.model, self.data)
        self.links: dict[str, Any] = {}
        for name, fid in self._frames.items():
            if name == desc.root_frame or any(go.parentFrame == fid
                                              for go in geoms.geometryObjects):
                self.links[name] = scene.add_frame(f"{ROBOT}/{name}", show_axes=False)
        for go in geoms.geometryObjects:
            link = self.model.frames[go.parentFrame].name
            local = self.data.oMf[go.parentFrame].actInv(
                self.data.oMi[go.parentJoint].act(go.placement))
            self._add_primitive(f"{ROBOT}/{link}/{go.name}", go.geometry, go.meshColor, local)
        self._update_links()
        if world is not None:
            self._add_world(world)

    # -- set-up ------------------------------------------------------------------------
    def _add_primitive(self, name: str, geometry: Any, rgba: np.ndarray, pose: pin.SE3
                       ) -> None:
        color = tuple(int(round(255 * float(c))) for c in rgba[:3])
        kw = dict(color=color, position=pose.translation.copy(), wxyz=wxyz_of(pose.rotation))
        kind = type(geometry).__name__
        if kind == "Box":
            self.scene.add_box(name, dimensions=tuple(2.0 * geometry.halfSide), **kw)
        elif kind == "Cylinder":
            self.scene.add_cylinder(name, radius=float(geometry.radius),
                                    height=2.0 * float(geometry.halfLength), **kw)
        elif kind == "Sphere":
            self.scene.add_icosphere(name, radius=float(geometry.radius), **kw)
        else:  # the generator writes only primitives; a mesh would need its file
            raise ViewerError(f"{name}: visual geometry {kind} is not supported")

    def _add_world(self, world: WorldSpec) -> None:
        t = world.table
        if all(math.isfinite(v) for v in (*t.x_range, *t.y_range)):
            size = (t.x_range[1] - t.x_range[0], t.y_range[1] - t.y_range[0], 0.01)
            centre = (sum(t.x_range) / 2, sum(t.y_range) / 2, t.height - 0.005)
            self.scene.add_box(f"{WORLD}/table", dimensions=size, color=TABLE_COLOR,
                               position=centre, opacity=0.6)
        else:
            self.scene.add_grid(f"{WORLD}/table", width=2.0, height=2.0,
                                position=(0.0, 0.0, t.height))
        for peg in world.pegs:
            self.scene.add_cylinder(f"{WORLD}/pegs/{peg.name}", radius=peg.radius,
                                    height=peg.height, color=OBJECT_COLORS["peg"],
                                    position=(*peg.xy, t.height + peg.height / 2))
        for pole in world.poles:
            self.scene.add_cylinder(f"{WORLD}/poles/{pole.name}", radius=pole.radius,
                                    height=pole.height, color=(120, 120, 120),
                                    position=(*pole.xy, (pole.z_min + pole.z_max) / 2))

    def view_points(self) -> np.ndarray:
        """(N, 3) points the first view must show (m, root frame): every link's origin at
        the drawn joint positions, tool0, the front half of a ring of the arm's reach around
        its base, and the work cell's pegs (foot, top and APPROACH
        above it), poles and the corners of a bounded table."""
        pts = [self.data.oMf[self._frames[n]].translation for n in self.links]
        pts.append(self.tool_position())
        # where the arm can swing: a ring of its reach at rest around its base, level with it
        base = self.data.oMf[self._frames[BASE_FRAME]].translation
        reach = float(np.linalg.norm(self.tool_position() - base))
        pts += [base + reach * np.array([math.cos(a), math.sin(a), 0.0])
                for a in np.linspace(-math.pi / 2, math.pi / 2, 7)]
        w = self._world
        if w is not None:
            t = w.table
            for peg in w.pegs:
                top = t.height + peg.height
                pts += [(*peg.xy, t.height), (*peg.xy, top), (*peg.xy, top + APPROACH)]
            for pole in w.poles:
                pts += [(*pole.xy, pole.z_min), (*pole.xy, pole.z_max)]
            if all(math.isfinite(v) for v in (*t.x_range, *t.y_range)):
                pts += [(x, y, t.height) for x in t.x_range for y in t.y_range]
        return np.array(pts, dtype=float).reshape(-1, 3)

    # -- joint state -------------------------------------------------------------------
    def set_joints(self, names: Sequence[str], positions: Sequence[float]) -> None:
        """Merge a joint state (rad, m; joints by name, e.g. only the rail's) and re-pose
        the robot. Names the robot does not have are ignored (another robot's joints on
        the same topic); a message with a non-finite value is rejected whole."""
        names = list(names)
        positions = list(positions)
        if len(names) != len(positions):
            raise SceneInputError(f"joint state: {len(names)} names but {len(positions)} "
                                  "positions")
        if len(set(names)) != len(names):
            raise SceneInputError(f"joint state: a joint named twice in {names}")
        bad = [n for n, p in zip(names, positions) if not _finite(p)]
        if bad:
            raise SceneInputError(f"joint state: non-finite position of {', '.join(bad)}")
        mine = [(n, p) for n, p in zip(names, positions) if n in self.joint_names]
        try:
            self._cache.update([n for n, _ in mine], [p for _, p in mine])
        except JointStateError as exc:
            raise SceneInputError(f"joint state: {exc}") from None
        seen = [n for n in self.joint_names if self._cache.has([n])]
        for n, v in zip(seen, self._cache.positions(seen)):
            self._q[self.joint_names.index(n)] = v
        self._update_links()
        tool = self.tool_position()
        if not self._path or np.linalg.norm(tool - self._path[-1]) >= self.config.path_min_step:
            self._path.append(tool)
            self._draw_path()

    def _update_links(self) -> None:
        pin.forwardKinematics(self.model, self.data, self._q)
        pin.updateFramePlacements(self.model, self.data)
        for name, handle in self.links.items():
            m = self.data.oMf[self._frames[name]]
            handle.position = m.translation.copy()
            handle.wxyz = wxyz_of(m.rotation)

    def joint_positions(self) -> dict[str, float]:
        """The joint positions the robot is drawn at (rad, m)."""
        return dict(zip(self.joint_names, (float(v) for v in self._q)))

    def frame_pose(self, frame: str) -> np.ndarray:
        """4x4 pose (root frame) of a robot frame at the drawn joint positions."""
        return self.data.oMf[self.model.getFrameId(frame)].homogeneous.copy()

    def tool_position(self) -> np.ndarray:
        """Position of tool0 (m, root frame) at the drawn joint positions."""
        return self.data.oMf[self._tool_id].translation.copy()

    @property
    def tool_path(self) -> np.ndarray:
        """(N, 3) recent tool0 positions, oldest first (m, root frame)."""
        return np.array(self._path).reshape(-1, 3)

    def _draw_path(self) -> None:
        if len(self._path) < 2:
            return
        pts = np.array(self._path)
        self.scene.add_line_segments(TOOL_PATH, np.stack([pts[:-1], pts[1:]], axis=1),
                                     PATH_COLOR, thickness=3.0, thickness_units="screen")

    def clear_path(self) -> None:
        """Forget the tool path (the next joint state starts a new one)."""
        self._path.clear()
        self.scene.add_line_segments(TOOL_PATH, np.zeros((0, 2, 3)), PATH_COLOR)

    # -- work-cell objects -------------------------------------------------------------
    def set_detections(self, frame_id: str, names: Sequence[str],
                       poses: Sequence[np.ndarray], now: float) -> None:
        """Show the objects of one detections message: ``poses`` (4x4) in ``frame_id`` (the
        camera frame or the root frame), received at ``now`` (s, any monotonic clock).
        Objects not reported for ``object_max_age`` are hidden by :meth:`expire`."""
        if frame_id == self.desc.camera.frame:
            base = self.camera_pose
        elif frame_id == self._root:
            base = np.eye(4)
        else:
            raise SceneInputError(f"detections in frame {frame_id!r}: expected "
                                  f"{self.desc.camera.frame!r} or {self._root!r}")
        if len(names) != len(poses):
            raise SceneInputError(f"detections: {len(names)} names but {len(poses)} poses")
        world = []
        for name, pose in zip(names, poses):
            p = np.asarray(pose, dtype=float)
            if (p.shape != (4, 4) or not np.all(np.isfinite(p)) or not name
                    or not np.allclose(p[:3, :3].T @ p[:3, :3], np.eye(3), atol=1e-3)):
                raise SceneInputError(f"detection {name!r}: not a finite rigid 4x4 pose "
                                      "(unit quaternion)")
            world.append(base @ p)
        for name, pose in zip(names, world):
            handle = self._objects.get(name, (None, 0.0))[0] or self._add_object(name)
            handle.position = pose[:3, 3].copy()
            handle.wxyz = wxyz_of(pose[:3, :3])
            handle.visible = True
            self._objects[name] = (handle, now)
        self.expire(now)

    def _add_object(self, name: str) -> Any:
        node = f"{OBJECTS}/{name}"
        w = self._world
        if name == "block":
            size = (w.block.size if w is not None and w.block is not None
                    else (self.config.object_size,) * 3)
            return self.scene.add_box(node, dimensions=tuple(size),
                                      color=OBJECT_COLORS["block"])
        if name.endswith("_peg"):  # the mock reports each peg's top
            return self.scene.add_icosphere(node, radius=0.01, color=OBJECT_COLORS["peg"])
        return self.scene.add_box(node, dimensions=(self.config.object_size,) * 3,
                                  color=OTHER_OBJECT_COLOR)

    def expire(self, now: float) -> None:
        """Hide the objects last reported more than ``object_max_age`` s before ``now``."""
        for handle, seen in self._objects.values():
            if now - seen > self.config.object_max_age:
                handle.visible = False

    def visible_objects(self) -> dict[str, np.ndarray]:
        """Name -> position (m, root frame) of each object shown now."""
        return {n: np.asarray(h.position, dtype=float)
                for n, (h, _) in self._objects.items() if h.visible}

    # -- wrench ------------------------------------------------------------------------
    def set_wrench(self, frame_id: str, force: Sequence[float]) -> None:
        """Draw the force (N) acting at tool0, expressed in ``frame_id`` (``base_link``, the
        root frame or ``tool0``), as an arrow from tool0."""
        f = _finite_vector(force, 3, "wrench force")
        if frame_id not in (self._root, BASE_FRAME, self.desc.tool_frame):
            raise SceneInputError(f"wrench in frame {frame_id!r}: expected base_link, "
                                  f"{self._root!r} or {self.desc.tool_frame!r}")
        rot = self.frame_pose(frame_id)[:3, :3] if frame_id != self._root else np.eye(3)
        f_root = rot @ f
        start = self.tool_position()
        end = start + self.config.wrench_scale * f_root
        self.wrench_force = f_root
        self.scene.add_arrows(WRENCH, np.array([[start, end]]), WRENCH_COLOR,
                              shaft_radius=0.004, head_radius=0.01, head_length=0.02)
