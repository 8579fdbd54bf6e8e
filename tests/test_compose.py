"""compose.yaml, checked where no Docker daemon runs: valid under the Compose Specification's
JSON schema (a copy in tests/compose/, its source and licence noted there); every command of
the project's image a command of the project (its ``--help`` runs, its options parse); every
``ADVISOR_*`` variable a field of :class:`app.service.config.Settings`, with values it takes;
the services named where the settings point (database, Redis, broker, the viewer's API); the
files it mounts present; Mosquitto's ACL doing what it says, on the machine's mosquitto; the
Dockerfile exposing the ports that listen beyond the container's loopback, and only those."""

from __future__ import annotations

import copy
import getpass
import json
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import jsonschema
import paho.mqtt.client as paho
import pytest
import typer
import yaml
from paho.mqtt.enums import CallbackAPIVersion

from app.cli import cli
from app.service.config import Settings
from app.service.mqtt import PACKET_HEADROOM, parse_url, subscriptions

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "compose.yaml"
SCHEMA = ROOT / "tests" / "compose" / "compose-spec.json"
DEPLOY = ROOT / "deploy"
MOSQUITTO = "/usr/sbin/mosquitto"
PASSWD = "/usr/bin/mosquitto_passwd"
MOSQUITTO_PUB = "/usr/bin/mosquitto_pub"
LOOPBACK = ("127.0.0.1", "localhost", "::1")
#: what .env gives (deploy/make_env.py makes it); any values do for these checks
DOTENV = {"POSTGRES_PASSWORD": "pg0123", "MQTT_PASSWORD": "mq0123", "ADVISOR_OPERATOR_KEY": "op0"}
VARIABLE = re.compile(r"\$\{(\w+)(?:(:?[?-])([^}]*))?\}")


def load() -> dict[str, Any]:
    raw: dict[str, Any] = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    return raw


def interpolate(value: Any, env: dict[str, str]) -> Any:
    """Compose's interpolation of ``${NAME}``, ``${NAME:?error}``, ``${NAME:-default}``."""
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    if not isinstance(value, str):
        return value

    def one(m: re.Match[str]) -> str:
        name, kind, rest = m.groups()
        if name in env and (env[name] or kind not in (":?", ":-")):
            return env[name]
        if kind and kind.endswith("?"):
            raise KeyError(f"{name}: {rest}")
        return rest or ""

    return VARIABLE.sub(one, value).replace("$$", "$")


def project(env: dict[str, str] | None = None) -> dict[str, Any]:
    resolved: dict[str, Any] = interpolate(load(), DOTENV if env is None else env)
    return resolved


def ours(compose: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The services that run the project's image (built from this repository)."""
    return {name: s for name, s in compose["services"].items() if "build" in s}


def environment(service: dict[str, Any]) -> dict[str, str]:
    env = service.get("environment", {})
    if isinstance(env, list):
        env = dict(item.split("=", 1) for item in env)
    return {k: str(v) for k, v in env.items()}


def dockerfile() -> list[tuple[str, str]]:
    """The Dockerfile's instructions, (NAME, arguments), continuation lines joined."""
    text = (ROOT / "Dockerfile").read_text(encoding="utf-8")
    joined = re.sub(r"\\\n", " ", "\n".join(line for line in text.splitlines()
                                           if not line.lstrip().startswith("#")))  # fmt: skip
    out = []
    for line in joined.splitlines():
        if line.strip():
            name, _, rest = line.strip().partition(" ")
            out.append((name.upper(), rest.strip()))
    return out


def image_env() -> dict[str, str]:
    """The ENV of the Dockerfile (what every container of the image starts with)."""
    env: dict[str, str] = {}
    for name, rest in dockerfile():
        if name == "ENV":
            env |= dict(item.split("=", 1) for item in shlex.split(rest))
    return env


def settings_of(env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> Settings:
    """Settings as a container with this environment reads them (nothing else of ours)."""
    for name in list(os.environ):
        if name.startswith("ADVISOR_"):
            monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    return Settings()


def option(args: list[str], name: str) -> str | None:
    return args[args.index(name) + 1] if name in args else None


# ---- the file itself ---------------------------------------------------------------------------
def test_compose_yaml_is_valid_under_the_compose_specification() -> None:
    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}"
              for e in validator.iter_errors(load())]  # fmt: skip
    assert not errors, errors
    # the schema does refuse what is wrong: a misspelt key, a condition there is not
    for path, value in ((("services", "advisor", "comand"), ["x"]),
                        (("services", "advisor", "depends_on"),
                         {"redis": {"condition": "service_ready"}})):  # fmt: skip
        broken = copy.deepcopy(load())
        broken[path[0]][path[1]][path[2]] = value
        assert not validator.is_valid(broken), path


