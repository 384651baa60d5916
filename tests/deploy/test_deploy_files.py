"""deploy/ (issue 6): the Dockerfile, the Ray cluster launcher files and the KubeRay
manifest parse, and every `tmoc` command in them and in docs/SCALING.md's "Scaling out" section
is the project's entry point with arguments its CLI accepts.

No Docker engine or Kubernetes here: files are checked by parsing (PyYAML, Ray's own
launcher schema, a small Dockerfile reader) and against the real argument parser.
"""
from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import pytest
import yaml

from coordinator.cli import UsageError, build_parser
from coordinator.commands import serve
from ..helpers import dockerfile_instructions

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
LAUNCHER = sorted((DEPLOY / "cluster").glob("*.yaml"))
KUBERAY = DEPLOY / "kuberay" / "raycluster.yaml"
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text())
ENTRY = next(iter(PYPROJECT["project"]["scripts"]))          # "tmoc"


# -- helpers ------------------------------------------------------------------------------
def dockerfile() -> list[tuple[str, str]]:
    return dockerfile_instructions(DEPLOY / "Dockerfile")


def tmoc_commands(text: str) -> list[list[str]]:
    """Every `tmoc ...` command in a shell text, as argv (up to the first shell operator)."""
    cmds = []
    for line in text.replace("\\\n", " ").splitlines():
        if not re.search(rf"(^|[\s;&|(]){ENTRY}\s", line) or line.lstrip().startswith("#"):
            continue
        lex = shlex.shlex(line, posix=True, punctuation_chars=True)
        lex.whitespace_split = True
        tokens = list(lex)
        for i, tok in enumerate(tokens):
            if tok == ENTRY:
                argv = []
                for t in tokens[i + 1:]:
                    if t and set(t) <= set(";&|<>()"):
                        break
                    argv.append(t)
                cmds.append(argv)
    return cmds


