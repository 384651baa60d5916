"""A task's settings as one validated, JSON-able record (pydantic)."""
from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, AliasChoices, BaseModel, ConfigDict, Field, PrivateAttr, model_validator

from planner.blocks.model import DEFAULT_COSTS
from sim_workers.domains import DEFAULT_DOMAIN, Scene
from sim_workers.engines.registry import BATCH_ENGINES, ENGINES

from .agents import AGENTS

# One place for each fact: the agent names are the registry's (coordinator.agents), the
# default utility terms the task model's (planner.blocks.model.DEFAULT_COSTS).
AgentName = Literal[tuple(AGENTS)]  # type: ignore[valid-type]
# The engines are the registry's (sim_workers.engines.registry: ENGINES, and the batch
# engines that step a shard's particles at once, an optional extra).
EngineName = Literal[ENGINES + BATCH_ENGINES]  # type: ignore[valid-type]


def _registered_domain(name: str) -> str:
    """A domain the registry knows (built-in or installed plugin), by its name: ``name-vN``
    is accepted when N is the installed version."""
    from coordinator.domains import names
    from sim_workers.domains import canonical_name

    try:
        return canonical_name(name)
    except ValueError as exc:
        if "is not installed" in str(exc):
            raise ValueError(str(exc).removeprefix("domain: ")) from None
        raise ValueError(f"unknown domain {name!r} (known: {', '.join(names())})") from None


DomainName = Annotated[str, AfterValidator(_registered_domain)]


class Costs(BaseModel):
    """Utility terms: action costs, the failure penalty and reward terms. The fields are
    the container's (and stack-and-push's); a plugin domain's own terms are extra fields,
    checked against its utility terms by RunConfig."""

    model_config = ConfigDict(extra="allow")
    pickup: float = Field(DEFAULT_COSTS["pickup"], ge=0, le=1e4)
    stack: float = Field(DEFAULT_COSTS["stack"], ge=0, le=1e4)
    push: float = Field(DEFAULT_COSTS["push"], ge=0, le=1e4)
    fail: float = Field(DEFAULT_COSTS["fail"], ge=0, le=1e4)
    deliver: float = Field(DEFAULT_COSTS["deliver"], ge=0, le=1e4)
    all_delivered: float = Field(DEFAULT_COSTS["all_delivered"], ge=0, le=1e4)


def one_object_count(data):
    """A settings mapping with the object count under one name: ``n_objects`` and its old
    name ``n_blocks`` both given must agree (ValueError naming n_objects otherwise)."""
    if isinstance(data, dict) and "n_objects" in data and "n_blocks" in data:
        if data["n_objects"] != data["n_blocks"]:
            raise ValueError(f"n_objects: {data['n_objects']!r} disagrees with n_blocks "
                             f"{data['n_blocks']!r} (one name for the object count is enough)")
        data = {k: v for k, v in data.items() if k != "n_blocks"}
    return data


