"""Request models of the HTTP service (pydantic v2): task and session specs, and the
robot's observations.

Request models are strict (a string is not an integer, ``true`` is not a number) and
forbid unknown fields, so whatever does not match the published schema is refused with a
422 naming the field. The task and session specs are built per server
(:func:`task_spec_model`, :func:`session_create_model`) so that the server's limits
(particles, episodes) are part of the OpenAPI schema and of the error message.
"""
from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, AliasChoices, BaseModel, ConfigDict, Field, create_model, model_validator

from coordinator.domains import DEFAULT_DOMAIN
from coordinator.run_config import Costs, RunConfig, field_bounds, one_object_count, stored_run_config

# Configuration arrays: metres / radians / unit quaternions; generous but finite bounds.
Coord = Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)]
Robot = Annotated[list[Coord], Field(min_length=5, max_length=5,
                                     description="gripper tool point x, y, z (m), yaw (rad), opening (m)")]
Pose7 = Annotated[list[Coord], Field(min_length=7, max_length=7,
                                     description="position x, y, z (m) and quaternion x, y, z, w")]
Atom = Annotated[str, Field(min_length=1, max_length=64)]
ActionText = Annotated[str, Field(min_length=1, max_length=64)]


# ------------------------------------------------------------------------- specs
class StrictCosts(Costs):
    """Utility terms: action costs, the failure penalty and the delivery rewards."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


# Every integer field of RunConfig (min_particles was missed when listed by hand: 1027.0
# was refused while 1027 was taken).
_INT_FIELDS = tuple(name for name, f in RunConfig.model_fields.items()
                    if f.annotation in (int, int | None)) + ("n_objects",)


class _SpecBase(BaseModel):
    """JSON has one number type: 3.0 is the integer 3 (as JSON Schema says it is); 3.5, "3"
    and true are still refused by the strict int fields. NaN and infinities are refused as
    "not a finite number" (not with a misleading range message)."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _integral_floats(cls, data: Any) -> Any:
        data = one_object_count(data)
        if isinstance(data, dict) and any(isinstance(data.get(k), float) for k in _INT_FIELDS):
            data = dict(data)
            for k in _INT_FIELDS:
                v = data.get(k)
                if isinstance(v, float) and v.is_integer():
                    data[k] = int(v)
        return data


# `truth` and `options` depend on the domain: each domain gets its own request model
# (below), and the published schema is their union, chosen by `domain`.
_CLI_ONLY = {"truth", "options"}
TAG_PREFIX = "domain="      # the union's tags; error locations leave them out


def _spec_fields(exclude: set[str], max_particles: int, max_episodes: int, max_steps: int,
                 max_counterfactual_rows: int | None = None) -> dict:
    fields: dict[str, Any] = {}
    for name, info in RunConfig.model_fields.items():
        if name in exclude or name in _CLI_ONLY:
            continue
        fields[name] = (info.annotation, info)
    # The engines this server has installed (a schema-valid request is never refused for one).
    from coordinator.engines import ENGINES, default_engine, installed
    have = tuple(e for e in ENGINES if installed(e))
    for name, whose in (("engine", "the particle worlds'"), ("reality_engine", "the simulated reality's")):
        if name not in exclude:
            fields[name] = (Literal[have] | None, Field(  # type: ignore[valid-type]
                None, description=f"{whose} physics engine, one of: {', '.join(have)} "
                                  f"(null: this server's default, {default_engine()})"))
    if "domain" not in exclude:
        # an enum of the domains registered when the app is built, so the OpenAPI schema
        # says which names are valid (a schema-valid request is never refused for its domain)
        from coordinator.domains import names
        known = tuple(names())
        fields["domain"] = (Literal[known], Field(  # type: ignore[valid-type]
            DEFAULT_DOMAIN, description=f"the task's domain, one of: {', '.join(known)} "
                                     "(GET /v1/domains)"))
    if "robot" not in exclude:
        # the robots registered when the app is built (GET /v1/robots)
        from coordinator.robots import names as robot_names
        bots = tuple(robot_names())
        fields["robot"] = (Literal[bots], Field(  # type: ignore[valid-type]
            "gripper", description=f"the robot that moves the tool, one of: {', '.join(bots)}; an arm's "
                                   "steps carry a joint trajectory (GET /v1/robots)"))
    fields["particles"] = (int, Field(
        min(RunConfig.model_fields["particles"].default, max_particles), ge=1, le=max_particles,
        description=f"particles (grounded worlds) of the belief over L; this server's limit is "
                    f"{max_particles} (--max-particles)"))
    fields["episodes"] = (int, Field(
        min(RunConfig.model_fields["episodes"].default, max_episodes), ge=1, le=max_episodes,
        description=f"episodes to run; this server's limit is {max_episodes} (--max-episodes)"))
    fields["max_steps"] = (int, Field(
        min(RunConfig.model_fields["max_steps"].default, max_steps), ge=1, le=max_steps,
        description=f"actions per episode at most; this server's limit is {max_steps} (--max-steps)"))
    # The snapshot's physics is rows x the domain's contexts a plan, so the server bounds
    # the rows on their own (--max-counterfactual-rows); without that limit, its particles'.
    rows = max_particles if max_counterfactual_rows is None else max_counterfactual_rows
    fields["counterfactual_rows"] = (int, Field(
        min(RunConfig.model_fields["counterfactual_rows"].default, rows), ge=0, le=rows,
        description=f"counterfactual experience: rows of L drawn from the belief before each episode's "
                    f"first plan, each simulating every context the domain declares (0: off, the "
                    f"paper's loop); this server's limit is {rows} (--max-counterfactual-rows)"))
    fields["seed"] = (int, Field(
        0, ge=0, le=2**53 - 1, description="the run's seed (a JSON-safe integer, below 2^53)"))
    # Deprecated, still accepted (clients send it): a task cannot choose its shards, every
    # task runs on the server's one shard pool (`tmoc serve --shards`). OpenAPI marks it.
    fields["shards"] = (int | None, Field(
        None, ge=0, le=field_bounds("shards")[1],
        description="deprecated and ignored by the service: every task uses the server's "
                    "shared shard pool (tmoc serve --shards)",
        json_schema_extra={"deprecated": True}))
    return fields