def readme_section(title: str, page: str = "docs/SCALING.md") -> str:
    """A `## title` section of a page (the README's sections moved to docs/, issue 28)."""
    text = (REPO / page).read_text()
    m = re.search(rf"^## {re.escape(title)}\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert m, f"{page} has no '## {title}' section"
    return m.group(1)


def code_blocks(markdown: str) -> str:
    return "\n".join(re.findall(r"```(?:bash|sh)?\n(.*?)```", markdown, re.S))


def check_serve(argv: list[str], monkeypatch) -> None:
    """A `tmoc serve` line of a deployment file: parses, binds beyond loopback with a token
    and joins the cluster it runs on; refused without the token (the files must set it)."""
    args = build_parser().parse_args(argv)
    assert args.command == "serve" and args.ray_address == "auto" and args.host == "0.0.0.0"
    monkeypatch.setenv("TMOC_API_TOKEN", "x" * 32)
    assert serve.check_args(args) == "x" * 32
    monkeypatch.delenv("TMOC_API_TOKEN")
    with pytest.raises(UsageError, match="TMOC_API_TOKEN"):
        serve.check_args(args)


# -- the image ----------------------------------------------------------------------------
def test_dockerfile_installs_the_project_and_runs_the_entry_point():
    instr = dockerfile()
    assert instr[0] == ("FROM", "python:3.11-slim")
    assert ("ENTRYPOINT", json.dumps([ENTRY])) in instr
    runs = " && ".join(a for op, a in instr if op == "RUN")
    assert re.search(r"pip install \.(\s|$)", runs), runs
    copied = {src for op, a in instr if op == "COPY" for src in a.split()[:-1]}
    packages = [p.rstrip("*") for p in PYPROJECT["tool"]["setuptools"]["packages"]["find"]["include"]]
    for needed in ["pyproject.toml", "README.md", *packages]:
        assert needed in copied, f"Dockerfile does not COPY {needed}"
        assert (REPO / needed).exists()
    ignored = {line.strip() for line in (DEPLOY / "Dockerfile.dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")}
    assert not ignored & copied


# -- Ray cluster launcher -----------------------------------------------------------------
@pytest.mark.parametrize("path", LAUNCHER, ids=lambda p: p.name)
def test_launcher_config_is_valid_and_its_head_serves(path, monkeypatch):
    from ray.autoscaler._private.util import prepare_config, validate_config

    raw = yaml.safe_load(path.read_text())
    validate_config(prepare_config(json.loads(json.dumps(raw))))     # what `ray up` checks
    assert "--entrypoint" in " ".join(raw["docker"]["run_options"])  # the launcher runs `bash`
    head = "\n".join(raw["head_start_ray_commands"])
    assert "ray start --head" in head and "ray start --address" in "\n".join(raw["worker_start_ray_commands"])
    cmds = tmoc_commands(head)
    assert len(cmds) == 1, cmds
    check_serve(cmds[0], monkeypatch)
    assert "TMOC_API_TOKEN=" in head


def test_launcher_examples_cover_on_premises_and_a_cloud():
    providers = {yaml.safe_load(p.read_text())["provider"]["type"] for p in LAUNCHER}
    assert "local" in providers and providers - {"local"}
    local = next(yaml.safe_load(p.read_text()) for p in LAUNCHER
                 if yaml.safe_load(p.read_text())["provider"]["type"] == "local")
    assert local["provider"]["head_ip"] and local["provider"]["worker_ips"]


# -- KubeRay ------------------------------------------------------------------------------
def test_kuberay_raycluster_has_a_head_that_serves_and_a_scaling_worker_group(monkeypatch):
    docs = [d for d in yaml.safe_load_all(KUBERAY.read_text()) if d]
    rc = next(d for d in docs if d["kind"] == "RayCluster")
    assert rc["apiVersion"] == "ray.io/v1"
    assert rc["metadata"]["annotations"]["ray.io/overwrite-container-cmd"] == "true"
    assert rc["spec"]["enableInTreeAutoscaling"] is True
    head = rc["spec"]["headGroupSpec"]["template"]["spec"]["containers"][0]
    workers = rc["spec"]["workerGroupSpecs"]
    assert workers
    for group in workers:
        assert 0 < group["minReplicas"] <= group["replicas"] <= group["maxReplicas"]
        assert group["maxReplicas"] > group["minReplicas"]
        worker = group["template"]["spec"]["containers"][0]
        assert worker["image"] == head["image"]
        assert "$KUBERAY_GEN_RAY_START_CMD" in " ".join(worker["args"])
    script = " ".join(head["args"])
    assert "KUBERAY_GEN_RAY_START_CMD" in script
    cmds = tmoc_commands(script)
    assert len(cmds) == 1, cmds
    check_serve(cmds[0], monkeypatch)
    token = next(e for e in head["env"] if e["name"] == "TMOC_API_TOKEN")
    assert token["valueFrom"]["secretKeyRef"]["name"]
    ports = {p["containerPort"] for p in head["ports"]}
    assert {6379, 8000} <= ports
    # The API's database lives on a volume the head mounts where --db points.
    db = cmds[0][cmds[0].index("--db") + 1]
    assert any(db.startswith(m["mountPath"] + "/") for m in head["volumeMounts"])
    claims = {d["metadata"]["name"] for d in docs if d["kind"] == "PersistentVolumeClaim"}
    vols = rc["spec"]["headGroupSpec"]["template"]["spec"]["volumes"]
    assert {v["persistentVolumeClaim"]["claimName"] for v in vols} <= claims


# -- the scaling-out page ------------------------------------------------------------------------
def test_readme_scaling_out_takes_a_user_to_a_cluster_with_the_same_entry_point(monkeypatch):
    section = readme_section("Scaling out")
    code = code_blocks(section)
    assert re.search(r"^ray start --head", code, re.M)
    assert re.search(r"^ray start --address", code, re.M)
    cmds = tmoc_commands(code)
    subs = {c[0] for c in cmds}
    assert {"run", "serve"} <= subs, cmds
    parser = build_parser()
    for argv in cmds:
        args = parser.parse_args(argv)                      # every line is a valid command
        assert args.ray_address == "auto", argv
        if args.command == "serve" and args.host == "0.0.0.0":
            check_serve(argv, monkeypatch)
    # The image and the deployment files the section points to exist.
    for ref in re.findall(r"deploy/[\w./-]+", section):
        assert (REPO / ref.rstrip(".")).exists(), ref
    assert "deploy/Dockerfile" in section and "deploy/kuberay/raycluster.yaml" in section