class RunConfig(BaseModel):
    """Everything that determines a run; with the same values a run is reproducible."""

    model_config = ConfigDict(extra="forbid")

    @model_validator(mode="before")
    @classmethod
    def _one_object_count(cls, data):
        return one_object_count(data)

    domain: DomainName = DEFAULT_DOMAIN
    agent: AgentName = "tmoc"
    particles: int = Field(32, ge=1, le=5000)
    # The particle budget (issue 15): "fixed" keeps `particles`; "kld" chooses the count for
    # each action by KLD-sampling (coordinator/particle_filter/particle_budget.py) between min_particles
    # (at most `particles`) and `particles`, with bins of kld_bin x each prior's width.
    # epsilon 0.2, not localisation's 0.05: at 0.05 a converged posterior straddling two
    # bins asks for 66 particles, more than the default 32; at 0.2 (17 for 2 bins) the
    # container at N <= 32 keeps utility and posterior (33.92 +- 0.31 mm against 33.92 +-
    # 0.26 fixed) with 8 particles per action from episode 3 (measured, seed 0).
    # The default is kld (benchmarks/bench_budget.py: the same final utility on the container
    # and on stack-and-push with L = (size, density), 17 % of fixed's particle-actions at
    # P 100). Stored settings from before the field keep "fixed" (stored_run_config).
    particle_budget: Literal["fixed", "kld"] = "kld"
    min_particles: int = Field(8, ge=1, le=5000)
    kld_epsilon: float = Field(0.2, gt=0, le=1)
    kld_quantile: float = Field(0.99, gt=0.5, lt=1)
    kld_bin: float = Field(0.1, ge=0.001, le=1)
    episodes: int = Field(8, ge=1, le=100000)
    seed: int = Field(0, ge=0, le=2**63 - 1)
    # The object count (issue 39): unset, the domain's own (its physics spec's n_blocks;
    # 8 for the built-in block worlds); `n_objects` is the domain-neutral spelling.
    n_blocks: int | None = Field(None, ge=1, le=16, validation_alias=AliasChoices("n_blocks", "n_objects"))
    true_size: float = Field(0.045, ge=0.02, le=0.08)
    sizes_variation: bool = False
    # The paper's real-robot run "with the sizes given": the belief is a point mass at the
    # true properties (Y grounded at the truth), so only T is learned. Simulated tasks only.
    known_properties: bool = False
    likelihood: Literal["replay", "paper"] = "replay"
    max_steps: int = Field(60, ge=1, le=1000)
    error_rate: float = Field(0.05, gt=0, lt=0.5)
    use_measurements: bool = True
    match: Literal["success", "state"] = "success"
    # The real pose x from the particles' x_i: "mode" averages over the heaviest mode of the
    # belief (bandwidth in metres of L); "mean" is the paper's weighted mean over all;
    # "success" (issue 37) takes, of the heaviest mode's pose, every other mode's and the
    # mean's, the one the particle worlds predict succeeds for most of the belief's weight
    # (the heaviest mode's on a tie; only a multimodal belief pays the extra simulations).
    pose_rule: Literal["success", "mode", "mean"] = "success"
    mode_bandwidth: float = Field(0.003, gt=0, le=0.1)
    # Resampling jitter: std = max(jitter * posterior std, jitter_floor * prior width).
    # The floor only keeps copies distinct when the posterior has collapsed onto one value:
    # 0.1 % of the prior's width (0.03 mm of size), below any posterior std the channels can
    # reach (docs/LOOP.md, "Constants"); calibration comes from the kernel and the likelihood.
    # (Before issue 37: 2 %, which is what calibrated the posterior; stored settings keep it.)
    jitter: float = Field(0.1, ge=0, le=1)
    jitter_floor: float = Field(0.001, ge=0, le=0.5)
    # The filter against model error and lock-in (issue 24; coordinator/particle_filter/reweighting.py). Each
    # weighed channel's likelihood is (1 - outlier_rate) N(y; f(L_i), sigma) + outlier_rate x a
    # floor 50 sensor sigmas wide, so a reading no particle explains moves no weight (0: the
    # plain Gaussian). model_error "online" widens sigma by the scatter of the belief's
    # innovations (sqrt(sensor^2 + model^2)). resample_kernel "rpf" moves every resampled
    # particle by the Musso-Oudjane-Le Gland bandwidth (0.63 posterior stds at 16 particles
    # and 2 properties) instead of the extra copies by the fixed `jitter`. lock_in redraws
    # particles (per block with the sizes variation) from the prior when no particle explains
    # an observation, at the rate 1 - w_fast / w_slow of augmented MCL (averages with these
    # rates). Stored settings from before these fields keep 0, "none", 0, "jitter", false and
    # false (stored_run_config).
    outlier_rate: float = Field(0.05, ge=0, lt=0.5)
    # "centered" (issue 37): the scatter of the innovations about their median, over a short
    # memory, so that a belief's own bias is not read as model error; "online": the raw
    # innovations (issue 24); "none": the sensor's sigma alone.
    model_error: Literal["centered", "online", "none"] = "centered"
    # An update keeps at least this share of the effective sample size (a sharper one is
    # scaled down: a power likelihood, not SMC tempering, which would carry the rest of the
    # likelihood); 0 (issue 37's default): the whole likelihood, every update.
    ess_keep: float = Field(0.0, ge=0, lt=1)
    # "liu_west" (issue 37): the Musso bandwidth with Liu and West's shrinkage towards the
    # mean, so resampling keeps the posterior's mean and variance; "rpf": the same kernel
    # without shrinkage (variance x (1 + h^2) per resample); "jitter": the fixed jitter.
    resample_kernel: Literal["liu_west", "rpf", "jitter"] = "liu_west"
    # The kernel's bandwidth h = (4 / (count (d + 2)))^(1 / (d + 4)): "n" the particle count
    # (every run so far), "ess" the effective sample size of the weights being resampled, the
    # count of points a weighted set holds (wider when few rows survive). Measured, "ess"
    # removes the coverage grid's density collapse and keeps 80 openings calibrated
    # (docs/LOOP.md); stored configs without the field keep "n".
    kernel_bandwidth: Literal["n", "ess"] = "ess"
    # With the sizes variation (one entry of L per block): weights per block, an action's
    # update going to the block it names (coordinator/particle_filter/block_weights.py); with "rpf" only
    # (the fixed jitter keeps one weight per particle: a schema-valid request is never
    # refused for the pair, issue 25's schemathesis run).
    block_weights: bool = True
    lock_in: bool = True
    # What the lock-in monitor does when it fires: "mh_move" (issue 37) a resample-move, each
    # row proposed from a mixture of the prior and a local random walk and accepted by
    # Metropolis-Hastings against the likelihood of the last real steps re-simulated;
    # "prior": rows redrawn from the prior at uniform weight (issue 24).
    recovery: Literal["mh_move", "prior"] = "mh_move"
    # The move's Metropolis-Hastings sweeps while its window holds every real step since the
    # prior (the run's first MOVE_WINDOW steps), where its target is the exact posterior:
    # one sweep left the large end's first grasps failing six times in a row (docs/LOOP.md,
    # "The first window's move"). Past that window the move takes one. 8 is
    # resample_move.MAX_SWEEPS, swept for this move too. Stored configs without the field
    # keep 1. At most 32: a move then re-simulates at most 32 x N x MOVE_WINDOW rows.
    first_window_sweeps: int = Field(8, ge=1, le=32)
    # The readings of a world whose symbolic outcome did not match reality's: "departure"
    # scores them flat over each channel's outlier width, the readings' density when
    # reality departs from the world's outcome (coordinator/particle_filter/likelihood.py,
    # readings_given_outcome; docs/LOOP.md); "own" against the world's own prediction of
    # the other regime, which charged the departure a second time (about x7000 for the
    # container's opening where error_rate says x19: a 57.9 mm belief collapsed to 56.4 +-
    # 0.05 mm on one rail pickup); "profile" as an exact prediction, which rated a wrong
    # world above every matched one 2.4 sigma off (the slide example then learned a
    # friction of 0.51 for 0.2). "own" stays the default until "departure" holds on every
    # domain (docs/LOOP.md). Stored configs without the field keep "own".
    disagreement_readings: Literal["departure", "profile", "own"] = "own"
    # The target of the recovery's move ("mh_move") past the run's first window: "prior",
    # the uniform prior times the window's likelihood, which forgets every step before the
    # window (with the window emptied at each episode's start, a slide belief of 0.200 +-
    # 0.003 under the "departure" readings was moved back to 0.25 +- 0.11 by two steps);
    # "belief", the belief before the window's first step (as the kernel density the
    # resampler draws from) times the window's likelihood, the posterior, but anchored on a
    # belief the monitor fired because it explained the window badly (one of the 30
    # calibration runs at 8 particles ended at z 7.8). docs/LOOP.md, "The move's target
    # past the first window".
    move_target: Literal["belief", "prior"] = "prior"
    # With recovery "mh_move": the move also when every row has mispredicted the outcome of
    # a step some row predicted, since the rows were last renewed (within the episode): each
    # step explained by some hypothesis and the sequence by none, the truth between the
    # rows (the seed-91 grasp cycle: docs/LOOP.md). Stored configs without the field: off.
    mismatch_move: bool = False
    # After every resample, and after a step no row explained, Gilks and Berzuini's
    # resample-move (issue 37): MAX_SWEEPS Metropolis-Hastings sweeps over the rows against
    # the belief before the step (its kernel density) times the step's likelihood, for a
    # step sharper than the particles' spacing (docs/LOOP.md, "Resample-move after a sharp
    # step"). Off by default: it fixes a collapse a resample leaves (a density 2657 +- 86
    # kg/m^3 for 2200 through a 3.5 N wrist, z 5.3) and the slide at 16 particles, but on
    # by default it made 80 plain openings over-confident (mean z^2 6-13 over 30 truths).
    move_after_resample: bool = False
    # Disjoint ranges keep the long-term average the slower one for any pair the schema
    # allows (a cross-field check would refuse schema-valid requests).
    lock_in_slow: float = Field(0.05, gt=0, lt=0.2)
    lock_in_fast: float = Field(0.3, ge=0.2, le=1)
    sim_weight: float = Field(1.0, ge=0, le=100)
    # How simulated outcomes enter T where reality disagrees (issue 24): "power_prior"
    # discounts each context's simulated counts by how well they predict its real outcomes
    # (coordinator.transition.transition_model.sim_discount); "none" counts them at sim_weight always
    # (every run before the field; stored settings without it keep it).
    sim_discount: Literal["power_prior", "none"] = "power_prior"
    # Counterfactual simulated experience (issue 40; coordinator.transition.counterfactual):
    # before each episode's first plan, this many rows of L drawn from the belief each run
    # one trial of every context the domain declares, and T takes the outcomes as
    # simulated evidence (a power prior per action family). 4 (docs/LOOP.md: measured to
    # pay in every built-in domain); 0: off, the paper's loop (stored settings without the
    # field keep it).
    counterfactual_rows: int = Field(4, ge=0, le=256)
    # A reality gap the particle worlds do not know, for simulated realities: "ACTION:K"
    # makes every ACTION in a T context >= K fail in reality only (coordinator.loop.reality.
    # ContextFailure), e.g. "stack:3" (stacks onto 3 or more blocks). None: no such gap.
    # Simulated realities only: a robot session has no such field.
    reality_fail: str | None = Field(None, max_length=64)
    # The physics engines (issue 27; sim_workers/engines): the particle worlds' and the
    # simulated reality's. None is the default engine (pybullet where it is installed, else
    # MuJoCo); the two differ for a run whose simulator is not its reality.
    engine: EngineName | None = None
    reality_engine: EngineName | None = None
    # The robot that moves the tool (issue 41; `tmoc robots`): "gripper", the floating
    # two-finger gripper, or an arm ("ur5e"), which gets a joint trajectory per step.
    robot: str = Field("gripper", min_length=1, max_length=64)
    # The simulated reality's sensors (issue 37; sim_workers.reality_gap.SensorNoise): what
    # it reports is noisy, the world goes on from the truth. Simulated realities only (a
    # robot session has no such fields). Stored settings from before them keep the exact
    # readings: 0, 0, "gaussian", 0 (stored_run_config).
    # The std of each weighed channel's noise, in multiples of its declared sigma (0: exact).
    sensor_noise: float = Field(1.0, ge=0, le=10)
    # A constant offset of each weighed channel's reading, in its declared sigmas.
    sensor_bias: float = Field(0.0, ge=-5, le=5)
    # The noise's shape: "student_t" is Student-t with 3 dof at the same std (heavy tails).
    sensor_tails: Literal["gaussian", "student_t"] = "gaussian"
    # The std (m, per axis) of the perceived planar positions of the movable objects.
    perception_sigma: float = Field(0.002, ge=0, le=0.05)
    # Gauss-Hermite nodes over which the filter integrates each particle world's outcome
    # of an action the domain declares perception-sensitive (``misalignment``), at
    # perception_sigma (coordinator/particle_filter/perception.py); 1: the perceived pose
    # alone. Odd, so the perceived pose is a node. 1 by default: 3 removed the large end's
    # first-grasp loop but did not improve utility or coverage over 13 runs (docs/LOOP.md).
    perception_nodes: Literal[1, 3, 5, 7] = 1
    # Perceptions a step is replayed at where the particle worlds disagreed among
    # themselves and no quadrature node applies: the perceived start and k - 1 more, each
    # movable object moved by N(0, perception_sigma^2) per axis, equally weighted, so an
    # outcome that what the camera cannot see decides is weighed as a chance, not as the
    # one replay's verdict (coordinator/loop/particle_worlds.py perception_draws; docs/
    # LOOP.md, "An outcome is a sample"). 1: the perceived start alone (stored settings).
    perception_samples: int = Field(1, ge=1, le=8)
    # Y's alternatives (the domain's ``pose_alternatives``: a cube's other grasp when a
    # neighbour is within the fingers' reach) judged by the particle worlds with the pose
    # rule "success" (issue 40; docs/LOOP.md, "Y's alternatives"). Off: Y's pose alone.
    pose_alternatives: bool = True
    # Y's grasp clearance per side (m) in a domain with the option ``grasp_clearance`` (the
    # block worlds: sim_workers.blocks.hand.grasp_opening): the opening widens to s + 2c
    # where the other objects leave room. None: the domain's default (6 mm in both block
    # domains, 3 sigma of the camera; the container's since 2026-12-01); stored settings
    # from before it: 0.
    grasp_clearance: float | None = Field(None, ge=0.0, le=0.02)
    # How the planner chooses among plans of equal expected utility, for a task half that
    # declares "trials" in ``transition_extras`` (the block worlds): "first", clingo's first
    # optimum (every run before the field); "evidence", the plan whose stacks and pushes
    # rest least on T's prior (planner.blocks.trips.tie_weights; docs/LOOP.md, "Ties
    # between equal plans"). Off by default until its calibration is measured over the grid.
    tie_break: Literal["first", "evidence"] = "first"
    costs: Costs = Costs()
    shards: int | None = Field(None, ge=0, le=4096)
    # The hidden truth by the names of L (`tmoc domains`), e.g. {"size": 0.04, "density":
    # 2400}; `true_size` is the same as truth["size"] (both may be given if they agree).
    # A property the domain knows but L does not hold (the density without the option
    # unknown_density) is a truth the agent knows: it becomes that option's value.
    truth: dict[str, float] = Field(default_factory=dict)
    # Domain options (scalar fields of the domain's physics spec), e.g.
    # {"unknown_density": true, "force_sigma": 0.1}; they reach every world, real and particle.
    options: dict[str, bool | int | float | str | None] = Field(default_factory=dict)
    # Whether the domain's L has a size (set by the validator; both built-ins do).
    _size_in_L: bool = PrivateAttr(True)

    @model_validator(mode="after")
    def _truth_and_options_are_the_domains(self) -> "RunConfig":
        from coordinator.domains import checked_options, options_of

        self.options, phys = checked_options(self.domain, dict(self.options), self.n_blocks)
        if self.grasp_clearance is not None:
            if "grasp_clearance" not in options_of(phys):
                raise ValueError(f"grasp_clearance: the {self.domain} domain has no grasp clearance")
            given = self.options.get("grasp_clearance", self.grasp_clearance)
            if given != self.grasp_clearance:
                raise ValueError(f"grasp_clearance: {self.grasp_clearance} disagrees with "
                                 f"options.grasp_clearance {given}")
            self.options["grasp_clearance"] = float(self.grasp_clearance)
        self.n_blocks = int(phys.n_objects)
        L = phys.L
        self._size_in_L = "size" in L.names
        if "size" in self.truth and not self._size_in_L:
            raise ValueError(f"truth.size: not a property of L for domain {self.domain!r} "
                             f"(properties: {', '.join(L.names)})")
        if "size" in self.truth:
            size = self.truth["size"]
            if "true_size" in self.model_fields_set and size != self.true_size:
                raise ValueError(f"truth.size: {size} disagrees with true_size {self.true_size}")
            low, high = field_bounds("true_size")
            if not low <= size <= high:
                raise ValueError(f"truth.size: {size} m is outside [{low}, {high}] m")
            self.true_size = float(size)
        # (an explicit default is let through: stored and HTTP specs carry every field)
        if not self._size_in_L and self.true_size != type(self).model_fields["true_size"].default:
            raise ValueError(f"true_size: domain {self.domain!r} has no size in L "
                             f"(properties: {', '.join(L.names)}); set truth instead")
        # A truth besides L's is a known property: an option of the physics (e.g. density).
        known = [n for n in self.truth if n not in L.names and n != "size"
                 and isinstance(options_of(phys).get(n), float)]
        for name in known:
            value = float(self.truth.pop(name))
            if name in self.options and self.options[name] != value:
                raise ValueError(f"truth.{name}: {value} disagrees with options.{name} {self.options[name]}")
            try:
                self.options, phys = checked_options(self.domain, {**self.options, name: value}, self.n_blocks)
            except ValueError as exc:
                raise ValueError(f"truth.{name}: {str(exc).split(': ', 2)[-1]}") from None
        for name in self.truth:
            if name not in L.names:
                raise ValueError(f"truth.{name}: not a property of L for domain {self.domain!r} "
                                 f"with these options (properties: {', '.join(L.names)})")
        if len(L.names) > 1 or not self._size_in_L:
            # The truth must be a world the physics can build (e.g. a density > 0).
            from sim_workers.properties import PropertyError

            try:
                phys.properties(phys.props_from_row(L.truth_row(self.truth_values(), self.n_blocks, False)))
            except PropertyError as exc:
                raise ValueError(f"truth.{exc}") from None
        return self

    @property
    def scene(self) -> Scene:
        """The run's scene as one value (domain, block count, options)."""
        return Scene.of(self.domain, self.n_blocks, self.options, self.engine)

    def truth_values(self) -> dict[str, float]:
        """The hidden truth by name (size from `true_size` where L has a size; the rest as
        given)."""
        if not self._size_in_L:
            return dict(self.truth)
        return {**self.truth, "size": float(self.true_size)}

    @model_validator(mode="after")
    def _engines_are_installed(self) -> "RunConfig":
        from sim_workers.engines import EngineError, check_engine

        for field in ("engine", "reality_engine"):
            value = getattr(self, field)
            if value is not None:
                try:
                    check_engine(value, field)
                except EngineError as exc:
                    raise ValueError(str(exc)) from None
        return self

    @model_validator(mode="after")
    def _robot_is_registered(self) -> "RunConfig":
        from sim_workers.robots import RobotError, names, robot

        try:
            bot = robot(self.robot)        # the registry; installed plugins scanned only for a name it lacks
        except RobotError:
            raise ValueError(f"robot: no robot {self.robot!r} (known: {', '.join(names())}; tmoc robots)") from None
        if bot.kind == "arm":
            from coordinator.domains import load
            from coordinator.robots import fits, options_for

            phys = load(self.domain, n_blocks=self.n_blocks).physics
            if not fits(self.robot, phys):
                raise ValueError(f"robot: domain {self.domain!r} declares no robot_base, so the arm "
                                 f"{self.robot!r} has nowhere to stand")
            # A domain that can push with the open front finger does so for an arm (its wrist
            # then clears the tower or the tray: docs/SERVICE.md), unless the run says otherwise.
            self.options = options_for(self.robot, phys, self.options)
        return self

    @model_validator(mode="after")
    def _reality_fail_is_a_context(self) -> "RunConfig":
        if self.reality_fail is None:
            return self
        from coordinator.domains import task_half
        from coordinator.loop.reality import ContextFailure

        try:
            failure = ContextFailure.parse(self.reality_fail)
        except ValueError as exc:
            raise ValueError(f"reality_fail: {exc}") from None
        contexts = task_half(self.domain).contexts(self.n_blocks)
        ks = [k for a, k in contexts if a == failure.action]
        if not ks:
            names = sorted({a for a, _ in contexts})
            raise ValueError(f"reality_fail: {failure.action!r} is not an action with T contexts "
                             f"(actions: {', '.join(names)})")
        # A context above the action's largest is accepted and never applies (the HTTP schema
        # can then say exactly what is valid without knowing n_blocks).
        return self

    @model_validator(mode="after")
    def _costs_are_the_domains(self) -> "RunConfig":
        from coordinator.domains import task_half

        terms = task_half(self.domain).default_costs
        given = self.costs.model_fields_set | set(self.costs.model_extra or {})
        for key in sorted(given):
            if key not in terms:
                if key in Costs.model_fields and getattr(self.costs, key) == Costs.model_fields[key].default:
                    continue     # another domain's default, as a dumped config carries it
                raise ValueError(f"costs.{key}: not a utility term of domain {self.domain!r} "
                                 f"(terms: {', '.join(terms)})")
            value = getattr(self.costs, key)
            if not isinstance(value, (int, float)) or not 0 <= float(value) <= 1e4:
                raise ValueError(f"costs.{key}: expected a number in [0, 10000], got {value!r}")
        # The domain's own values where none was given, so that a dumped config (stored
        # runs, checkpoints, tasks) reads back with the same utility (a domain whose terms
        # differ from the block worlds' defaults would otherwise come back with theirs).
        for key, value in terms.items():
            if key not in given and getattr(self.costs, key, None) != value:
                setattr(self.costs, key, float(value))
        return self


