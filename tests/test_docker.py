"""docker/ without a Docker engine: what can be checked of the image recipe and the compose cluster here.

- docker/compose.yaml (and compose.tls.yaml) validate against the Compose specification's JSON schema
  (and with `docker compose config` where the compose plugin exists);
- every command in them is `dronesim ROLE ...` and parses with that role's real argparse parser; every
  file they name exists in the repository or the image;
- docker/Dockerfile copies what exists, what Dockerfile.dockerignore lets through and all the package
  needs; its lock files pin what pyproject.toml asks for and what is installed here; the build stage's
  commands run here (a venv instead of an image);
- docker/zenohd.json5 and the compose command lines play a whole game: through an embedded router
  loaded from that file, and through zenohd itself when it is installed (tests/setup.d/zenohd.sh);
- the entrypoint gives scaled drone replicas unique ids; the health check tells a present entity from
  an absent one.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.metadata
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from tests.harness import CACHE, Proc, journal_records, zenohd

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
COMPOSE = DOCKER / "compose.yaml"
COMPOSE_TLS = DOCKER / "compose.tls.yaml"
DOCKERFILE = DOCKER / "Dockerfile"
DOCKERIGNORE = DOCKER / "Dockerfile.dockerignore"
ZENOHD_CONF = DOCKER / "zenohd.json5"
ENTRYPOINT = DOCKER / "entrypoint.py"
HEALTH = DOCKER / "healthcheck.py"
#: what the docker-compose 1.29.2 wheel (PyPI) ships: the Compose specification's JSON schema.
COMPOSE_SCHEMA_SOURCE = ("docker-compose==1.29.2", "compose/config/compose_spec.json")
#: the dronesim subcommands that are entities or a router, and the module holding each one's `cli`.
ROLE_MODULES = {
    "coordinator": "dronesim.coordinator.node",
    "env": "dronesim.entities.env_node",
    "drone": "dronesim.entities.drone_node",
    "gcs": "dronesim.entities.gcs_node",
    "router": "dronesim.router",
}
ROUTER_ENDPOINT = "tcp/router:7447"

yaml = pytest.importorskip("yaml", reason="PyYAML is needed to read the compose files")


# --------------------------------------------------------------------------- reading the files


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def zenoh_pin() -> str:
    for dep in pyproject()["project"]["dependencies"]:
        m = re.fullmatch(r"eclipse-zenoh\s*==\s*([\w.]+)", dep)
        if m:
            return m.group(1)
    raise AssertionError("pyproject.toml does not pin eclipse-zenoh==X.Y.Z")


_VAR = re.compile(r"\$(?:\$|\{(?P<braced>[^}]*)\}|(?P<plain>[A-Za-z_][A-Za-z0-9_]*))")


def interpolate(text: str, env: dict[str, str]) -> str:
    """Compose's variable interpolation: $$, $VAR, ${VAR}, ${VAR:-default}, ${VAR-default}, ${VAR:?err}."""

    def sub(m: re.Match) -> str:
        if m.group(0) == "$$":
            return "$"
        expr = m.group("braced") if m.group("braced") is not None else m.group("plain")
        name, op, arg = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:(:?[-?])(.*))?", expr, re.S).groups()
        value = env.get(name)
        if op in (":-", "-"):
            return arg if (value is None or (op == ":-" and value == "")) else value
        if op in (":?", "?"):
            if value is None or (op == ":?" and value == ""):
                raise AssertionError(f"compose variable {name} is required: {arg}")
            return value
        return value or ""

    return _VAR.sub(sub, text)


def load_compose(path: Path = COMPOSE, **env: str) -> dict:
    """The compose file as Compose reads it: variables interpolated (defaults, or `env`), then YAML."""
    return yaml.safe_load(interpolate(path.read_text(), env))


def merge_compose(base: dict, override: dict) -> dict:
    """`docker compose -f base -f override`, for what these files use: mappings merge, a command is
    replaced, volumes merge by their path in the container."""
    out = json.loads(json.dumps(base))
    for name, svc in override.get("services", {}).items():
        target = out["services"].setdefault(name, {})
        for key, value in svc.items():
            if key == "volumes":
                mounts = {v.split(":")[1]: v for v in target.get("volumes", [])}
                mounts.update({v.split(":")[1]: v for v in value})
                target["volumes"] = list(mounts.values())
            elif isinstance(value, dict) and isinstance(target.get(key), dict):
                target[key] = {**target[key], **value}
            else:
                target[key] = value
    return out


def load_cluster(path: Path = COMPOSE, **env: str) -> dict:
    """compose.yaml, or compose.yaml with the override `path` applied."""
    base = load_compose(COMPOSE, **env)
    return base if path == COMPOSE else merge_compose(base, load_compose(path, **env))