def _strict_model(name: str, doc: str, fields: dict) -> type[BaseModel]:
    base = type(f"_{name}Base", (BaseModel,), {"model_config": ConfigDict(extra="forbid", strict=True,
                                                                           allow_inf_nan=False)})
    return create_model(name, __base__=base, __doc__=doc, **fields)


def _field_of(name: str, decl: dict) -> tuple:
    """A request field from a domain's declaration {type, description, ge/gt/le/lt}."""
    kind = decl["type"]
    bounds = {k: decl[k] for k in ("ge", "gt", "le", "lt") if k in decl}
    return (kind | None, Field(None, description=decl.get("description", ""), **bounds))


def _label(domain: str) -> str:
    """A domain's name as a schema component's prefix: stack_and_push -> StackAndPush."""
    return "".join(w.title() for w in domain.replace("-", "_").split("_"))


def _domain_models(domain: str) -> tuple[type[BaseModel], type[BaseModel]]:
    """(options, truth) request models of `domain`, from what its physics half declares
    (``http_options``, ``http_truth`` of its task half): each field independently valid,
    so every request the schema describes is one the domain accepts."""
    from coordinator.domains import task_half

    task = task_half(domain)
    label = _label(domain)
    options = {k: _field_of(k, d) for k, d in dict(task.http_options).items()}
    truth = {k: _field_of(k, d) for k, d in dict(task.http_truth).items()}
    return (_strict_model(f"{label}Options", f"Options of the {domain} domain (`tmoc domains`); "
                                             "unset ones keep the domain's defaults.", options),
            _strict_model(f"{label}Truth", f"The hidden truth of the {domain} domain besides "
                                           "`true_size`, by the names of L; a property L does not "
                                           "hold (the density without unknown_density) is a truth the "
                                           "agent knows.", truth))


def _costs_model(domain: str) -> type[BaseModel]:
    """The utility terms of `domain` as a request model: its own terms, each a number in
    [0, 10000] defaulting to the domain's value, and the block worlds' terms it does not
    have only at their default value (a dumped config carries them; RunConfig accepts
    nothing else), so that every body the schema describes is one the domain accepts."""
    from coordinator.domains import task_half

    terms = dict(task_half(domain).default_costs)
    fields: dict[str, Any] = {k: (float, Field(float(v), ge=0, le=1e4, description=f"utility term {k!r} "
                                               f"of {domain} (default {float(v):g})"))
                              for k, v in terms.items()}
    for k, info in Costs.model_fields.items():
        if k not in terms:
            fields[k] = (float | None, Field(None, ge=info.default, le=info.default, description=(
                f"not a term of {domain}: accepted only at its default {info.default:g}, as a "
                "config dumped by another domain carries it")))
    return _strict_model(f"{_label(domain)}Costs", f"Utility terms of the {domain} domain (`tmoc domains`): "
                                          "action costs, the failure penalty and its rewards.", fields)