def field_bounds(name: str) -> tuple[float | None, float | None]:
    """The (ge, le) limits RunConfig puts on field `name` (None: unbounded on that side):
    what the CLI's limits (`tmoc serve --max-particles`, ...) are checked against.

    >>> field_bounds("particles")
    (1, 5000)
    """
    low = high = None
    for constraint in RunConfig.model_fields[name].metadata:
        low = getattr(constraint, "ge", low)
        high = getattr(constraint, "le", high)
    return low, high


# A run's random streams: children of SeedSequence(seed), each owned by one part, so the
# agent's decisions never shift the reality's draws (and results depend on the seed only).
AGENT_STREAM = 0        # the session: belief, planning, grasps
REALITY_STREAM = 1      # the simulated reality: per-episode gap and placement
COUNTERFACTUAL_STREAM = 2   # counterfactual experience: rows and trials, per episode


def seed_stream(seed: int, stream: int) -> np.random.Generator:
    """The generator of stream `stream` of a run seeded `seed` (child `stream` of
    ``SeedSequence(seed)``; the same whatever the number of streams).

    >>> float(seed_stream(0, AGENT_STREAM).random()) == float(seed_stream(0, 0).random())
    True
    """
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(stream + 1)[stream])


# What a stored config without the sensor fields ran with: the exact readings (issue 37).
PRE_SENSOR_NOISE = {"sensor_noise": 0.0, "sensor_bias": 0.0, "sensor_tails": "gaussian",
                    "perception_sigma": 0.0, "perception_nodes": 1}