#: Volume sources that are made, not shipped: the TLS kit of `dronesim certs` (compose.tls.yaml).
GENERATED = {"../certs"}


def dronesim_services(compose: dict) -> dict[str, dict]:
    """The services running the dronesim image (every one but the router)."""
    return {name: svc for name, svc in compose["services"].items()
            if isinstance(svc.get("command"), list) and svc["command"][:1] == ["dronesim"]}


def flag_values(argv: list[str], *names: str) -> list[str]:
    """Every value of the flags `names` in argv (``--flag value`` and ``--flag=value``)."""
    out = []
    for i, arg in enumerate(argv):
        for n in names:
            if arg == n and i + 1 < len(argv):
                out.append(argv[i + 1])
            elif arg.startswith(n + "="):
                out.append(arg.split("=", 1)[1])
    return out


def replace_flag(argv: list[str], name: str, value: str) -> list[str]:
    out = list(argv)
    i = out.index(name)
    out[i + 1] = value
    return out


class Parsed(Exception):
    def __init__(self, namespace) -> None:
        self.namespace = namespace


def parse_role(role: str, argv: list[str]):
    """`dronesim ROLE argv` parsed by the role's own argparse parser (its `cli` stops right after parsing)."""
    import argparse
    import io

    cli = importlib.import_module(ROLE_MODULES[role]).cli
    real = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise Parsed(real(self, args, namespace))

    err = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stderr(err):
        mp.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
        try:
            cli(list(argv))
        except Parsed as done:
            return done.namespace
        except SystemExit:
            raise AssertionError(f"`dronesim {role} {shlex.join(argv)}` does not parse: {err.getvalue().strip()}") \
                from None
    raise AssertionError(f"dronesim {role}'s cli never parsed its arguments")


# --------------------------------------------------------------------------- the compose specification


def compose_schema() -> dict:
    """The Compose specification's JSON schema, offline: from an installed `compose` package (the
    docker-compose 1.29.2 wheel or Debian's python3-compose), else from the cache, else fetched once
    with pip from PyPI into the cache."""
    spec = importlib.util.find_spec("compose")
    if spec is not None and spec.submodule_search_locations:
        for loc in spec.submodule_search_locations:
            path = Path(loc) / "config" / "compose_spec.json"
            if path.exists():
                return json.loads(path.read_text())
    cached = CACHE / "compose_spec.json"
    if not cached.exists():
        req, member = COMPOSE_SCHEMA_SOURCE
        tmp = CACHE / "compose-wheel"
        tmp.mkdir(parents=True, exist_ok=True)
        p = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
                            "--no-deps", "--only-binary=:all:", "-d", str(tmp), req],
                           capture_output=True, text=True, timeout=300)
        wheels = sorted(tmp.glob("docker_compose-*.whl"))
        if p.returncode != 0 or not wheels:
            pytest.skip(f"no Compose JSON schema here, and `pip download {req}` failed: {p.stderr.strip()[-300:]}")
        with zipfile.ZipFile(wheels[-1]) as z:
            cached.write_bytes(z.read(member))
        shutil.rmtree(tmp, ignore_errors=True)
    return json.loads(cached.read_text())


def compose_files() -> list[Path]:
    return [p for p in (COMPOSE, COMPOSE_TLS) if p.exists()]


@pytest.mark.parametrize("path", compose_files(), ids=lambda p: p.name)
def test_compose_file_validates_against_the_compose_specification(path):
    jsonschema = pytest.importorskip("jsonschema", reason="jsonschema validates the compose file")
    schema = compose_schema()
    data = load_compose(path)
    # The schema names draft 2019-09 with a non-canonical URI: say it explicitly.
    validator = jsonschema.Draft201909Validator(schema, format_checker=jsonschema.FormatChecker())
    errors = sorted(validator.iter_errors(data), key=lambda e: list(e.absolute_path))
    assert not errors, "\n".join(f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in errors)


def docker_compose_plugin() -> bool:
    docker = shutil.which("docker")
    if docker is None:
        return False
    return subprocess.run([docker, "compose", "version"], capture_output=True, timeout=30).returncode == 0


