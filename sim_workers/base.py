"""The physics half of a domain, as a base class: the protocol the worlds, the shards and
the coordinator speak (dm_control's ``Physics``/``Task`` split, Gymnasium's ``Env``).

A domain subclasses ``PhysicsDomain``, sets ``name`` and ``spec`` and implements the
abstract members; every other member has a default here, so the service calls each one
directly and never probes a domain with ``getattr``. ``required_members()`` lists the
abstract ones, and ``missing_members(cls)`` is the structural check ``tmoc
check-domain`` runs first (it names every missing member at once, before anything is
built).

``spec`` is the domain's options: a dataclass whose scalar fields are what ``--option``,
``options`` over HTTP and ``tmoc domains`` show. The defaults below read four of its
fields: ``n_blocks`` (the object count), ``true_size``, ``prior_low`` and ``prior_high``
(the default L: one size for every object), ``base_max_force`` (the palm's force limit
when a trajectory sets none) and ``settle_s`` (how long a world settles after a
trajectory); a domain overrides the member instead where its spec has no such field.
"""
from __future__ import annotations

import abc
import inspect
from typing import Any, ClassVar

import numpy as np

from .configuration import Configuration, Workspace
from .properties import PropertySpace
from .scene import SceneDescription

# The motion planner's bounds (x, y, z, yaw) when a domain declares none.
DEFAULT_WORKSPACE = Workspace(np.array([-0.5, -0.6, 0.0, -np.pi]), np.array([1.2, 0.6, 0.6, np.pi]))

# (old, new) names of protocol members renamed by issue 39: the core asks for the new ones.
_RENAMED = (("block_names", "learned_objects"), ("n_blocks", "n_objects"), ("max_blocks", "max_objects"))