def _per_domain(name: str, doc: str, fields: dict, with_truth: bool) -> Any:
    """The union of one request model per registered domain, chosen by `domain` (default
    container): each carries that domain's `options` (and `truth`)."""
    from pydantic import Discriminator, Tag

    from coordinator.domains import load, names, spec, task_half
    from coordinator.domains import canonical_name

    domain_info = fields["domain"][1]
    branches = []
    for d in names():
        opts, truth = _domain_models(d)
        own = {**fields, "options": (opts, Field(default_factory=opts, description=opts.__doc__))}
        costs = _costs_model(d)
        own["costs"] = (costs, Field(default_factory=costs, description=costs.__doc__))
        phys = load(d).physics
        top = phys.max_objects
        if "n_blocks" in own:
            # The domain's own count by default (issue 39); `n_objects` is the neutral name.
            own["n_blocks"] = (int, Field(min(int(phys.n_objects), top), ge=1, le=int(top),
                                          validation_alias=AliasChoices("n_objects", "n_blocks"),
                                          description=f"objects in the scene (1..{top} in {d}; "
                                                      f"default {min(int(phys.n_objects), top)}); "
                                                      f"also spelled n_blocks"))
        if "robot" in own:
            # only the robots that can stand in this domain's scene: an arm needs its robot_base
            # (a schema-valid request is never refused for its robot)
            from coordinator.robots import names_for

            bots = tuple(names_for(phys))
            own["robot"] = (Literal[bots], Field(  # type: ignore[valid-type]
                "gripper", description=f"the robot that moves the tool, one of: {', '.join(bots)} in {d}; "
                                       "an arm's steps carry a joint trajectory (GET /v1/robots)"))
        if with_truth:
            own["truth"] = (truth, Field(default_factory=truth, description=truth.__doc__))
        if "true_size" in own and "size" not in phys.L.names:
            # No size to hide: `true_size` only at its default, as stored specs carry it
            # (RunConfig refuses any other value, naming `truth`).
            default = RunConfig.model_fields["true_size"].default
            own["true_size"] = (float, Field(default, ge=default, le=default, description=(
                f"{d} has no size in L (its truth goes in `truth`): accepted only at the "
                f"default {default:g}")))
        if "reality_fail" in own:        # the schema names the domain's actions (issue 24)
            acts = sorted({a for a, _ in task_half(d).contexts(1)})
            own["reality_fail"] = (str | None, Field(
                None, max_length=64, pattern=f"^({'|'.join(acts)})(:[0-9]{{1,3}})?$",
                description="a reality gap the particle worlds do not know: ACTION:K makes every "
                            "ACTION in a T context >= K fail in the simulated reality only"))
        # Its name or its versioned id (`container-v1`), as the registry and the CLI take
        # them (issue 38, row 12: the id got 422 over HTTP); read back as the name.
        spelled = Annotated[Literal[d, spec(d).id], AfterValidator(canonical_name)]  # type: ignore[valid-type]
        if d == DEFAULT_DOMAIN:
            own["domain"] = (spelled, Field(DEFAULT_DOMAIN, description=domain_info.description))
        else:
            own["domain"] = (spelled, Field(description=domain_info.description))
        model = create_model(f"{name}{_label(d)}", __base__=_SpecBase, __doc__=doc, **own)
        branches.append(Annotated[model, Tag(TAG_PREFIX + d)])
    if len(branches) == 1:
        return branches[0]

    def which(v: Any) -> str:
        d = v.get("domain", DEFAULT_DOMAIN) if isinstance(v, dict) else getattr(v, "domain", DEFAULT_DOMAIN)
        if isinstance(d, str) and d not in names():
            try:
                d = canonical_name(d)          # a versioned id: its domain's branch
            except ValueError:
                pass
        return TAG_PREFIX + (d if isinstance(d, str) and d in names() else DEFAULT_DOMAIN)

    from typing import Union

    return Annotated[Union[tuple(branches)], Discriminator(which)]  # type: ignore[valid-type]


def spec_body(spec: BaseModel, **dump) -> dict:
    """A request's JSON as stored: `options`, `truth` and `costs` without their unset (null) fields."""
    body = spec.model_dump(mode="json", **dump)
    for key in ("options", "truth", "costs"):
        if isinstance(body.get(key), dict):
            body[key] = {k: v for k, v in body[key].items() if v is not None}
    return body