@pytest.mark.skipif(not docker_compose_plugin(), reason="no `docker compose` plugin here (the schema test stands in)")
def test_docker_compose_config_accepts_the_files():
    files = [a for p in compose_files() for a in ("-f", str(p))]
    p = subprocess.run(["docker", "compose", *files, "config", "--quiet"], capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr


# --------------------------------------------------------------------------- what the compose file says


def test_router_is_the_real_zenohd_matching_eclipse_zenoh():
    compose = load_compose()
    router = compose["services"]["router"]
    assert router["image"] == f"eclipse/zenoh:{zenoh_pin()}", "the router image must match eclipse-zenoh's version"
    mounts = {v.split(":")[1]: (DOCKER / v.split(":")[0]).resolve() for v in router["volumes"]}
    conf_in_container = router["command"][router["command"].index("-c") + 1]
    assert mounts[conf_in_container] == ZENOHD_CONF.resolve()
    assert any(p.endswith(":7447") for p in router["ports"])
    assert router["healthcheck"]["test"][0] == "CMD-SHELL"


def test_router_config_listens_on_7447_without_multicast():
    import zenoh

    conf = zenoh.Config.from_file(str(ZENOHD_CONF))
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    admin = json.loads(conf.get_json("adminspace"))
    assert admin["enabled"] is True and admin["permissions"] == {"read": True, "write": False}


def test_every_dronesim_service_is_an_explicit_client_of_the_router():
    compose = load_compose()
    services = dronesim_services(compose)
    roles = {svc["command"][1] for svc in services.values()}
    assert {"coordinator", "env", "drone", "gcs"} <= roles
    for name, svc in services.items():
        argv = svc["command"]
        assert flag_values(argv, "--connect", "-e") == [ROUTER_ENDPOINT], name
        assert flag_values(argv, "--mode", "-m") == ["client"], name
        assert not flag_values(argv, "--listen", "-l"), name
        assert svc["build"]["dockerfile"] == "docker/Dockerfile" and (DOCKER / svc["build"]["context"]).resolve() == ROOT
        assert svc["depends_on"]["router"]["condition"] == "service_healthy", name
        assert svc["init"] is True and svc["read_only"] is True, name


@pytest.mark.skipif(not COMPOSE_TLS.exists(), reason="no TLS variant")
def test_tls_variant_uses_mutual_tls_and_access_control_everywhere():
    import zenoh

    cluster = load_cluster(COMPOSE_TLS)
    router = cluster["services"]["router"]
    conf_path = DOCKER / mounts(router)[router["command"][router["command"].index("-c") + 1]]
    assert conf_path.resolve().parent == (ROOT / "config").resolve()
    conf = zenoh.Config.from_file(str(conf_path))
    assert json.loads(conf.get_json("listen/endpoints")) == ["tls/0.0.0.0:7447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    acl = json.loads(conf.get_json("access_control"))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    subjects = {s["id"] for s in acl["subjects"]}
    assert {"SRV", "ENV", "GCS", "D01"} <= subjects
    assert "/certs" in mounts(router)
    for name, svc in dronesim_services(cluster).items():
        argv = svc["command"]
        assert flag_values(argv, "--connect") == ["tls/router:7447"], name
        assert flag_values(argv, "--tls-cert") == ["/certs/{id}.pem"], name
        assert flag_values(argv, "--tls-key") == ["/certs/{id}.key"], name
        assert "/certs" in mounts(svc), name
    drones = int(flag_values(cluster["services"]["coordinator"]["command"], "--drones")[0])
    assert all(f"D{i:02d}" in subjects for i in range(1, drones + 1)), "the ACL must name every drone"


def test_drones_scale_to_the_coordinators_drone_count():
    for env in ({}, {"DRONES": "5"}):
        compose = load_compose(**env)
        services = compose["services"]
        drones = flag_values(services["coordinator"]["command"], "--drones")[0]
        assert services["drone"]["deploy"]["replicas"] == int(drones) == int(env.get("DRONES", 3))
        assert flag_values(services["drone"]["command"], "--id") == ["auto"]
        assert flag_values(services["swarm"]["command"], "--id") == [f"1-{drones}"]


def test_web_ground_station_is_published():
    gcs = load_compose()["services"]["gcs"]
    host, _, port = flag_values(gcs["command"], "--web")[0].rpartition(":")
    assert host == "0.0.0.0", "inside a container the page must listen on every interface"
    assert any(p.endswith(f":{port}") for p in gcs["ports"])


@pytest.mark.parametrize("path", compose_files(), ids=lambda p: p.name)
def test_every_compose_command_parses_with_the_roles_own_parser(path):
    for name, svc in dronesim_services(load_compose(path)).items():
        argv = svc["command"]
        role, rest = argv[1], argv[2:]
        assert role in ROLE_MODULES, f"{name}: unknown role {role}"
        if role == "drone" and flag_values(rest, "--id") == ["auto"]:
            rest = replace_flag(rest, "--id", "D01")  # what the entrypoint passes on
        args = parse_role(role, rest)
        if role == "coordinator":
            from dronesim.coordinator.node import game_config

            game = game_config(args)
            assert len(game.drones) == int(flag_values(argv, "--drones")[0])
        if role == "drone":
            from dronesim.entities.drone_node import parse_drones

            assert parse_drones(args.id)


def documented_commands() -> list[list[str]]:
    """Every `dronesim ROLE ...` line in the code blocks of docs/docker.md (after `docker run IMAGE` too)."""
    out, fenced = [], False
    for line in (ROOT / "docs" / "docker.md").read_text().splitlines():
        if line.startswith("```"):
            fenced = not fenced
            continue
        if fenced and "dronesim " in line:
            argv = shlex.split(line)
            for i, word in enumerate(argv[:-1]):
                if word == "dronesim" and argv[i + 1] in ROLE_MODULES:
                    out.append(argv[i + 1:])
                    break
    return out


def test_every_documented_command_parses():
    commands = documented_commands()
    assert any(c[0] == "gcs" and "tcp/HOST:7447" in c for c in commands), "the remote join is documented"
    assert any(c[0] == "gcs" and "tls/HOST:7447" in c for c in commands), "the TLS remote join is documented"
    for argv in commands:
        parse_role(argv[0], argv[1:])
    text = (ROOT / "docs" / "docker.md").read_text()
    assert "docker compose -f docker/compose.yaml up" in text
    assert "## Docker" in (ROOT / "README.md").read_text() and "docs/docker.md" in (ROOT / "README.md").read_text()


def container_files(compose: dict) -> dict[str, Path]:
    """Paths inside the dronesim image -> the repository files they come from."""
    return {dst: ROOT / src for src, dst in dockerfile_copies() if not src.endswith("/")}


def mounts(svc: dict) -> dict[str, str]:
    """Container path -> source of a service's volumes."""
    return {v.split(":")[1]: v.split(":")[0] for v in svc.get("volumes", [])}


@pytest.mark.parametrize("path", compose_files(), ids=lambda p: p.name)
def test_every_file_a_compose_command_names_exists(path):
    cluster = load_cluster(path)
    image = container_files(cluster)
    for name, svc in cluster["services"].items():
        for dst, src in mounts(svc).items():
            if src.startswith(".") and src not in GENERATED:
                assert (DOCKER / src).exists(), f"{name}: volume source {src} is missing"
        argv = svc.get("command") or []
        named = flag_values(argv, "--config", "-c", "--scenario", "--world", "--script", "--tls-ca", "--tls-cert",
                            "--tls-key", "--password-file", "--users-file", "--acl", "--journal")
        for value in named:
            mount = next((d for d in mounts(svc) if value.startswith(d.rstrip("/") + "/") or value == d), None)
            if mount is None:
                assert value in image, f"{name}: {value} is neither in the image nor on a volume"
                assert image[value].exists(), f"{name}: {value} comes from {image[value]}, which is missing"
            elif mounts(svc)[mount].startswith("."):
                source = mounts(svc)[mount]
                if source not in GENERATED:
                    local = (DOCKER / source / Path(value).relative_to(mount)) if value != mount else DOCKER / source
                    assert local.exists(), f"{name}: {value} is {local}, which is missing"
        for journal in flag_values(argv, "--journal"):
            volume = mounts(svc).get(str(Path(journal).parent))
            assert volume and not volume.startswith("."), f"{name}: {journal} is not on a named volume"
            assert "mkdir -p /data" in DOCKERFILE.read_text()


# --------------------------------------------------------------------------- the image recipe


def dockerfile_instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    lines, current = [], ""
    for raw in DOCKERFILE.read_text().splitlines():
        if not current and (raw.strip().startswith("#") or not raw.strip()):
            continue
        current += raw.rstrip("\\").strip() + " "
        if not raw.rstrip().endswith("\\"):
            lines.append(current.strip())
            current = ""
    return [(line.split(None, 1)[0].upper(), line.split(None, 1)[1] if " " in line else "") for line in lines]


def dockerfile_copies() -> list[tuple[str, str]]:
    """(source, destination) of every COPY from the build context (not --from a stage)."""
    out = []
    for instr, args in dockerfile_instructions():
        if instr != "COPY":
            continue
        parts = [p for p in shlex.split(args) if not p.startswith("--chmod") and not p.startswith("--chown")]
        if any(p.startswith("--from") for p in parts):
            continue
        *sources, dest = parts
        for src in sources:
            out.append((src, dest + Path(src).name if dest.endswith("/") and not src.endswith("/") else dest))
    return out


def ignored(path: str, patterns: list[str]) -> bool:
    """.dockerignore semantics (last matching pattern wins, `!` re-includes, a dir covers its files)."""
    import fnmatch

    def matches(pattern: str, p: str) -> bool:
        pattern = pattern.rstrip("/")
        rx = fnmatch.translate(pattern).replace(".*", "[^/]*").replace("[^/]*[^/]*", ".*")
        if pattern.startswith("**/"):
            rx = "(.*/)?" + fnmatch.translate(pattern[3:]).replace(".*", "[^/]*")
        parts = p.split("/")
        return any(re.fullmatch(rx, "/".join(parts[:i])) for i in range(1, len(parts) + 1))

    result = False
    for pat in patterns:
        negate = pat.startswith("!")
        if matches(pat.lstrip("!"), path):
            result = not negate
    return result


def dockerignore_patterns() -> list[str]:
    return [ln.strip() for ln in DOCKERIGNORE.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def test_dockerfile_is_multi_stage_slim_non_root_with_a_healthcheck():
    instrs = dockerfile_instructions()
    froms = [a for i, a in instrs if i == "FROM"]
    args = dict(a.split("=", 1) for i, a in instrs if i == "ARG" and "=" in a)
    assert len(froms) >= 2, "multi-stage: a build stage and a runtime stage"
    assert args["PYTHON_IMAGE"].startswith("python:3.11-slim")
    user = [a for i, a in instrs if i == "USER"]
    assert user and user[-1] not in ("root", "0"), "the runtime runs as a non-root user"
    health = [a for i, a in instrs if i == "HEALTHCHECK"]
    assert health and "dronesim-health" in health[0]
    copies = dict((dst, src) for src, dst in dockerfile_copies())
    assert copies["/usr/local/bin/dronesim-health"] == "docker/healthcheck.py"
    entry = json.loads([a for i, a in instrs if i == "ENTRYPOINT"][0])
    assert copies[entry[0]] == "docker/entrypoint.py"
    assert any("--require-hashes" in a and "docker/requirements.lock" in a for i, a in instrs if i == "RUN")
    assert any("pip wheel" in a for i, a in instrs if i == "RUN"), "the build stage builds a wheel"


def test_every_copy_source_exists_and_passes_the_dockerignore():
    patterns = dockerignore_patterns()
    for src, _ in dockerfile_copies():
        assert (ROOT / src).exists(), f"COPY {src}: missing"
        assert not ignored(src.rstrip("/"), patterns), f"COPY {src}: excluded by {DOCKERIGNORE.name}"
    assert ignored(".git", patterns) and ignored("tests/test_docker.py", patterns)
    assert ignored("runtime/__pycache__/cli.cpython-311.pyc", patterns)


def test_the_image_gets_everything_the_package_is_built_from():
    project = pyproject()
    copied = {src.rstrip("/") for src, _ in dockerfile_copies()}
    package_dirs = {Path(d).parts[0] for d in project["tool"]["setuptools"]["package-dir"].values()}
    assert package_dirs <= copied, f"not copied into the build stage: {package_dirs - copied}"
    assert {"pyproject.toml", project["project"]["readme"]} <= copied


def lock(path: Path) -> dict[str, tuple[str, list[str]]]:
    """name -> (version, hashes) of a pip lock file."""
    text = path.read_text().replace("\\\n", " ")
    out = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            req, *opts = line.split()
            name, version = req.split("==")
            out[name] = (version, [o.split(":", 1)[1] for o in opts if o.startswith("--hash=sha256:")])
    return out


def test_locks_pin_what_pyproject_asks_and_what_is_installed():
    from packaging.requirements import Requirement
    from packaging.version import Version

    runtime = lock(DOCKER / "requirements.lock")
    wanted = {Requirement(d).name: Requirement(d) for d in pyproject()["project"]["dependencies"]}
    assert set(runtime) == set(wanted), "the lock must hold exactly the runtime dependencies"
    for name, (version, hashes) in runtime.items():
        assert wanted[name].specifier.contains(version), f"{name}=={version} breaks pyproject's {wanted[name]}"
        assert len(hashes) >= 2, f"{name}: a wheel hash for linux/amd64 and one for linux/arm64"
        installed = importlib.metadata.version(name)
        assert Version(installed).major == Version(version).major, \
            f"{name}: {installed} installed, {version} in the image: run bash docker/lock.sh"
    assert runtime["eclipse-zenoh"][0] == zenoh_pin() == importlib.metadata.version("eclipse-zenoh")
    build = lock(DOCKER / "build-requirements.lock")
    for dep in pyproject()["build-system"]["requires"]:
        req = Requirement(dep)
        assert req.specifier.contains(build[req.name][0]), f"build lock breaks {req}"


@pytest.mark.slow
def test_the_build_stage_runs_here(tmp_path):
    """The Dockerfile's build stage, run with this machine's Python instead of python:3.11-slim: the
    hashed locks install, the wheel builds, and the installed package runs outside the source tree
    with every subpackage and data file."""
    def run(*argv: str, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(argv, capture_output=True, text=True, timeout=600, **kw)

    if sys.version_info[:2] != (3, 11):
        pytest.skip("the locks are for CPython 3.11 (the image's)")
    venv, build = tmp_path / "venv", tmp_path / "build"
    assert run(sys.executable, "-m", "venv", "--without-pip", str(venv)).returncode == 0
    assert run(sys.executable, "-m", "venv", str(build)).returncode == 0
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    p = run(*pip, "--python", str(venv / "bin" / "python"), "install", "--require-hashes", "--only-binary=:all:",
            "-r", str(DOCKER / "requirements.lock"))
    if p.returncode != 0 and ("Could not fetch" in p.stderr or "NewConnectionError" in p.stderr):
        pytest.skip(f"PyPI unreachable: {p.stderr.strip()[-300:]}")
    assert p.returncode == 0, p.stderr
    p = run(str(build / "bin" / "pip"), "install", "--disable-pip-version-check", "--require-hashes",
            "--only-binary=:all:", "-r", str(DOCKER / "build-requirements.lock"))
    assert p.returncode == 0, p.stderr
    context = tmp_path / "context"  # what the Dockerfile copies, and nothing else
    for src, _ in dockerfile_copies():
        target = context / src
        if (ROOT / src).is_dir():
            shutil.copytree(ROOT / src, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / src, target)
    p = run(str(build / "bin" / "pip"), "wheel", "--disable-pip-version-check", "--no-deps",
            "--no-build-isolation", "--wheel-dir", str(tmp_path / "wheels"), ".", cwd=context)
    assert p.returncode == 0, p.stderr
    wheel = next((tmp_path / "wheels").glob("dronesim-*.whl"))
    p = run(*pip, "--python", str(venv / "bin" / "python"), "install", "--no-deps", str(wheel))
    assert p.returncode == 0, p.stderr
    names = zipfile.ZipFile(wheel).namelist()
    for init in ROOT.glob("*/**/__init__.py"):
        rel = init.relative_to(ROOT)
        if rel.parts[0] in ("tests", "build", "dist") or ".egg-info" in str(rel):
            continue
        assert any(n.endswith("/".join(rel.parts[1:])) or n.endswith(rel.name) for n in names)
    modules = sorted({n[:-3].replace("/", ".").removesuffix(".__init__") for n in names
                      if n.endswith(".py") and not n.endswith("__main__.py")})
    code = "import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m)\n"
    p = run(str(venv / "bin" / "python"), "-c", code, *modules, cwd=tmp_path)
    assert p.returncode == 0, f"the installed wheel does not import: {p.stderr}"
    p = run(str(venv / "bin" / "python"), "-m", "dronesim", "--help", cwd=tmp_path)
    assert p.returncode == 0 and "coordinator" in p.stdout
    for pkg_data, patterns in pyproject()["tool"]["setuptools"].get("package-data", {}).items():
        src_dir = ROOT / pyproject()["tool"]["setuptools"]["package-dir"][pkg_data]
        for pattern in patterns:
            for f in src_dir.glob(pattern):
                want = "/".join([*pkg_data.split("."), str(f.relative_to(src_dir))])
                assert want in names, f"{want} is not in the wheel"


# --------------------------------------------------------------------------- entrypoint and health check


def load_script(path: Path):
    spec = importlib.util.spec_from_file_location(path.stem.replace("-", "_") + "_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_entrypoint_names_each_containers_entity():
    ep = load_script(ENTRYPOINT)
    assert ep.drone_entity(ep.flags(["--id", "D07"])) == "D07"
    assert ep.drone_entity(ep.flags(["--id", "3"])) == "D03"
    assert ep.drone_entity(ep.flags(["--id", "1-8", "--host", "H02"])) == "H02"
    assert ep.with_id(["--id", "auto", "--autopilot", "v1"], "D04") == ["--id", "D04", "--autopilot", "v1"]
    assert ep.with_id(["--id=auto"], "D12") == ["--id=D12"]
    assert ep.fill(["--tls-cert", "/certs/{id}.pem", "--seed", "7"], "D03") == ["--tls-cert", "/certs/D03.pem", "--seed", "7"]
    assert ep.TAKEN.search("dronesim drone: connection refused: D01 is already connected")
    assert ep.TAKEN.search("dronesim drone: connection refused: drone D02 is already taken by H01")
    assert ep.UNKNOWN.search("dronesim drone: connection refused: unknown drone D04: this game flies D01, D02")


def test_health_check_without_an_entity_is_healthy(tmp_path):
    p = subprocess.run([sys.executable, str(HEALTH)], capture_output=True, text=True, timeout=60,
                       env=dict(os.environ, DRONESIM_STATE=str(tmp_path / "none.json")))
    assert p.returncode == 0 and "no dronesim entity" in p.stdout


# --------------------------------------------------------------------------- whole games


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def embedded_router_from_config():
    """docker/zenohd.json5 in a Python router session, listening on a free loopback port instead."""
    import zenoh

    from dronesim.transport import router_locators

    conf = zenoh.Config.from_file(str(ZENOHD_CONF))
    conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    with zenoh.open(conf) as router:
        yield router_locators(router)[0]


def health(state: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(HEALTH)], capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, DRONESIM_STATE=str(state)))


def quit_when_idle(url: str, timeout: float = 120) -> None:
    """Follow the web ground station's event stream until every drone is at its target, then quit."""
    import urllib.request

    base = url.rstrip("/")
    event, data = "", []
    with urllib.request.urlopen(f"{base}/api/events", timeout=timeout) as stream:
        for raw in stream:
            line = raw.decode().rstrip("\r\n")
            if line.startswith("event:"):
                event = line.split(":", 1)[1].strip()
            elif line.startswith("data:"):
                data.append(line.split(":", 1)[1].strip())
            elif not line:
                state = json.loads("\n".join(data)) if event == "state" and data else None
                event, data = "", []
                if state is not None and state["control"]["waiting"] == "idle":
                    break
        else:
            raise AssertionError("the web ground station's stream ended before the drones arrived")
    req = urllib.request.Request(f"{base}/api/control", data=json.dumps({"action": "quit"}).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(req, timeout=30) as answer:
        assert json.loads(answer.read())["ok"] is True


GAME_ENV = {"DRONES": "2", "SEED": "7", "MAX_TURNS": "40", "WEB_PACE": "0", "WEB_LINGER": "0"}


def play_compose_game(cluster: dict, rewrite: dict[str, str], tmp_path: Path) -> tuple[dict[str, Proc], Path]:
    """The cluster's command lines, run through the image's entrypoint with each `rewrite` applied (the
    router endpoint, /data, /certs): the web page takes a free loopback port and gets scripted targets,
    and three drone replicas with `--id auto` race for the two drone ids. The "containers" are checked
    healthy while they wait for the ground station, which a test then drives as a human would."""
    services = cluster["services"]
    data = tmp_path / "data"
    data.mkdir()
    rewrite = {**rewrite, "/data/": f"{data}/"}

    def argv_of(name: str) -> list[str]:
        argv = list(services[name]["command"])
        for old, new in rewrite.items():
            argv = [a.replace(old, new) for a in argv]
        return [sys.executable, str(ENTRYPOINT), *argv]

    def start(name: str, argv: list[str]) -> Proc:
        state = tmp_path / f"{name}.state.json"  # each "container" has its own /tmp
        proc = Proc(name, ["env", f"DRONESIM_STATE={state}", *argv], tmp_path)
        proc.state = state
        return proc

    procs: dict[str, Proc] = {}
    try:
        procs["coordinator"] = start("coordinator", argv_of("coordinator"))
        procs["coordinator"].expect("coordinator ready")
        procs["env"] = start("env", argv_of("env"))
        replicas = services["drone"]["deploy"]["replicas"]
        for n in range(1, replicas + 2):  # one replica too many
            procs[f"drone-{n}"] = start(f"drone-{n}", argv_of("drone"))
        for i in range(1, replicas + 1):
            procs["coordinator"].expect(rf"admitted D{i:02d}\b")
        extra = f"D{replicas + 1:02d}"
        procs["coordinator"].expect(rf"refused {extra}: unknown drone")
        procs["coordinator"].expect(r"admitted ENV\b")
        drones = {n: json.loads(p.state.read_text())["entity"] for n, p in procs.items() if n.startswith("drone-")}
        assert sorted(drones.values()) == [*(f"D{i:02d}" for i in range(1, replicas + 1)), extra]
        for name, entity in drones.items():
            if entity == extra:
                assert procs[name].wait() == 2, "the replica finding no free id says so and fails"
        for name in ("coordinator", "env", *(n for n, e in drones.items() if e != extra)):
            probe = health(procs[name].state)  # the entities are up, waiting for the ground station
            assert probe.returncode == 0, f"{name}: {probe.stdout}{probe.stderr}"
        gone = tmp_path / "gone.state.json"
        state = json.loads(procs["env"].state.read_text())
        gone.write_text(json.dumps({**state, "role": "drone", "entity": "D09", "pid": None}))
        assert health(gone).returncode == 1, "no D09 here: unhealthy"
        web = replace_flag(argv_of("gcs"), "--web", "127.0.0.1:0") + ["--targets", "D01=9,9,0;D02=9,0,0"]
        procs["gcs"] = start("gcs", web)
        url = re.search(r"https?://\S+", procs["gcs"].expect(r"web ground station: http")).group(0)
        quit_when_idle(url)  # as the human would: once every drone is at its target, Quit game
        for p in procs.values():
            p.wait(120)
    except AssertionError as err:
        for p in procs.values():
            p.kill()
        raise AssertionError("\n".join([str(err), *(f"=== {n}\n{p.text}" for n, p in procs.items())])) from None
    finally:
        for p in procs.values():
            p.kill()
    journal = flag_values(services["coordinator"]["command"], "--journal")[0].replace("/data/", f"{data}/")
    return procs, Path(journal)


def check_game(procs: dict[str, Proc], journal: Path) -> None:
    codes = {name: p.p.returncode for name, p in procs.items()}
    extra = [n for n, p in procs.items() if n.startswith("drone-") and any("no free drone id" in l for l in p.err)]
    assert len(extra) == 1 and codes.pop(extra[0]) == 2, {n: p.text for n, p in procs.items()}
    assert set(codes.values()) == {0}, {n: p.text for n, p in procs.items()}
    records = journal_records(journal)
    header, over = records[0], records[-1]
    assert header["record"] == "header" and over["record"] == "over"
    assert [d["drone"] for d in header["drones"]] == ["D01", "D02"]
    assert {d["autopilot"] for d in header["drones"]} == {"dstar"}
    flown = sorted(l.split()[-1] for n, p in procs.items() if n.startswith("drone-")
                   for l in p.err if "You are connected as" in l)
    assert flown == ["D01", "D02"], flown  # each id flown by exactly one replica


@pytest.mark.integration
@pytest.mark.slow
def test_compose_game_through_the_router_config(tmp_path):
    with embedded_router_from_config() as locator:
        procs, journal = play_compose_game(load_cluster(COMPOSE, **GAME_ENV), {ROUTER_ENDPOINT: locator}, tmp_path)
    check_game(procs, journal)


def router_health_probe(port: int) -> str:
    """The router service's health check command, for `port` instead of 7447."""
    test = load_compose()["services"]["router"]["healthcheck"]["test"][1]
    assert ":1D17 " in test
    return test.replace(":1D17 ", f":{port:04X} ")


@pytest.mark.integration
@pytest.mark.slow
def test_compose_game_through_zenohd(tmp_path):
    port = free_port()
    text = ZENOHD_CONF.read_text()
    assert '"tcp/0.0.0.0:7447"' in text
    conf = tmp_path / "zenohd.json5"
    conf.write_text(text.replace('"tcp/0.0.0.0:7447"', f'"tcp/127.0.0.1:{port}"'))
    with zenohd(conf, f"tcp/127.0.0.1:{port}", tmp_path) as locator:
        assert subprocess.run(["sh", "-c", router_health_probe(port)]).returncode == 0, \
            "the router's health check misses zenohd's listening socket"
        procs, journal = play_compose_game(load_cluster(COMPOSE, **GAME_ENV), {ROUTER_ENDPOINT: locator}, tmp_path)
    check_game(procs, journal)


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.skipif(not COMPOSE_TLS.exists(), reason="no TLS variant")
def test_tls_compose_game_through_zenohd_with_access_control(tmp_path):
    """compose.tls.yaml: zenohd with its mutual-TLS + ACL config, certificates from `dronesim certs`,
    every entity presenting its own (the drone replicas the one of the id they claim)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed by dronesim certs")
    cluster = load_cluster(COMPOSE_TLS, **GAME_ENV)
    router = cluster["services"]["router"]
    config_src = DOCKER / mounts(router)[router["command"][router["command"].index("-c") + 1]]
    certs = tmp_path / "certs"
    kit = str(int(GAME_ENV["DRONES"]) + 1)  # the extra replica has a certificate: the coordinator refuses it
    made = subprocess.run([sys.executable, "-m", "dronesim", "certs", str(certs), "--drones", kit],
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    port = free_port()
    text = config_src.read_text()
    assert '"tls/0.0.0.0:7447"' in text and '"certs/' in text
    conf = tmp_path / "zenohd.json5"  # its certs/... paths are relative to the router's working dir
    conf.write_text(text.replace('"tls/0.0.0.0:7447"', f'"tls/127.0.0.1:{port}"').replace('"certs/', f'"{certs}/'))
    endpoint = next(e for e in flag_values(cluster["services"]["coordinator"]["command"], "--connect"))
    assert endpoint == "tls/router:7447"
    with zenohd(conf, f"tls/127.0.0.1:{port}", tmp_path) as locator:
        procs, journal = play_compose_game(cluster, {endpoint: locator, "/certs/": f"{certs}/"}, tmp_path)
    check_game(procs, journal)