# What a stored config without the filter fields ran with (the same numbers, bit for bit).
# The filter of issue 24 as it ran before issue 37 (a power likelihood, the Musso kernel
# without shrinkage and a 2 % floor, raw innovations, prior redraws, the heaviest mode's
# pose): `tmoc run --config` with these reproduces it, and the benchmarks' "before".
PRE_ISSUE_37_FILTER = {"ess_keep": 0.5, "resample_kernel": "rpf", "jitter_floor": 0.02,
                       "model_error": "online", "recovery": "prior", "pose_rule": "mode",
                       "perception_nodes": 1, "pose_alternatives": False, "move_after_resample": False,
                       "kernel_bandwidth": "n", "first_window_sweeps": 1,
                       "disagreement_readings": "own", "mismatch_move": False, "move_target": "prior",
                       "perception_samples": 1}

PRE_ISSUE_24_FILTER = {"outlier_rate": 0.0, "model_error": "none", "ess_keep": 0.0,
                       "resample_kernel": "jitter", "block_weights": False, "lock_in": False,
                       "disagreement_readings": "own", "mismatch_move": False, "move_target": "prior"}


def stored_run_config(fields: dict) -> RunConfig:
    """The RunConfig of a stored settings dump (a checkpoint's or a task's spec). Dumps are
    whole (every field), so one without `particle_budget` predates the adaptive budget:
    it keeps the fixed budget it ran with, whatever the default is now; likewise one without
    the filter fields of issue 24 keeps the filter it ran with, and one without
    `sim_discount` T's undiscounted simulated counts, and one without the sensor fields of
    issue 37 the simulated reality's exact readings (PRE_SENSOR_NOISE)."""
    fields = dict(fields)
    # Before the domain's own default count: every run had 8 objects.
    if "n_objects" not in fields:
        fields.setdefault("n_blocks", 8)
    fields.setdefault("particle_budget", "fixed")
    fields.setdefault("sim_discount", "none")
    # Before counterfactual experience (issue 40): the executed action's worlds only.
    fields.setdefault("counterfactual_rows", 0)
    # Before issue 37's filter: the lock-in monitor redrew from the prior.
    fields.setdefault("recovery", "prior")
    # Before the move after resampling, and the kernel's bandwidth from the ESS.
    fields.setdefault("move_after_resample", False)
    fields.setdefault("kernel_bandwidth", "n")
    # Before the first window's move ran to the exact posterior: one sweep.
    fields.setdefault("first_window_sweeps", 1)
    # Before a mismatched world's readings were scored at the profile: against its own.
    fields.setdefault("disagreement_readings", "own")
    fields.setdefault("mismatch_move", False)
    fields.setdefault("move_target", "prior")
    # Before Y's alternatives: Y's pose alone.
    fields.setdefault("pose_alternatives", False)
    # Before the tie-break by evidence: clingo's first optimum.
    fields.setdefault("tie_break", "first")
    # Before a disagreed step was replayed at more perceptions: the perceived start alone.
    fields.setdefault("perception_samples", 1)
    # Before Y's grasp clearance: the 1.15 sides' opening, in a domain that has the option.
    if "grasp_clearance" not in fields and "grasp_clearance" not in (fields.get("options") or {}):
        from coordinator.domains import load, options_of

        try:
            has = "grasp_clearance" in options_of(load(fields.get("domain", DEFAULT_DOMAIN)).physics)
        except Exception:  # noqa: BLE001 - an unknown domain: RunConfig names it below
            has = False
        if has:
            fields["grasp_clearance"] = 0.0
    # Before issue 24's filter: the plain Gaussian, sensor sigma, fixed jitter, no lock-in.
    for key, before in PRE_ISSUE_24_FILTER.items():
        fields.setdefault(key, before)
    # Before issue 37's sensors: the simulated reality read exactly.
    for key, before in PRE_SENSOR_NOISE.items():
        fields.setdefault(key, before)
    return RunConfig(**fields)