def test_every_variable_it_needs_is_given_by_make_env(tmp_path: Path) -> None:
    """``${NAME:?...}``: compose refuses to start without them; deploy/make_env.py writes each
    (and refuses to replace an .env that exists)."""
    needed = {m.group(1) for m in VARIABLE.finditer(COMPOSE.read_text(encoding="utf-8"))}
    assert needed == set(DOTENV)
    with pytest.raises(KeyError, match="MQTT_PASSWORD"):
        project({k: v for k, v in DOTENV.items() if k != "MQTT_PASSWORD"})
    target = tmp_path / ".env"
    run = [sys.executable, str(DEPLOY / "make_env.py"), str(target)]
    assert subprocess.run(run, capture_output=True).returncode == 0
    made = dict(line.split("=", 1) for line in target.read_text().splitlines())
    assert set(made) == needed and all(re.fullmatch(r"[0-9a-f]{48,}", v) for v in made.values())
    assert target.stat().st_mode & 0o777 == 0o600
    again = subprocess.run(run, capture_output=True, text=True)
    assert again.returncode == 1 and "exists" in again.stderr
    assert dict(line.split("=", 1) for line in target.read_text().splitlines()) == made


# ---- commands and settings of the project ------------------------------------------------------
def commands() -> dict[str, list[str]]:
    """Every command the project's image runs: each service's, and the Dockerfile's CMD."""
    out = {name: list(s["command"]) for name, s in ours(project()).items()}
    (cmd,) = [rest for name, rest in dockerfile() if name == "CMD"]
    out["Dockerfile CMD"] = json.loads(cmd)
    return out


def parse(args: list[str]) -> dict[str, Any]:
    """``args`` (after ``python -m app``) as the command line parses them: its options' values;
    an error for an option that is not one, a value not of its type or not among its choices."""
    command: Any = typer.main.get_command(cli)
    rest = list(args)
    while hasattr(command, "commands"):  # a group: the next word names a command of it
        name, *rest = rest
        assert name in command.commands, f"no command {name}"
        command = command.commands[name]
    params: dict[str, Any] = command.make_context(" ".join(args), rest).params
    return params


def test_every_command_of_the_projects_image_is_one_of_its_commands() -> None:
    found = commands()
    assert {"advisor", "viewer", "Dockerfile CMD"} <= set(found)
    for where, argv in found.items():
        if argv[:3] == ["python", "-m", "app"]:
            args = argv[3:]
        else:
            assert argv[0] == "advisor", f"{where}: {argv} is not `python -m app` nor `advisor`"
            args = argv[1:]
        path = [a for a in args if not a.startswith("-")][:1]
        run = subprocess.run(
            [sys.executable, "-m", "app", *path, "--help"], cwd=ROOT, capture_output=True,
            text=True, env=os.environ | {"COLUMNS": "200"},
        )  # fmt: skip
        assert run.returncode == 0, f"{where}: {run.stderr}"
        for arg in args:
            if arg.startswith("--"):
                assert arg in run.stdout, f"{where}: `{' '.join(path)}` has no {arg}"
        parse(args)  # every option known, every value of its type and among its choices
    with pytest.raises(Exception, match="No such option: --hots"):
        parse(["serve", "--hots", "0.0.0.0"])  # what a misspelt command gets
    assert parse(["serve", "--port", "8000", "--no-viewer"])["no_viewer"] is True


