"""The robot declaration: base classes with defaults, and the registry by name.

A robot moves the tool point the domains plan for: the fingertip centre of a two-finger
gripper pointing down, at (x, y, z) with the fingers' yaw about the world's z axis. A
``FloatingGripper`` moves it directly. An ``Arm`` carries the gripper on its flange: its tool
pose is ``base @ forward(q) @ flange_to_tool``, and ``joints_for`` answers the inverse, the
branch nearest the current joints within the limits, or ``Unreachable`` by name.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from importlib.metadata import entry_points

import numpy as np

from .kinematics import DH, forward, inverse, nearest, rigid_inverse

__all__ = ["Arm", "FloatingGripper", "Joint", "Robot", "RobotError", "base_pose", "broken", "describe", "names",
           "register", "robot", "tool_pose"]

ENTRY_POINT_GROUP = "tmoc.robots"


class RobotError(ValueError):
    """An unknown robot name, or a declaration that is not a robot."""


@dataclass(frozen=True)
class Joint:
    """One joint: position range (rad or m), speed (per s) and acceleration (per s^2) limits;
    None where the maker publishes none."""

    name: str
    low: float
    high: float
    max_velocity: float | None = None
    max_acceleration: float | None = None


def tool_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """The 4 x 4 world pose of the tool point (x, y, z, yaw): the gripper pointing down
    (its z axis along the world's -z), its fingers closing along its x axis turned by `yaw`.

    >>> np.round(tool_pose(0.1, 0.2, 0.3, 0.0), 6).tolist()
    [[1.0, 0.0, 0.0, 0.1], [0.0, -1.0, 0.0, 0.2], [0.0, 0.0, -1.0, 0.3], [0.0, 0.0, 0.0, 1.0]]
    """
    c, s = math.cos(yaw), math.sin(yaw)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    t = np.eye(4)
    t[:3, :3] = rz @ np.diag([1.0, -1.0, -1.0])       # Rx(pi): the gripper points down
    t[:3, 3] = (x, y, z)
    return t


def base_pose(x: float, y: float, z: float, yaw: float) -> np.ndarray:
    """The 4 x 4 world pose of a base standing at (x, y, z), turned `yaw` about the world's z."""
    c, s = math.cos(yaw), math.sin(yaw)
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = (x, y, z)
    return t


class Robot:
    """A robot declaration. Subclasses set ``name``, ``description`` and ``joints``."""

    name: str = ""
    kind: str = ""
    description: str = ""
    joints: tuple[Joint, ...] = ()

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def low(self) -> np.ndarray:
        return np.array([j.low for j in self.joints])

    @property
    def high(self) -> np.ndarray:
        return np.array([j.high for j in self.joints])

    def joints_for(self, x: float, y: float, z: float, yaw: float, current=None) -> np.ndarray:
        """The robot's joints that put the tool point at (x, y, z, yaw), from `current`."""
        raise NotImplementedError

    def describe(self) -> dict:
        """What a client needs to check a trajectory with its own kinematics (JSON-ready)."""
        return {"name": self.name, "kind": self.kind, "description": self.description,
                "joints": [{"name": j.name, "low": j.low, "high": j.high, "max_velocity": j.max_velocity,
                            "max_acceleration": j.max_acceleration} for j in self.joints]}


class FloatingGripper(Robot):
    """The floating two-finger gripper: its joints are the tool point's coordinates."""

    name = "gripper"
    kind = "floating"
    description = "the service's floating two-finger gripper: the tool point (x, y, z, yaw) is commanded directly"
    joints = (Joint("x", -math.inf, math.inf), Joint("y", -math.inf, math.inf), Joint("z", -math.inf, math.inf),
              Joint("yaw", -math.inf, math.inf))

    def joints_for(self, x: float, y: float, z: float, yaw: float, current=None) -> np.ndarray:
        return np.array([x, y, z, yaw], dtype=np.float64)


class Arm(Robot):
    """A six-joint arm of the UR geometry with the gripper on its flange. Subclasses set
    ``dh``, ``joints``, ``flange_to_tool`` and ``base`` (4 x 4 world pose of the base frame)."""

    kind = "arm"
    dh: DH
    flange_to_tool: np.ndarray = np.eye(4)
    base: np.ndarray = np.eye(4)
    # Collision shapes of the links (``sim_workers.robots.collision.Capsule``), and the
    # joint acceleration a time parameterisation uses where the maker publishes none.
    links: tuple = ()
    acceleration: float = 1.4
    # Per joint frame 1-6, the link's mass (kg) and the joint's torque limit (N m), where the
    # maker publishes them: what a simulated arm's joint controller moves (``robots.servo``).
    link_masses: tuple = ()
    joint_torques: tuple = ()

    def placed(self, base: tuple[float, float, float, float] | None) -> "Arm":
        """This arm with its base at (x, y, z, yaw) in the world (a domain's ``robot_base``);
        itself where `base` is None."""
        if base is None:
            return self
        arm = copy.copy(self)
        arm.base = base_pose(*base)
        return arm

    def tool(self, q: np.ndarray) -> np.ndarray:
        """The tool's world pose (4 x 4) at joint angles `q`."""
        return self.base @ forward(self.dh, q) @ self.flange_to_tool

    def flange_target(self, tool: np.ndarray) -> np.ndarray:
        """The flange pose in the base frame that puts the tool at world pose `tool`."""
        return rigid_inverse(self.base) @ tool @ rigid_inverse(self.flange_to_tool)

    def branches(self, tool: np.ndarray, wrist_hint: float = 0.0) -> np.ndarray:
        """Every branch of the inverse for a world tool pose, (k, 6); ``Unreachable`` if none."""
        return inverse(self.dh, self.flange_target(tool), wrist_hint)

    def joints_for(self, x: float, y: float, z: float, yaw: float, current=None) -> np.ndarray:
        """The joints that put the tool point at (x, y, z, yaw): the branch nearest `current`
        (default: the arm's home) within the limits; ``Unreachable`` says why when none is."""
        current = self.home if current is None else np.asarray(current, dtype=np.float64)
        return nearest(self.branches(tool_pose(x, y, z, yaw), float(current[5])), current, self.low, self.high)

    @property
    def home(self) -> np.ndarray:
        return np.zeros(len(self.joints))

    def describe(self) -> dict:
        d = super().describe()
        d.update(dh={k: getattr(self.dh, k) for k in ("d1", "a2", "a3", "d4", "d5", "d6")},
                 dh_alpha=self.dh.alpha.tolist(), base=np.asarray(self.base).tolist(),
                 flange_to_tool=np.asarray(self.flange_to_tool).tolist(), home=self.home.tolist(),
                 links=[{"name": c.name, "frame": c.frame, "a": list(c.a), "b": list(c.b), "radius": c.radius}
                        for c in self.links],
                 trajectory_acceleration=self.acceleration, link_masses=list(self.link_masses),
                 joint_torques=list(self.joint_torques))
        return d


_REGISTRY: dict[str, Robot] = {}
_BROKEN: dict[str, str] = {}        # installed plugins left out, with why
_SEEN: set[str] = set()             # entry points already loaded (or left out)


def register(declaration: Robot | type[Robot]) -> Robot:
    """Add a robot (a ``Robot`` subclass or instance) under its ``name``; returns it."""
    bot = declaration() if isinstance(declaration, type) else declaration
    if not isinstance(bot, Robot) or not bot.name:
        raise RobotError(f"not a named Robot declaration: {declaration!r}")
    _REGISTRY[bot.name] = bot
    return bot


def _load_plugins() -> None:
    """Register the installed plugins' robots once each; one that does not load is left out
    and named by ``broken()`` (it must not hide the others)."""
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _SEEN:
            continue
        _SEEN.add(ep.name)
        try:
            register(ep.load())
        except Exception as exc:  # noqa: BLE001 - a broken plugin is reported, not raised
            _BROKEN[ep.name] = f"{type(exc).__name__}: {exc}"


def broken() -> dict[str, str]:
    """Installed robot plugins left out, with why."""
    _load_plugins()
    return dict(_BROKEN)


def names() -> list[str]:
    """Every registered robot's name: the built-ins, then the installed plugins'."""
    _load_plugins()
    return list(_REGISTRY)


def robot(name: str) -> Robot:
    """The robot registered as `name`; ``RobotError`` names the known ones otherwise."""
    if name not in _REGISTRY:
        _load_plugins()
    if name not in _REGISTRY:
        raise RobotError(f"unknown robot {name!r}; known: {', '.join(names())}")
    return _REGISTRY[name]


def describe(name: str) -> dict:
    return robot(name).describe()