class PhysicsDomain(abc.ABC):
    """Scene, Y, Y^-1, measurements and the prior over L of one domain (no planning here)."""

    name: ClassVar[str]
    spec: Any                                   # the options: a dataclass, see the module doc
    max_objects: ClassVar[int] = 16             # the object count's upper limit
    max_blocks: ClassVar[int] = 16              # (its old name)
    # Action kinds whose particle worlds leave out the bodies they cannot reach
    # (sim_workers/reach.py): only where measured to keep the outcomes.
    leave_out_actions: ClassVar[tuple[str, ...]] = ()
    # Whether the world records a sensor log (wrist force, opening) during an action; a
    # domain that reads none pays nothing.
    logs_sensors: ClassVar[bool] = False
    probe_actions: ClassVar[tuple[str, ...]] = ()   # what `tmoc probe` can try in this domain
    # Closed ranges of numeric options (spec fields) a run or request may set: a value
    # outside is refused naming ``options.KEY`` (issue 38: `force_sigma: 1e-300` passed and
    # every observation then failed; a time step of 1e-9 s would cost unbounded CPU).
    # Options not named here are checked for type and finiteness only.
    option_ranges: ClassVar[dict[str, tuple[float, float]]] = {}
    # Where an arm's base stands in this scene (x, y, z, yaw in the world frame, metres and
    # radians): a place from which it reaches every tool point the domain's trajectories use
    # at its default object count (issue 41; tests/sim_workers/test_robots.py checks it over
    # episodes). None: the robot's own base pose (the world origin).
    robot_base: ClassVar[tuple[float, float, float, float] | None] = None
    # The engine this domain's worlds are built in (``sim_workers.engines``): set by
    # ``sim_workers.domains.load(..., engine=)``; None is the default engine.
    engine: str | None = None

    # -- the objects and their unknown properties L -------------------------------------
    @property
    @abc.abstractmethod
    def object_names(self) -> list[str]:
        """Every movable object's name, in the order of ``Configuration.objects``."""

    @property
    def learned_objects(self) -> list[str]:
        """The objects that carry their own row of L with per-object unknowns (default:
        every object)."""
        return list(self.object_names)

    @property
    def n_objects(self) -> int:
        """How many objects with unknown properties the scene holds: the spec's count,
        its ``n_blocks`` field (the constructor option every domain and stored setting
        carries, so it keeps that name)."""
        return int(self.spec.n_blocks)

    # The protocol's names before issue 39, still answered; a domain written then
    # overrides them, and the new names follow its overrides (``__init_subclass__``).
    @property
    def block_names(self) -> list[str]:
        """Old name of ``learned_objects``."""
        return list(self.learned_objects)

    @property
    def n_blocks(self) -> int:
        """Old name of ``n_objects``."""
        return self.n_objects

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        for old, new in _RENAMED:          # whichever a class sets, the other follows
            if old in cls.__dict__ and new not in cls.__dict__:
                setattr(cls, new, cls.__dict__[old])
            elif new in cls.__dict__ and old not in cls.__dict__:
                setattr(cls, old, cls.__dict__[new])

    @property
    def L(self) -> PropertySpace:
        """The unknown properties (names, units, prior, default truth); default: one size."""
        sp = self.spec
        return PropertySpace(("size",), ("m",), (float(sp.prior_low),), (float(sp.prior_high),),
                             (float(sp.true_size),))

    @abc.abstractmethod
    def true_properties(self, sizes_variation: bool = False) -> dict:
        """The hidden truth as properties (``sizes_variation``: objects of unequal size)."""

    @abc.abstractmethod
    def properties(self, props: dict) -> dict:
        """`props` validated and completed (PropertyError naming the field); idempotent."""

    def object_sizes(self, props: dict) -> np.ndarray:
        """Each object's size under these properties (``block_names`` order), as the
        transit's collision model and the box of a held object take it; default: the
        block worlds' ``block_sizes``."""
        return np.asarray(props["block_sizes"], dtype=np.float64)

    def props_from_row(self, row: np.ndarray) -> dict:
        """A row of L (what the wire carries) as the properties a world is built from;
        default: one size for every object."""
        return {"block_sizes": np.broadcast_to(np.asarray(row, dtype=np.float64), (self.n_objects,))}

    # -- the scene --------------------------------------------------------------------
    @abc.abstractmethod
    def scene_description(self, props: dict) -> SceneDescription:
        """The scene for these properties as data (``sim_workers.scene``): bodies of boxes
        with mass, pose and friction, which of them are the objects, the gripper, the
        physics settings. An engine backend builds it (the engine seam)."""

    @property
    def base_max_force(self) -> float:
        """The palm's force limit (N) when a trajectory sets none (``spec.base_max_force``)."""
        return float(self.spec.base_max_force)

    @property
    def settle_s(self) -> float:
        """How long (s) the world may settle after a trajectory before it is observed
        (``spec.settle_s``; it stops earlier at rest)."""
        return float(self.spec.settle_s)

    @property
    def jittered_objects(self) -> tuple[int, ...]:
        """Rows of ``Configuration.objects`` the simulated reality places with jitter at the
        start of an episode (default: every object; a domain keeps a fixture still)."""
        return tuple(range(len(self.object_names)))

    @property
    def grasp_actions(self) -> tuple[str, ...]:
        """The action kinds that grasp an object (default: ``pickup``): the TOEP baseline
        draws its random grounding for these only, as the paper's TOEP randomises grasps."""
        return ("pickup",)

    @property
    def execution_jitter(self) -> dict[str, float]:
        """The simulated reality's relative timing jitter per action kind: a real arm runs
        that kind U(1 +- jitter) times faster or slower than commanded (default: none)."""
        return {}

    @abc.abstractmethod
    def initial_configuration(self, props: dict) -> Configuration:
        """Where everything starts, for objects of these properties."""

    @abc.abstractmethod
    def place(self, config: Configuration, props: dict) -> Configuration:
        """`config` made consistent with these properties (a particle's own sizes)."""

    def after_action(self, config: Configuration, action: str) -> Configuration:
        """What happens after `action` outside the robot (default: nothing; return `config`
        itself so that the world knows nothing moved)."""
        return config

    # -- Y^-1 and Y ----------------------------------------------------------------------
    @abc.abstractmethod
    def symbolic_state(self, config: Configuration) -> frozenset[str]:
        """Y^-1: the symbolic state of a configuration."""

    @abc.abstractmethod
    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray:
        """Y: the action's key pose for objects of these properties."""

    def action_poses(self, rows: np.ndarray, config: Configuration, action: str) -> np.ndarray:
        """Y for every row of L ((N, D) -> (N, ...)); default: one ``action_pose`` per row."""
        return np.array([self.action_pose(self.props_from_row(row), config, action)
                         for row in np.asarray(rows, dtype=np.float64)])

    def pose_classes(self, rows: np.ndarray, config: Configuration, action: str) -> np.ndarray:
        """The discrete choice Y makes for each row of L ((N, D) -> (N,) ints), so that the
        coordinator averages a pose within one class only; default: one class."""
        return np.zeros(len(rows), dtype=np.int64)

    def pose_alternatives(self, config: Configuration, action: str, pose: np.ndarray,
                          rows: np.ndarray) -> list[np.ndarray]:
        """Other poses Y could give `action` for the same objects (a cube's other grasp, a
        grasp side), for the particle worlds to judge: the coordinator tries each in every
        world of the belief (`rows`, (N, D)) when `pose` is not predicted to succeed in all
        of them, and takes the one predicted to succeed for most of the belief's weight
        (issue 40, "Y's alternatives"; docs/LOOP.md). The domain may leave out the ones
        that cannot differ (nothing within reach); default: none."""
        return []

    def take_first(self, config: Configuration) -> tuple[str, ...]:
        """Objects that rest on others in `config` (leaning on them, lying on them): a plan
        takes them before the rest, since the objects under them cannot be taken while they
        are there. The session hands them to the task half's planner as ``first``, so a
        domain that returns any has a planner that takes that keyword; default: none."""
        return ()

    def misalignment(self, config: Configuration, action: str) -> tuple[int, np.ndarray] | None:
        """Where an error in perception changes the action's outcome: the row of
        ``config.objects`` whose perceived planar position the action is aimed at, and the
        unit planar axis along which an error in it matters (a parallel gripper's closing
        axis), or None (default: no action is that sensitive). The filter integrates the
        particle worlds' outcomes over the perception error along that axis (issue 37;
        docs/LOOP.md, "Perception in the likelihood"); an error across it must not change
        the outcome."""
        return None

    def held_object(self, state: frozenset[str]) -> str | None:
        """The object in the hand in symbolic state `state` (None: the hand is empty); the
        transit's collision check carries its box. Default: none is ever held."""
        return None

    def check_action(self, action: str) -> None:
        """ValueError naming what is wrong if `action` is not one this scene can execute
        (default: no check; the service validates actions against the task half, and a
        domain calls this from its own Y where a bad argument must be named)."""
        return None

    # -- motion ----------------------------------------------------------------------------
    @abc.abstractmethod
    def pre_pose(self, config: Configuration, action: str, key: np.ndarray) -> np.ndarray:
        """Where the robot goes before the action's own motion (its transit's goal)."""

    @abc.abstractmethod
    def action_trajectory(self, config: Configuration, action: str, key: np.ndarray,
                          transit: np.ndarray | None = None) -> np.ndarray:
        """The commanded trajectory (time, target per row), after `transit` if given."""

    @abc.abstractmethod
    def transit_end_time(self, config: Configuration, action: str, key: np.ndarray,
                         transit: np.ndarray | None = None) -> float:
        """When the trajectory reaches the pre-pose (the particle worlds start there)."""

    @property
    def carry_height(self) -> float:
        """The tool point's height (m) for a transit over the scene: ``spec.carry_height``,
        else the gripper's build height in the scene description."""
        height = getattr(self.spec, "carry_height", None)
        if height is None:
            height = self.scene_description(self.properties(self.true_properties())).gripper.carry_height
        return float(height)

    def default_transit(self, start: np.ndarray, pre: np.ndarray) -> np.ndarray:
        """The path used when the motion planner finds none, and the first candidate it
        checks: (M, 5) waypoints up to the highest of ``carry_height`` and both ends,
        across, and down (default; every built-in domain and the chute use this one)."""
        z = max(self.carry_height, start[2], pre[2])
        return np.array([start, [*start[:2], z, *start[3:]], [*pre[:2], z, *pre[3:]], pre])

    def transit_candidates(self, robot: np.ndarray, pre: np.ndarray) -> list[tuple[str, np.ndarray]]:
        """Paths the motion planner tries before RRT*: (name, (M, >=4) waypoints) each."""
        return [("up_across_down", self.default_transit(robot, pre))]

    @abc.abstractmethod
    def obstacles(self, config: Configuration, size) -> list:
        """Boxes (centre, half extents[, rotation]) the transit must avoid, for believed
        sizes `size` (one for all, or one per object)."""

    @abc.abstractmethod
    def gripper_boxes(self, held_size: float = 0.0, opening: float | None = None) -> list:
        """(half extents, z offset above the fingertips) of the gripper's boxes."""

    @property
    def workspace(self) -> Workspace:
        """The motion planner's bounds."""
        return DEFAULT_WORKSPACE

    # -- measurements --------------------------------------------------------------------
    def senses(self, action: str) -> bool:
        """Whether `action` records the sensor log its measurements read (default:
        ``logs_sensors`` for every action)."""
        return self.logs_sensors

    @abc.abstractmethod
    def measurements(self, config: Configuration, log: Any = None, action: str = "") -> np.ndarray:
        """The measurement vector after `action` in `config` (`log`: the action's sensor
        log when ``senses(action)``, else None)."""

    @abc.abstractmethod
    def measurement_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(indices, std) of the measurements the belief's likelihood weighs."""

    def measurement_channels(self) -> list[dict]:
        """Every channel: name, index, unit and sigma (None: reported, not weighed), and
        ``sensed: True`` for a channel read from the action's sensor log (last in the
        vector; a robot that does not report it is not measured there); default: the
        weighed ones, named ``channel_<i>``."""
        idx, sigma = self.measurement_model()
        return [{"name": f"channel_{int(i)}", "index": int(i), "unit": "", "sigma": float(s)}
                for i, s in zip(idx, sigma)]

    # -- probes (`tmoc probe`, T*) --------------------------------------------------------
    def probe_trial(self, action: str, true_size: float, believed_size: float, load_k: int,
                    rng: np.random.Generator, **kwargs) -> bool:
        """One seeded trial of `action` in this world: whether it had its intended effect.

        A domain may instead declare it by L's names,
        ``probe_trial(self, action, load_k, rng, *, truth, belief)``: it then gets the truth
        and Y's belief as dicts with every property of L (``sim_workers.probe.by_name``)."""
        raise NotImplementedError(f"domain {self.name!r} has no probe trials")

    def probe_loads(self, action: str) -> range:
        """The loads a probe of `action` accepts (default 1..n_objects)."""
        return range(1, self.n_objects + 1)

    def t_star_probe_jobs(self, n_blocks: int) -> list[tuple[str, int]]:
        """(action, load) of every probe the T* estimate needs."""
        raise NotImplementedError(f"domain {self.name!r} has no T* probes")

    def t_star_from_probes(self, successes: dict, trials: int, n_blocks: int) -> dict:
        """T* in the planner's form from the probes' success counts."""
        raise NotImplementedError(f"domain {self.name!r} has no T* probes")

    # -- counterfactual experience (issue 40) ---------------------------------------------
    def counterfactual_jobs(self, n_blocks: int) -> list[tuple[str, int]]:
        """(probe action, load) of the contexts the planner may choose, simulated from the
        belief before planning (``coordinator.transition.counterfactual``); default: T*'s
        probes (``t_star_probe_jobs``); [] where the domain has none."""
        try:
            return list(self.t_star_probe_jobs(n_blocks))
        except NotImplementedError:
            return []

    def counterfactual_rates(self, successes: dict, trials: int, n_blocks: int) -> dict:
        """The counterfactual probes' success counts as T's success rates, in the planner's
        form (``{action: p}`` or ``{action: [p per context]}``); default: as T*
        (``t_star_from_probes``), since the jobs are T*'s."""
        return self.t_star_from_probes(successes, trials, n_blocks)


def required_members(base: type = PhysicsDomain) -> list[str]:
    """The members a domain must define: the base's declared class attributes without a
    default (such as ``name``), then its abstract methods and properties. (``spec`` is set
    per instance by ``__init__`` and checked once the domain is built.)"""
    declared = [n for n in base.__dict__.get("__annotations__", {}) if n != "spec" and not hasattr(base, n)]
    return declared + sorted(base.__abstractmethods__)


def optional_members(base: type = PhysicsDomain) -> list[str]:
    """The members `base` gives a default for (a domain overrides them where it needs to)."""
    required = set(required_members(base)) | {"spec"}
    return sorted(n for n in base.__dict__ if not n.startswith("_") and n not in required)


def missing_members(cls: type, base: type = PhysicsDomain) -> list[str]:
    """What class `cls` lacks of the protocol `base`, every member by name (empty:
    structurally complete); a class that does not subclass `base` says so first."""
    missing = [] if isinstance(cls, type) and issubclass(cls, base) else [f"(a subclass of {base.__name__})"]
    for member in required_members(base):
        attr = inspect.getattr_static(cls, member, None) if isinstance(cls, type) else None
        if attr is None or getattr(attr, "__isabstractmethod__", False):
            missing.append(member)
    return missing