def task_spec_model(max_particles: int, max_episodes: int, max_steps: int = 1000,
                    max_runtime_s: float = 3600.0, max_counterfactual_rows: int | None = None) -> Any:
    """A task: the RunConfig fields, with this server's limits, and the kind of reality;
    `options` and `truth` per domain."""
    fields = _spec_fields(set(), max_particles, max_episodes, max_steps, max_counterfactual_rows)
    fields["max_runtime_s"] = (float | None, Field(
        None, ge=1.0, le=max_runtime_s,
        description=f"the task's budget of running time in seconds (queueing not counted); past it "
                    f"the task stops within one action and fails, its finished episodes kept. "
                    f"Unset: this server's limit, {max_runtime_s:g} s (--max-task-runtime-s)"))
    fields["frames"] = (bool, Field(
        True, description="render scene pictures (GET /v1/tasks/{id}/frames): the real world at the "
                          "end of every episode, every failed action beside particles' predictions; "
                          "they change nothing in the results"))
    fields["reality"] = (Literal["simulated"], Field(
        "simulated", description="the real world of a task: a simulated grounded world holding "
                                 "the hidden truth (`true_size`, `truth`). An external robot is "
                                 "driven through POST /v1/sessions instead."))
    return _per_domain("TaskSpec", "A task spec: RunConfig fields (see `tmoc run`) and `reality`.",
                       fields, with_truth=True)


def session_create_model(max_particles: int, max_episodes: int, max_steps: int = 1000,
                         max_counterfactual_rows: int | None = None) -> Any:
    """An external-robot session: the learning settings plus, optionally, the first
    episode's initial observation. The truth (`true_size`) is the robot's world, not a field."""
    # (the simulated reality's fields: a robot's sensors are its own)
    fields = _spec_fields({"true_size", "known_properties", "reality_fail", "reality_engine",
                           "sensor_noise", "sensor_bias", "sensor_tails", "perception_sigma"},
                          max_particles, max_episodes, max_steps, max_counterfactual_rows)
    fields["reality"] = (Literal["external"], Field(
        "external", description="the robot that posts observations is the real world"))
    fields["observation"] = (InitialObservation | None, Field(
        None, description="the robot's initial observation: starts episode 0 at once"))
    return _per_domain("SessionCreate", "A session spec (RunConfig fields but the truth) and an "
                       "optional initial observation.", fields, with_truth=False)


# ------------------------------------------------------------------------- observations
class ConfigurationIn(BaseModel):
    """A scene's continuous configuration, as the robot measured it."""

    model_config = ConfigDict(extra="forbid", strict=True)
    robot: Robot
    objects: Annotated[list[Pose7], Field(min_length=1, max_length=64,
                                          description="one row per object in the domain's order "
                                                      "(container: c, b1..bN)")]



class InitialObservation(BaseModel):
    """What the robot observed: the configuration; the symbolic state (Y^-1 of the
    configuration when left out) and the measurements (derived from it when left out)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    configuration: ConfigurationIn
    state: Annotated[list[Atom], Field(max_length=256)] | None = Field(
        None, description="ground atoms, e.g. is_in(b3,init); default: the server's Y^-1")
    measurements: Annotated[list[Coord | None], Field(max_length=256)] | None = Field(
        None, description="the domain's measurement channels in order (GET /v1/domains/{name}: "
                          "finger opening, x, y per block, ...); null for a channel not measured; "
                          "default: read off the configuration")
    joint_positions: Annotated[list[Coord], Field(min_length=1, max_length=16)] | None = Field(
        None, description="an arm's measured joint positions (rad, in GET /v1/robots/{name}'s joint order): "
                          "the next step's joint trajectory starts from them; only for a session with an arm")


class StepObservation(InitialObservation):
    """The outcome of the pending action; `action` echoes the action the robot executed."""

    action: ActionText = Field(description="the pending action this observation answers")
    step_id: Annotated[str, Field(min_length=1, max_length=160)] = Field(
        description="the pending step's `step_id` (from `next`): an observation answers one "
                    "step; the same observation re-posted gets the same reply and changes nothing")


def run_config(spec: dict) -> RunConfig:
    """The RunConfig of a stored task or session spec (service-only fields dropped)."""
    fields = {k: v for k, v in spec.items() if k in RunConfig.model_fields}
    fields["shards"] = None
    return stored_run_config(fields)