def test_every_advisor_variable_is_a_setting_and_the_image_takes_its_value(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fields = {f"ADVISOR_{name.upper()}" for name in Settings.model_fields}
    base = image_env()
    assert {n for n in base if n.startswith("ADVISOR_")} <= fields
    for name, service in ours(project()).items():
        env = environment(service)
        unknown = sorted(n for n in env if n.startswith("ADVISOR_") and n not in fields)
        assert not unknown, f"{name}: {unknown} are not settings (app/service/config.py)"
        settings_of(base | env, monkeypatch)  # ValidationError for a value it refuses


def test_the_service_listens_on_every_interface_and_the_ports_are_those_published(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    services = ours(project())
    by_command = {s["command"][3]: (n, s) for n, s in services.items()}
    _, api = by_command["serve"]
    settings = settings_of(image_env() | environment(api), monkeypatch)
    argv = api["command"]
    host = option(argv, "--host") or settings.host
    port = int(option(argv, "--port") or settings.port)
    assert host == "0.0.0.0"  # reachable from the other containers and the published port
    assert "--no-viewer" in argv or not settings.viewer_enabled  # the viewer: its own service
    assert [p.rsplit(":", 1)[-1] for p in api["ports"]] == [str(port)]
    viewer_name, viewer = by_command["viewer"]
    vargv = viewer["command"]
    assert option(vargv, "--host") == "0.0.0.0"
    assert [p.rsplit(":", 1)[-1] for p in viewer["ports"]] == [option(vargv, "--port")]
    target = urlsplit(option(vargv, "--api") or "")
    assert services[target.hostname or ""] is api and target.port == port
    assert (
        environment(viewer)["ADVISOR_OPERATOR_KEY"] == environment(api)["ADVISOR_OPERATOR_KEY"]
    )  # the key the service takes for its operators
    check = viewer["healthcheck"]["test"]  # the image's own would ask for the API
    assert check[:3] == ["CMD", "python", "-c"] and f"{option(vargv, '--port')})" in check[3]
    compile(check[3], f"{viewer_name}'s health check", "exec")
    compose = project()
    for service in compose["services"].values():  # published on the host's loopback only
        for published in service.get("ports", []):
            assert published.split(":")[0] in LOOPBACK, published


def test_the_settings_name_the_services_that_hold_what_they_point_at(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    compose = project()
    services = compose["services"]
    (api,) = [s for s in ours(compose).values() if s["command"][3] == "serve"]
    settings = settings_of(image_env() | environment(api), monkeypatch)
    database = urlsplit(settings.db_url)
    postgres = environment(services[database.hostname or ""])
    assert (database.username, database.password, database.path.lstrip("/")) == (
        postgres["POSTGRES_USER"], postgres["POSTGRES_PASSWORD"], postgres["POSTGRES_DB"]
    )  # fmt: skip
    assert database.scheme == "postgresql+psycopg"
    redis = urlsplit(settings.redis_url or "")
    assert "redis" in services[redis.hostname or ""]["image"] and settings.workers > 1
    broker = parse_url(settings.mqtt_url or "")
    mosquitto = services[broker.host]
    assert "mosquitto" in mosquitto["image"] and broker.port == 1883
    assert broker.password == environment(mosquitto)["MQTT_PASSWORD"]
    acl = (DEPLOY / "mosquitto" / "acl").read_text(encoding="utf-8")
    assert f"user {broker.username}\ntopic read {settings.mqtt_prefix}/#\n" in acl
    for service in services.values():
        assert set(service.get("depends_on", {})) <= set(services)


def test_the_files_it_mounts_exist_and_mosquitto_reads_them_where_they_are() -> None:
    mosquitto = project()["services"]["mosquitto"]
    mounts = dict(v.split(":")[:2] for v in mosquitto["volumes"])
    for source in mounts:
        if source.startswith("."):
            assert (ROOT / source).is_file(), source
    conf = dict(
        line.split(None, 1)
        for line in (DEPLOY / "mosquitto" / "mosquitto.conf").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    )
    assert conf["allow_anonymous"] == "false" and conf["listener"] == "1883"
    assert mounts["./deploy/mosquitto/acl"] == conf["acl_file"]
    start = (DEPLOY / "mosquitto" / "start.sh").read_text()
    assert mounts["./deploy/mosquitto/start.sh"] in " ".join(mosquitto["command"])
    assert f"-c {mounts['./deploy/mosquitto/mosquitto.conf']}" in start
    assert f"passwords={conf['password_file']}\n" in start  # where it writes the service's user
    volume_dirs = [t for s, t in mounts.items() if not s.startswith(".")]
    assert any(conf["password_file"].startswith(d + "/") for d in volume_dirs)  # kept
    assert subprocess.run(["sh", "-n", str(DEPLOY / "mosquitto" / "start.sh")]).returncode == 0


def test_the_dockerfile_exposes_what_listens_beyond_loopback_and_only_that(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The image's CMD serves the API on ``--host``; the viewer that ``serve`` starts listens
    on ``ADVISOR_VIEWER_HOST``, loopback unless the image's environment says otherwise."""
    settings = settings_of(image_env(), monkeypatch)
    (cmd,) = [json.loads(rest) for name, rest in dockerfile() if name == "CMD"]
    host, port = option(cmd, "--host") or settings.host, option(cmd, "--port") or settings.port
    listening = {str(port)} if host not in LOOPBACK else set()
    if (
        settings.viewer_enabled
        and "--no-viewer" not in cmd
        and (settings.viewer_host not in LOOPBACK)
    ):
        listening.add(str(settings.viewer_port))
    exposed = {p for name, rest in dockerfile() if name == "EXPOSE" for p in rest.split()}
    assert exposed == listening == {"8000"}


# ---- Mosquitto's ACL, on a broker of the test's own ---------------------------------------------
class Device:
    """An MQTT v5 client (paho, its network thread) of one user; keeps what it receives."""

    def __init__(self, port: int, user: str | None, password: str | None = None):
        self.client = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv5)
        if user is not None:
            self.client.username_pw_set(user, password)
        self.got: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.connected = threading.Event()
        self.answered = threading.Event()
        self.refused: Any = None
        self.subscribed = threading.Event()
        self.client.on_connect = self._connect
        self.client.on_subscribe = lambda *_: self.subscribed.set()
        self.client.on_message = self._message
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        assert self.answered.wait(10), "no CONNACK"

    def _connect(self, _c: Any, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        if reason.is_failure:
            self.refused = reason
        else:
            self.connected.set()
        self.answered.set()

    def _message(self, _c: Any, _u: Any, message: paho.MQTTMessage) -> None:
        with self.lock:
            self.got.append((message.topic, bytes(message.payload)))

    def subscribe(self, *topics: str) -> None:
        self.subscribed.clear()
        self.client.subscribe([(t, 1) for t in topics])
        assert self.subscribed.wait(10)

    def publish(self, topic: str, payload: str) -> None:
        self.client.publish(topic, payload.encode(), qos=1).wait_for_publish(10)

    def received(self) -> set[tuple[str, str]]:
        with self.lock:
            return {(t, p.decode()) for t, p in self.got}

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def deploy_broker(workdir: Path, users: dict[str, str]) -> tuple[subprocess.Popen[bytes], int]:
    """Mosquitto with deploy/mosquitto/mosquitto.conf and its ACL file as compose runs them,
    on a free port of loopback (returned with the process), with a password file of
    ``users``."""
    passwords = workdir / "passwd"
    passwords.touch(mode=0o600)
    for user, password in users.items():
        subprocess.run([PASSWD, "-b", str(passwords), user, password], check=True)
    port = free_port()
    here = {
        "listener": f"{port} 127.0.0.1", "password_file": str(passwords),
        "acl_file": str(DEPLOY / "mosquitto" / "acl"), "persistence_location": f"{workdir}/",
    }  # fmt: skip
    lines = []
    for line in (DEPLOY / "mosquitto" / "mosquitto.conf").read_text().splitlines():
        key = line.split(None, 1)[0] if line.strip() else ""
        lines.append(f"{key} {here[key]}" if key in here else line)
    # started as root, Mosquitto would run as the user "mosquitto", who cannot read workdir
    lines.append(f"user {getpass.getuser()}")
    conf = workdir / "mosquitto.conf"
    conf.write_text("\n".join(lines) + "\n")
    proc = subprocess.Popen([MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    deadline = time.monotonic() + 10
    while True:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc, port
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.terminate()
                raise AssertionError("mosquitto failed to start") from None
            time.sleep(0.05)


def needs_mosquitto() -> None:
    if shutil.which(MOSQUITTO) is None or shutil.which(PASSWD) is None:
        pytest.skip(f"{MOSQUITTO} and {PASSWD} are not installed (apt-get install mosquitto)")


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[tuple[int, dict[str, str]]]:
    """:func:`deploy_broker` with the service's user, the set-up user and two devices."""
    needs_mosquitto()
    users = {
        "advisor": "service-pw", "setup": "setup-pw", "robot-7": "seven-pw",
        "robot-8": "eight-pw",
    }  # fmt: skip
    proc, port = deploy_broker(tmp_path, users)
    try:
        yield port, users
    finally:
        proc.terminate()
        proc.wait(10)


def test_mosquittos_acl_lets_a_device_publish_and_read_only_its_own_topics(
    broker: tuple[int, dict[str, str]],
) -> None:
    """Both forms of the topics: ``advisor/<device>/<domain>/<explorer>/<kind>`` and the short
    ``advisor/<domain>/<explorer>/<kind>`` (the explorer its own device). A device writes
    events and reads decisions and errors under its own user name only, whatever it
    subscribes to; only the service reads every topic; configs are the set-up user's."""
    port, users = broker
    service = Device(port, "advisor", users["advisor"])
    setup = Device(port, "setup", users["setup"])
    seven = Device(port, "robot-7", users["robot-7"])
    eight = Device(port, "robot-8", users["robot-8"])
    try:
        service.subscribe(*subscriptions("advisor"))  # as the bridge does
        seven.subscribe("advisor/#")  # greedy: it gets its own topics only
        eight.subscribe("advisor/+/+/decisions", "advisor/+/+/events",
                        "advisor/+/+/+/decisions", "advisor/+/+/+/events")  # fmt: skip
        # the device form
        seven.publish("advisor/robot-7/default/e1/events", "own event")
        seven.publish("advisor/robot-8/default/e1/events", "forged event")
        seven.publish("advisor/robot-8/default/robot-7/decisions", "forged decision")
        seven.publish("advisor/robot-7/default/e1/config", "its own config")
        setup.publish("advisor/robot-7/default/e1/config", "a config")
        service.publish("advisor/robot-7/default/e1/decisions", "for 7's e1")
        service.publish("advisor/robot-7/default/e1/errors", "error for 7's e1")
        # 8's explorer that has 7's name: 8's, not 7's
        service.publish("advisor/robot-8/default/robot-7/decisions", "for 8's robot-7")
        # the short form
        seven.publish("advisor/default/robot-7/events", "own short event")
        seven.publish("advisor/default/robot-8/events", "forged short event")
        seven.publish("advisor/lobby/robot-8/decisions", "forged short decision")
        seven.publish("advisor/default/robot-7/config", "its own short config")
        setup.publish("advisor/default/robot-7/config", "a short config")
        service.publish("advisor/default/robot-7/decisions", "for 7")
        service.publish("advisor/lobby/robot-8/decisions", "for 8")
        service.publish("advisor/default/robot-7/errors", "error for 7")
        wanted = {
            service: {("advisor/robot-7/default/e1/events", "own event"),
                      ("advisor/robot-7/default/e1/config", "a config"),
                      ("advisor/default/robot-7/events", "own short event"),
                      ("advisor/default/robot-7/config", "a short config")},
            seven: {("advisor/robot-7/default/e1/decisions", "for 7's e1"),
                    ("advisor/robot-7/default/e1/errors", "error for 7's e1"),
                    ("advisor/default/robot-7/decisions", "for 7"),
                    ("advisor/default/robot-7/errors", "error for 7")},
            eight: {("advisor/robot-8/default/robot-7/decisions", "for 8's robot-7"),
                    ("advisor/lobby/robot-8/decisions", "for 8")},
        }  # fmt: skip
        deadline = time.monotonic() + 10
        while any(d.received() != w for d, w in wanted.items()) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)  # and nothing more comes
        for device, want in wanted.items():
            assert device.received() == want
    finally:
        for device in (service, setup, seven, eight):
            device.close()
    for user, password in ((None, None), ("robot-7", "wrong")):  # no password, a wrong one
        refused = Device(port, user, password)
        refused.close()
        assert refused.refused is not None and not refused.connected.is_set()


def mosquitto_pub(port: int, user: str, password: str, topic: str, payload: Path) -> str:
    """``mosquitto_pub`` (MQTT v5, QoS 1, debug output): what it says about the publish."""
    run = subprocess.run(
        [MOSQUITTO_PUB, "-h", "127.0.0.1", "-p", str(port), "-u", user, "-P", password,
         "-V", "5", "-q", "1", "-d", "-t", topic, "-f", str(payload)],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    return run.stdout + run.stderr


def test_mosquittos_size_limits_are_the_services_and_a_publisher_is_told(
    broker: tuple[int, dict[str, str]], tmp_path: Path
) -> None:
    """deploy/mosquitto/mosquitto.conf's ``message_size_limit`` is the service's
    ADVISOR_MAX_BODY_BYTES and its ``max_packet_size`` the bridge's Maximum Packet Size (the
    service's settings as compose runs it). A device's message over the first is refused,
    its PUBACK saying so (reason 149, packet too large); one over the second is not sent by an
    MQTT v5 client (Mosquitto told it the maximum when it connected), and an MQTT 3.1.1 client
    that sends one is disconnected; none of them reaches the service; a message within both
    does."""
    if shutil.which(MOSQUITTO_PUB) is None:
        pytest.skip(f"{MOSQUITTO_PUB} is not installed (apt-get install mosquitto-clients)")
    conf = dict(
        line.split(None, 1)
        for line in (DEPLOY / "mosquitto" / "mosquitto.conf").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    )
    settings = Settings()  # compose sets no size: the defaults
    assert int(conf["message_size_limit"]) == settings.max_body_bytes
    assert int(conf["max_packet_size"]) == settings.max_body_bytes + PACKET_HEADROOM
    port, users = broker
    service = Device(port, "advisor", users["advisor"])
    try:
        service.subscribe("advisor/+/+/+/events")
        sizes = {"fits": settings.max_body_bytes, "over-limit": settings.max_body_bytes + 1,
                 "over-packet": settings.max_body_bytes + PACKET_HEADROOM}  # fmt: skip
        said = {}
        for name, size in sizes.items():
            payload = tmp_path / name
            payload.write_bytes(b"x" * size)
            said[name] = mosquitto_pub(
                port, "robot-7", users["robot-7"], f"advisor/robot-7/default/{name}/events",
                payload,
            )  # fmt: skip
        assert "received PUBACK (Mid: 1, RC:0)" in said["fits"], said["fits"]
        assert "received PUBACK (Mid: 1, RC:149)" in said["over-limit"], said["over-limit"]
        assert "sending PUBLISH" not in said["over-packet"], said["over-packet"]
        old = paho.Client(CallbackAPIVersion.VERSION2, protocol=paho.MQTTv311)
        old.username_pw_set("robot-7", users["robot-7"])
        gone = threading.Event()
        old.on_disconnect = lambda *_: gone.set()
        old.connect("127.0.0.1", port)
        old.loop_start()
        try:
            big = b"x" * (settings.max_body_bytes + PACKET_HEADROOM)
            old.publish("advisor/robot-7/default/old-client/events", big, qos=1)
            assert gone.wait(10), "the broker kept the client that sent a packet too large"
        finally:
            old.loop_stop()
        deadline = time.monotonic() + 10
        while not service.received() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.3)  # and nothing more comes
        assert [t for t, _ in service.received()] == ["advisor/robot-7/default/fits/events"]
    finally:
        service.close()


@pytest.mark.skipif(
    shutil.which("docker-compose") is None,
    reason="Debian's docker-compose is not installed (apt-get install docker-compose); the "
    "schema's check above runs everywhere",
)
def test_debians_docker_compose_reads_it() -> None:
    """docker-compose 1.29.2 (Debian's) reads the file as Docker Compose would (no daemon
    needed): interpolation, merge keys, its own schema."""
    run = subprocess.run(
        ["docker-compose", "-f", str(COMPOSE), "config", "-q"], cwd=ROOT, capture_output=True,
        text=True, env=os.environ | DOTENV,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
