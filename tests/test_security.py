"""Security: TLS, mutual TLS, user/password, and the router's access control generated from the key table.

Unit tests: the ACL that schema/acl.py derives from KEY_TABLE grants every key to exactly its writer (and
nothing else to anyone), config/ holds what the generator writes, `dronesim certs` issues the right
certificates, and the security flags make the right zenoh config.

Integration tests, each against a real router -- an embedded Python router (a `zenoh.open` session in
router mode, configured by the very flags `dronesim router` takes: --tls-*, --users-file, --acl) and
`zenohd` (configured by the whole router config `python -m schema.acl --router-config` writes)
-- and with either identity (user/password over TLS, or mutual TLS where the certificate's CN names the
principal):

* no, wrong or untrusted credentials cannot open a session; a principal the ACL does not know cannot
  get or put anything;
* a spoofed NPS for another drone, a target from a drone, a fake OVER/TURN/STATUS from a non-coordinator,
  a DONE or UPD from the wrong role, a second queryable on ENV/ASK (or SRV/CONNECT) and a presence token
  under another entity's name are all dropped by the router;
* a real game (every entity a process with its own credentials, the ground station joining by name
  over TLS with the example client config of config/) under those attacks ends with the same journal as
  an unattacked one, and no process ever sees (and so never has to reject) a forbidden message.

How "this message must NOT arrive" is proven without sleeping
-----------------------------------------------------------
A message that does not arrive leaves no event to wait for, so each negative check waits for a positive
*barrier* that the forbidden message would have had to precede:

* Puts. The attacker, after its forbidden puts, puts a *marker* on a key it IS allowed to write, from the
  same session, with the same priority (data), reliability and congestion control. Zenoh keeps the order
  of one session's messages of one priority: they leave on one link, in order; the router handles one
  link's input in order, and forwards what it accepts to the receiver's single link, in order; the
  receiver's callbacks run in that order on its link's thread -- *direct* callbacks, that is: by
  default zenoh-python runs each Python callback on a thread of its own, and two subscriptions'
  callbacks may then run out of arrival order (`direct()` below). So once the receiver holds the marker,
  a forbidden put that the router had let through would already be in the receiver's list. A positive
  control (the legitimate writer puts on each of the same keys, then its own marker) proves the
  receiver's subscriptions do deliver those keys.
* An attacker the ACL does not know at all has no key to put a marker on. It then follows its forbidden
  put with a query: clients send every query to their router (zenoh's client routing), the router
  handles the put before the query, and the query's final answer (the router refuses the query: no
  reply, an immediate end) comes back only after the put has been dropped or forwarded. Then the
  receiver makes a query of its own to a legitimate queryable: its reply reaches the receiver on the
  same link and priority as the forwarded put would have, so after it.
* Declarations (a queryable, a liveliness token) travel at zenoh's control priority, in order within a
  session. The attacker declares its forbidden queryable, then its own (allowed) presence token: when
  the token is seen elsewhere, the router has already handled the queryable's declaration. A query then
  gets every reply of every queryable the router registered (it ends when all have answered, and the
  attackers' queryables would answer at once): only the legitimate ones answer, and the attackers'
  callbacks never run. A positive control (a second legitimate queryable) proves several answers do
  come back.

In the game, no sleep either: the attacker acts on the coordinator's TURN messages, and the journal
comparison, plus "the coordinator rejected nothing and no entity mentions a forged turn", prove nothing
forbidden reached anyone in time to matter.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import queue
import re
import socket
import stat
import subprocess
import threading
from pathlib import Path

import pytest
import zenoh

from dronesim import certs
from network.transport import add_zenoh_args, router_locators, zenoh_config
from schema import (
    KEY_TABLE,
    CellKind,
    Done,
    DroneState,
    DroneStatus,
    EndReason,
    Intent,
    Keys,
    KeySpec,
    Nps,
    Over,
    Phase,
    Refused,
    Status,
    Target,
    Turn,
    Upd,
    UsageError,
    acl,
    decode,
    encode,
)
from schema.tuning import PUT_RATE, TGT_RATE
from tests.harness import Cluster, ask_until_replied, zenohd

ROOT = Path(__file__).resolve().parent.parent
CONFIG = ROOT / "config"
ACL_DRONES = ("D01", "D02")  # the deployment's drones; the games fly D01, D02 is an attacker's identity
HOSTS = {"H01": ("D03", "D04")}  # a swarm host of the deployment, another attacker's identity
STRANGER = "EVIL"  # authenticated (a CA-signed certificate, a password in the dictionary) but in no ACL subject
IDENTITIES = ("usrpwd", "cert")
TIMEOUT = 30.0
BLOCK = zenoh.CongestionControl.BLOCK


# --------------------------------------------------------------------------- unit: the ACL


def concrete_keys(spec: KeySpec, root: str, names: list[str], drones: list[str]) -> list[str]:
    """Every concrete key a key-table row stands for, in a deployment of these principals and drones."""
    keys = [spec.template]
    for placeholder, values in (("{drone}", drones), ("{entity}", names), ("{session}", ["a1b2c3"]),
                                ("{phase}", ["GCS", "DRONES", "ENV"])):
        keys = [k.replace(placeholder, v) for k in keys for v in values] if any(placeholder in k for k in keys) \
            else keys
    return [f"{root}/{k}" for k in keys]


def write_message(how: str) -> str:
    return {"put": "put", "query": "declare_queryable", "liveliness": "liveliness_token"}[how]


def writer_of(spec, key: str, root: str, principals: list[acl.Principal]) -> set[str]:
    """Who the key table says may write `key`: its writer role; for a drone's key, the principal flying
    that drone; for an entity's own key (presence), that entity."""
    entity = key[len(root) + 1:].split("/")[0]
    if spec.writer == "each entity":
        return {entity}
    if spec.writer == "DRONE" and "{entity}" in spec.template:  # a drone process's own key (a host's MOVES)
        return {p.name for p in principals if p.role == "DRONE" and p.name == entity}
    if spec.writer == "DRONE":
        return {p.name for p in principals if entity in p.drones}
    return {p.name for p in principals if p.role == spec.writer}


def test_acl_grants_every_key_of_the_table_to_exactly_its_writer():
    roots = ["sim", "other/game"]
    principals = acl.principals(["D01", "D02", "D05"], {"H01": ("D03", "D04")})
    names = [p.name for p in principals]
    block = acl.access_control(["D01", "D02", "D05"], roots=roots, identity="usrpwd", hosts={"H01": ("D03", "D04")})
    assert block["default_permission"] == "deny" and block["enabled"]
    assert {s["id"] for s in block["subjects"]} == set(names) == {"SRV", "ENV", "GCS", "D01", "D02", "D05", "H01"}
    assert all(r["permission"] == "allow" for r in block["rules"]), "default-deny: the generator writes only allows"
    assert len({s["usernames"][0] for s in block["subjects"]}) == len(block["subjects"]), "subjects must not overlap"
    drones = ["D01", "D02", "D03", "D04", "D05", "D09"]  # D09: in no game of this deployment
    for root in roots:
        for spec in KEY_TABLE:
            message = write_message(spec.how)
            keys = concrete_keys(spec, root, names, drones)
            assert keys, spec
            for key in keys:
                writers = {p for p in names if acl.allowed(block, p, "ingress", message, key)}
                assert writers == writer_of(spec, key, root, principals), (key, message)
                if spec.how == "query":  # the queryable's owner is the only one who may answer
                    assert {p for p in names if acl.allowed(block, p, "ingress", "reply", key)} == writers, key
                for p in principals:  # nobody deletes anything
                    assert not acl.allowed(block, p.name, "ingress", "delete", key)
            # readers can read it: subscribe to / query / watch the key the way the entities do
            for p in principals:
                if p.role not in acl.readers_of(spec):
                    continue
                wildcard = concrete_keys(spec, root, ["*"], ["*"])[0]
                match spec.how:
                    case "put":
                        assert acl.allowed(block, p.name, "ingress", "declare_subscriber", wildcard), (p, wildcard)
                        assert acl.allowed(block, p.name, "egress", "put", keys[0])
                    case "query":
                        own = concrete_keys(spec, root, [p.name], list(p.drones) or ["*"])[0]
                        assert acl.allowed(block, p.name, "ingress", "query", own), (p, own)
                        assert acl.allowed(block, p.name, "egress", "reply", own)
                    case "liveliness":
                        assert acl.allowed(block, p.name, "ingress", "declare_liveliness_subscriber", wildcard)
                        assert acl.allowed(block, p.name, "egress", "liveliness_token", keys[0])
    # nothing outside the roots, for anyone, in any direction
    for p in names:
        for message in acl.MESSAGES:
            for flow in ("ingress", "egress"):
                assert not acl.allowed(block, p, flow, message, "elsewhere/D01/NPS")
                assert not acl.allowed(block, p, flow, message, "@/router/x")


def test_acl_swarm_hosts_fly_their_drones_only():
    block = acl.access_control(["D01", "D02", "D03"], hosts={"H01": ("D02", "D03")})
    assert acl.allowed(block, "H01", "ingress", "put", "sim/D02/NPS")
    assert acl.allowed(block, "H01", "ingress", "put", "sim/D03/NPS")
    assert not acl.allowed(block, "H01", "ingress", "put", "sim/D01/NPS")
    assert not acl.allowed(block, "D02", "ingress", "put", "sim/D02/NPS"), "a hosted drone is not its own principal"
    assert "D02" not in {s["id"] for s in block["subjects"]}
    assert acl.allowed(block, "H01", "ingress", "liveliness_token", "sim/H01/ALIVE/0123abcd")
    assert not acl.allowed(block, "H01", "ingress", "liveliness_token", "sim/D02/ALIVE/0123abcd")
    with pytest.raises(ValueError, match="flown by both"):
        acl.access_control(["D01"], hosts={"H01": ("D01",), "H02": ("D01",)})
    assert acl.parse_hosts(["H01=D01-D03", "H02=D05,D07"]) == {"H01": ("D01", "D02", "D03"), "H02": ("D05", "D07")}
    for bad in ("H01=foo", "H01=3-1", "H01=D01,D01", "H01"):
        assert acl.main(["--drones", "4", "--host", bad, "--identity", "usrpwd"]) == 2, bad


def test_acl_a_spare_host_may_fly_every_drone_which_keep_their_own_principals():
    """docker/compose.yaml's swarm profile: H01 may fly the game in place of the drone processes; each drone keeps
    its own principal (the drone replicas hold every drone's credentials anyway); the other roles' keys stay theirs."""
    block = acl.access_control(["D01", "D02"], spare_hosts=["H01"])
    assert sorted(s["id"] for s in block["subjects"]) == ["D01", "D02", "ENV", "GCS", "H01", "SRV"]
    for who in ("H01", "D01"):
        assert acl.allowed(block, who, "ingress", "put", "sim/D01/NPS")
    assert acl.allowed(block, "H01", "ingress", "put", "sim/D02/NPS")
    assert not acl.allowed(block, "D01", "ingress", "put", "sim/D02/NPS")
    assert acl.allowed(block, "H01", "ingress", "put", "sim/H01/MOVES")
    for key in ("sim/D01/TGT", "sim/GCS/DONE", "sim/OBS/STATUS", "sim/SRV/OVER", "sim/SRV/TURN/DRONES"):
        assert not acl.allowed(block, "H01", "ingress", "put", key), key
    for bad in (["D03"], ["H01", "H01x"]):
        with pytest.raises(ValueError, match="spare"):
            acl.access_control(["D01"], spare_hosts=bad)
    with pytest.raises(ValueError, match="spare"):
        acl.access_control(["D01"], hosts={"H01": ("D01",)}, spare_hosts=["H01"])


def test_game_credentials_are_kept_and_each_role_gets_its_share_alone(tmp_path, capsys):
    """`dronesim certs DIR --game --by-role OUT` (docker/compose.yaml's credentials service): the router's zenohd
    config besides the kit, and each role's share in OUT: the CA's certificate and that role's passwords alone.
    Made again, nothing changes; a password no longer in the kit leaves its share."""
    kit, out = tmp_path / "kit", tmp_path / "out"
    argv = [str(kit), "--game", "--drones", "2", "--spare-host", "H01", "--by-role", str(out)]
    assert certs.cli(argv) == 0
    assert f"zenohd -c {kit / 'router.json5'}" in capsys.readouterr().out
    shares = {share.name: sorted(f.name for f in share.iterdir()) for share in out.iterdir()}
    assert shares == {"SRV": ["SRV.password", "ca.pem"], "ENV": ["ENV.password", "ca.pem"],
                      "GCS": ["GCS.password", "ca.pem"],
                      "drones": ["D01.password", "D02.password", "H01.password", "ca.pem"]}
    assert (out / "drones" / "D02.password").read_text() == (kit / "D02.password").read_text()
    assert (out / "drones" / "D02.password").stat().st_mode & 0o777 == 0o600
    conf = zenoh.Config.from_file(str(kit / "router.json5"))
    assert json.loads(conf.get_json("listen/endpoints")) == ["tls/0.0.0.0:7447"]
    assert json.loads(conf.get_json("transport/auth/usrpwd/dictionary_file")) == str(kit / "users.txt")
    before = {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()}
    assert certs.cli(argv) == 0
    assert {f: f.read_bytes() for f in tmp_path.rglob("*") if f.is_file()} == before
    (kit / "D02.password").unlink()
    assert certs.cli([str(kit), "--game", "--drones", "1", "--spare-host", "H01", "--by-role", str(out)]) == 0
    assert sorted(f.name for f in (out / "drones").iterdir()) == ["D01.password", "H01.password", "ca.pem"]
    assert certs.cli([str(kit), "--by-role", str(out)]) == 2, "--by-role goes with --game"


def test_acl_binds_a_per_entity_query_key_to_its_asker(monkeypatch):
    """Were admission keyed by entity (SRV/CONNECT/{entity}, see docs/security.md), the generated ACL
    would let each principal ask only as itself, and the coordinator serve them all."""
    row = KeySpec("SRV/CONNECT/{entity}", "query", None, None, "SRV", "ENV, GCS, drones", "admission")
    monkeypatch.setattr(acl, "KEY_TABLE", (row,))
    block = acl.access_control(["D01", "D02"])
    assert acl.allowed(block, "SRV", "ingress", "declare_queryable", "sim/SRV/CONNECT/*")
    assert acl.allowed(block, "D01", "ingress", "query", "sim/SRV/CONNECT/D01")
    assert not acl.allowed(block, "D01", "ingress", "query", "sim/SRV/CONNECT/D02")
    assert not acl.allowed(block, "D01", "ingress", "query", "sim/SRV/CONNECT/GCS")
    assert acl.allowed(block, "GCS", "ingress", "query", "sim/SRV/CONNECT/GCS")


def test_acl_identities_name_principals_by_user_certificate_or_both():
    for identity, fields in (("usrpwd", {"usernames"}), ("cert", {"cert_common_names"}),
                             ("both", {"usernames", "cert_common_names"})):
        block = acl.access_control(["D01"], identity=identity)
        for s in block["subjects"]:
            assert set(s) - {"id"} == fields and all(s[f] == [s["id"]] for f in fields)
    with pytest.raises(ValueError):
        acl.access_control(["D01"], identity="password")


def test_config_folder_is_what_the_generator_writes():
    files = acl.examples()
    for name, text in files.items():
        assert (CONFIG / name).read_text() == text, \
            f"config/{name} is stale: run python -m schema.acl --write-examples config/"
    for name in files:  # each is a valid zenoh config (the ACL alone is a partial one)
        zenoh.Config.from_file(str(CONFIG / name))


def test_generator_command_line(tmp_path, capsys):
    assert acl.main(["--drones", "3", "--root", "sim", "--identity", "cert", "--host", "H01=D02-D03"]) == 0
    out = tmp_path / "acl.json5"
    out.write_text(capsys.readouterr().out)
    block = json.loads(zenoh.Config.from_file(str(out)).get_json("access_control"))
    assert {s["id"] for s in block["subjects"]} == {"SRV", "ENV", "GCS", "D01", "H01"}
    assert acl.main(["--drones", "2", "--router-config", "--certs", "/etc/ds"]) == 0
    out.write_text(capsys.readouterr().out)
    conf = json.loads(zenoh.Config.from_file(str(out)).get_json("transport"))
    assert conf["link"]["tls"]["listen_certificate"] == "/etc/ds/router.pem"
    assert conf["auth"]["usrpwd"]["dictionary_file"] == "/etc/ds/users.txt"
    assert acl.main(["--host", "X1=D01"]) == 2


# --------------------------------------------------------------------------- unit: certificates, flags


def x509_text(path: Path) -> str:
    return subprocess.run(["openssl", "x509", "-in", str(path), "-noout", "-text"], capture_output=True, text=True,
                          check=True).stdout


@pytest.fixture(scope="module")
def kit(tmp_path_factory) -> Path:
    """A development kit for the deployment: CA, router, SRV/ENV/GCS/D01/D02/H01 and a stranger."""
    folder = tmp_path_factory.mktemp("certs")
    k = certs.make(folder, drones=ACL_DRONES, hosts=HOSTS, passwords=True)
    k.issue(STRANGER)
    k.password(STRANGER)
    k.users()
    return folder


@pytest.fixture(scope="module")
def rogue(tmp_path_factory) -> Path:
    """Another CA's kit: same names, untrusted by the deployment."""
    folder = tmp_path_factory.mktemp("rogue")
    certs.make(folder, drones=ACL_DRONES, passwords=True)
    return folder


def test_certs_issue_a_ca_a_router_and_one_certificate_per_role(kit):
    assert "CA:TRUE" in x509_text(kit / "ca.pem")
    router = x509_text(kit / "router.pem")
    assert "Subject: CN = router" in router
    assert re.search(r"DNS:localhost, IP Address:127\.0\.0\.1, IP Address:0:0:0:0:0:0:0:1", router), router
    assert "TLS Web Server Authentication" in router
    for entity in ("SRV", "ENV", "GCS", "D01", "D02", "H01"):
        text = x509_text(kit / f"{entity}.pem")
        assert f"Subject: CN = {entity}" in text and "CA:FALSE" in text and "TLS Web Client Authentication" in text
        assert stat.S_IMODE((kit / f"{entity}.key").stat().st_mode) == 0o600
        assert stat.S_IMODE((kit / f"{entity}.password").stat().st_mode) == 0o600
    verify = subprocess.run(["openssl", "verify", "-CAfile", str(kit / "ca.pem"),
                             *(str(kit / f"{e}.pem") for e in ("router", "SRV", "D01", "H01"))],
                            capture_output=True, text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    users = dict(line.split(":", 1) for line in (kit / "users.txt").read_text().splitlines())
    assert users["GCS"] == (kit / "GCS.password").read_text().strip() and len(users["GCS"]) >= 24
    assert set(users) == {"SRV", "ENV", "GCS", "D01", "D02", "H01", STRANGER}


def test_certs_command_keeps_what_exists_and_names_the_router_host(tmp_path):
    folder = tmp_path / "c"
    assert certs.cli([str(folder), "--drones", "1", "--router-host", "sim.example.org",
                      "--router-host", "10.1.2.3"]) == 0
    text = x509_text(folder / "router.pem")
    assert "DNS:sim.example.org" in text and "IP Address:10.1.2.3" in text
    ca, d01 = (folder / "ca.pem").read_bytes(), (folder / "D01.pem").read_bytes()
    assert certs.cli([str(folder), "--drones", "2"]) == 0
    assert (folder / "ca.pem").read_bytes() == ca and (folder / "D01.pem").read_bytes() == d01
    assert (folder / "D02.pem").exists() and not (folder / "users.txt").exists()
    router = (folder / "router.pem").read_bytes()
    assert certs.cli([str(folder), "--router-host", "sim.example.org"]) == 0
    assert (folder / "router.pem").read_bytes() == router  # the name is in it: kept
    assert certs.cli([str(folder), "--router-host", "other.example.org"]) == 0
    text = x509_text(folder / "router.pem")  # a new name: re-issued, with the names it had
    assert "DNS:other.example.org" in text and "DNS:sim.example.org" in text and "IP Address:10.1.2.3" in text
    assert certs.cli([str(folder), "--drones", "1", "--force"]) == 0
    assert (folder / "ca.pem").read_bytes() == ca and (folder / "D01.pem").read_bytes() != d01
    assert certs.cli([str(folder), "--host", "X9"]) == 2
    assert certs.cli([str(folder), "--router-host", "bad name!"]) == 2


def parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_zenoh_args(p)
    return p.parse_args(list(argv))


def conf_value(conf: zenoh.Config, key: str):
    return json.loads(conf.get_json(key))


def test_security_flags_make_the_zenoh_config(kit, monkeypatch, tmp_path):
    monkeypatch.delenv("DRONESIM_PASSWORD", raising=False)
    conf = zenoh_config(parse("-m", "client", "-e", "tls/localhost:7447", "--tls-ca", str(kit / "ca.pem"),
                              "--tls-cert", str(kit / "GCS.pem"), "--tls-key", str(kit / "GCS.key"),
                              "--user", "GCS", "--password-file", str(kit / "GCS.password")))
    tls = conf_value(conf, "transport/link/tls")
    assert tls["root_ca_certificate"] == str(kit / "ca.pem")
    assert tls["connect_certificate"] == str(kit / "GCS.pem") and tls["connect_private_key"] == str(kit / "GCS.key")
    assert tls["enable_mtls"] is True  # a client presents its certificate only with mTLS on
    usrpwd = conf_value(conf, "transport/auth/usrpwd")
    assert usrpwd["user"] == "GCS" and usrpwd["password"] == (kit / "GCS.password").read_text().strip()
    # a router: its certificate is the server's; clients' certificates are required only with --tls-mtls
    acl_file = tmp_path / "acl.json5"
    acl_file.write_text(acl.render(acl.access_control(["D01"])))
    router = zenoh_config(parse("-m", "router", "--tls-cert", str(kit / "router.pem"), "--tls-key",
                                str(kit / "router.key"), "--users-file", str(kit / "users.txt"),
                                "--acl", str(acl_file)))
    assert conf_value(router, "transport/link/tls/listen_certificate") == str(kit / "router.pem")
    assert not conf_value(router, "transport/link/tls/enable_mtls")  # unset: zenoh's default, off
    assert conf_value(router, "transport/auth/usrpwd/dictionary_file") == str(kit / "users.txt")
    assert conf_value(router, "access_control")["default_permission"] == "deny"
    # its budgets of puts a second, key by key for the keys the access control grants (issue 33, 6): the ground
    # station's DONE key and D01's TGT key each have one; a plain router's, D01's to D1024's each (none for all)
    budgets = {r["key_expr"]: r["freq"] for item in conf_value(router, "downsampling") for r in item["rules"]}
    assert {"sim/D01/NPS", "sim/D01/TGT", "sim/GCS/DONE"} <= budgets.keys()
    # a TGT a drone a turn at most (TGT_RATE), below the other keys' budget: a flood of stale TGTs passes less
    assert budgets["sim/D01/TGT"] == TGT_RATE < budgets["sim/GCS/DONE"] == budgets["sim/D01/NPS"] == PUT_RATE
    plain = {r["key_expr"] for item in acl.flood_filters(["**"])["downsampling"] for r in item["rules"]}
    assert "**/GCS/DONE" in plain and "**/D01/TGT" in plain and "**/*/TGT" not in plain
    assert conf_value(zenoh_config(parse("-m", "router", "--tls-mtls")), "transport/link/tls/enable_mtls") is True
    # the password comes from a file or the environment, never from a flag
    monkeypatch.setenv("DRONESIM_PASSWORD", "from-env")
    assert conf_value(zenoh_config(parse("--user", "D01")), "transport/auth/usrpwd/password") == "from-env"
    monkeypatch.delenv("DRONESIM_PASSWORD")
    for argv, why in ((["--user", "D01"], "needs --password-file"),
                      (["--password-file", str(kit / "D01.password")], "needs --user"),
                      (["--tls-cert", str(kit / "D01.pem")], "go together"),
                      (["--tls-ca", str(tmp_path / "nope.pem")], "no such file"),
                      (["--acl", str(kit / "ca.pem")], "cannot load --acl")):
        with pytest.raises(UsageError, match=why):
            zenoh_config(parse(*argv))
    # argparse takes `--password S3CRET` for `--password-file S3CRET`: refused without echoing it
    with pytest.raises(UsageError, match="no such file") as err:
        zenoh_config(parse("--user", "D01", "--password", "S3CRET"))
    assert "S3CRET" not in str(err.value)


# --------------------------------------------------------------------------- routers


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def acl_block(identity: str) -> dict:
    return acl.access_control(ACL_DRONES, roots=["sim"], identity=identity, hosts=HOSTS)


@contextlib.contextmanager
def embedded_router(kit: Path, identity: str, tmp: Path):
    """A Python router configured by `dronesim router`'s own flags; yields its TLS locator."""
    acl_file = tmp / f"acl-{identity}.json5"
    acl_file.write_text(acl.render(acl_block(identity)))
    flags = ["--mode", "router", "--listen", "tls/127.0.0.1:0", "--tls-ca", str(kit / "ca.pem"),
             "--tls-cert", str(kit / "router.pem"), "--tls-key", str(kit / "router.key"), "--acl", str(acl_file)]
    flags += ["--tls-mtls"] if identity == "cert" else ["--users-file", str(kit / "users.txt")]
    conf = zenoh_config(parse(*flags))
    conf.insert_json5("adminspace", '{"enabled": true, "permissions": {"read": true, "write": false}}')
    with zenoh.open(conf) as router:
        yield router_locators(router)[0]


@contextlib.contextmanager
def zenohd_router(kit: Path, identity: str, tmp: Path):
    """zenohd with the whole router config the generator writes; yields its TLS locator."""
    port = free_port()
    conf = acl.router_config(acl_block(identity), listen=f"tls/127.0.0.1:{port}", certs=str(kit),
                             mtls=identity == "cert", users=str(kit / "users.txt") if identity == "usrpwd" else None)
    conf["plugins_loading"] = {"enabled": False}
    path = tmp / f"zenohd-{identity}.json5"
    path.write_text(json.dumps(conf, indent=2))
    with zenohd(path, f"tls/127.0.0.1:{port}", tmp, name=f"zenohd-{identity}") as locator:
        yield locator

ROUTERS = {"embedded": embedded_router, "zenohd": zenohd_router}


@pytest.fixture(params=[(r, i) for r in ROUTERS for i in IDENTITIES], ids=lambda p: f"{p[0]}-{p[1]}")
def secured(request, kit, tmp_path):
    """(locator, identity) of a fresh router with TLS, authentication and the generated ACL."""
    kind, identity = request.param
    with ROUTERS[kind](kit, identity, tmp_path) as locator:
        yield locator, identity


def credentials(kit: Path, entity: str, identity: str) -> list[str]:
    """The flags an entity process runs with."""
    flags = ["--tls-ca", str(kit / "ca.pem")]
    if identity == "cert":
        return flags + ["--tls-cert", str(kit / f"{entity}.pem"), "--tls-key", str(kit / f"{entity}.key")]
    return flags + ["--user", entity, "--password-file", str(kit / f"{entity}.password")]


def open_session(locator: str, flags: list[str]) -> zenoh.Session:
    return zenoh.open(zenoh_config(parse("--mode", "client", "--connect", locator, *flags)))


@contextlib.contextmanager
def sessions(locator: str, kit: Path, identity: str, *entities: str):
    opened = [open_session(locator, credentials(kit, e, identity)) for e in entities]
    try:
        yield opened
    finally:
        for s in opened:
            s.close()


integration = pytest.mark.integration  # the tests below; the unit tests above need no router


# --------------------------------------------------------------------------- refused credentials


@integration
def test_no_wrong_or_untrusted_credentials_cannot_open_a_session(secured, kit, rogue):
    locator, identity = secured
    ca = ["--tls-ca", str(kit / "ca.pem")]
    if identity == "usrpwd":
        bad = {"no credentials": ca,
               "wrong password": ca + ["--user", "GCS", "--password-file", str(kit / "ENV.password")],
               "unknown user": ca + ["--user", "D07", "--password-file", str(kit / "D01.password")],
               "untrusted router (no CA)": ["--user", "GCS", "--password-file", str(kit / "GCS.password")],
               "another CA": ["--tls-ca", str(rogue / "ca.pem"), "--user", "GCS",
                              "--password-file", str(kit / "GCS.password")]}
    else:
        bad = {"no certificate": ca,
               "certificate from another CA": ca + ["--tls-cert", str(rogue / "GCS.pem"), "--tls-key",
                                                    str(rogue / "GCS.key")],
               "untrusted router (no CA)": ["--tls-cert", str(kit / "GCS.pem"), "--tls-key", str(kit / "GCS.key")]}
    for why, flags in bad.items():
        with pytest.raises(zenoh.ZError):
            s = open_session(locator, flags)
            s.close()
            pytest.fail(f"a session opened with {why}")
    open_session(locator, credentials(kit, "GCS", identity)).close()  # the right ones do open


@integration
def test_a_principal_in_no_acl_subject_can_neither_put_nor_get(secured, kit):
    """EVIL is authenticated (CA-signed certificate / password in the dictionary) but the ACL does not
    name it: default deny. Its session is not even told of any subscriber (so it does not send its put:
    zenoh clients drop a put nobody they know of subscribes to), and a put or a query that would reach the
    router is refused there. Barrier for the put: its own refused query, whose end comes from the router
    after the put, then the receiver's own query round trip (see the module docstring)."""
    locator, identity = secured
    keys = Keys("sim")
    with sessions(locator, kit, identity, "SRV", "D01", STRANGER) as (srv, d01, evil):
        got: list[bytes] = []
        handles = [d01.declare_subscriber(keys.over, direct(lambda s: got.append(s.payload.to_bytes()))),
                   d01.liveliness().declare_token(keys.alive("D01", "barrier")),
                   srv.declare_queryable(keys.connect, lambda q: (q.reply(q.key_expr, b"welcome"), q.drop())),
                   srv.liveliness().declare_token(keys.alive("SRV", "barrier"))]
        await_token(srv, keys.alive("D01", "barrier"))  # srv knows D01's subscription (declared before)
        await_token(d01, keys.alive("SRV", "barrier"))  # the router knows the coordinator's queryable
        await_token(evil, keys.alive("SRV", "barrier"), present=False)  # nor may it watch presence
        evil.put(keys.over, b"evil OVER", congestion_control=BLOCK)
        assert list(evil.get(keys.connect, timeout=TIMEOUT)) == [], "a stranger got an answer"
        replies = [r.ok.payload.to_bytes() for r in d01.get(keys.connect, timeout=TIMEOUT) if r.ok]
        assert replies == [b"welcome"], "positive control: D01 may ask the coordinator"
        srv.put(keys.over, b"real OVER", congestion_control=BLOCK)
        assert [r.ok.payload.to_bytes() for r in ask_until_replied(d01, keys.connect) if r.ok] == [b"welcome"]
        assert got == [b"real OVER"], got
        for h in reversed(handles):
            h.undeclare()


def direct(callback) -> zenoh.handlers.Callback:
    """A callback zenoh runs on the link's own thread, in arrival order. (By default zenoh-python runs
    each Python callback on a thread of its own: two subscribers' callbacks, or a callback and a query's
    replies, could then be seen out of the order the messages came in.)"""
    return zenoh.handlers.Callback(callback, indirect=False)


def await_token(session: zenoh.Session, key: str, *, present: bool = True) -> None:
    """Block until `session` sees a liveliness token on `key`. With present=False: check it sees none
    -- a liveliness *query* (``get``) ends when the router has answered, so this needs no timeout."""
    if not present:
        assert [r for r in session.liveliness().get(key, timeout=TIMEOUT) if r.ok] == [], f"{key} is visible"
        return
    seen = threading.Event()
    watch = session.liveliness().declare_subscriber(key, lambda _: seen.set(), history=True)
    try:
        assert seen.wait(TIMEOUT), f"the token {key} never showed"
    finally:
        watch.undeclare()


# --------------------------------------------------------------------------- spoofed messages


#: (attacker, key, what) -- each one forbidden by the key table; the attacker's marker key follows.
FORBIDDEN_PUTS = [
    ("D02", "sim/D01/NPS", "a spoofed NPS for another drone"),
    ("D02", "sim/D01/TGT", "a target published by a drone"),
    ("D02", "sim/D02/TGT", "a drone giving itself a target"),
    ("D02", "sim/SRV/OVER", "a fake OVER from a drone"),
    ("D02", "sim/SRV/TURN", "a fake TURN from a drone"),
    ("D02", "sim/OBS/STATUS", "a fake STATUS from a drone"),
    ("D02", "sim/GCS/DONE", "a DONE from a drone"),
    ("D02", "sim/ENV/UPD", "an UPD from a drone"),
    ("H01", "sim/D01/NPS", "a swarm host moving a drone it does not fly"),
    ("GCS", "sim/SRV/OVER", "a fake OVER from the ground station"),
    ("GCS", "sim/SRV/TURN", "a fake TURN from the ground station"),
    ("GCS", "sim/D01/NPS", "the ground station moving a drone"),
    ("ENV", "sim/SRV/TURN", "a fake TURN from the environment"),
    ("ENV", "sim/SRV/OVER", "a fake OVER from the environment"),
    ("ENV", "sim/D01/TGT", "a target from the environment"),
    ("ENV", "sim/D01/NPS", "the environment moving a drone"),
]
#: a key each attacker IS allowed to put on: its marker
MARKER = {"D02": "sim/D02/NPS", "H01": "sim/D03/NPS", "GCS": "sim/GCS/DONE", "ENV": "sim/ENV/UPD"}
#: the legitimate writer of each key (positive control)
WRITER = {"sim/D01/NPS": "D01", "sim/D01/TGT": "GCS", "sim/D02/TGT": "GCS", "sim/SRV/OVER": "SRV",
          "sim/SRV/TURN": "SRV", "sim/OBS/STATUS": "SRV", "sim/GCS/DONE": "GCS", "sim/ENV/UPD": "ENV"}
#: what the coordinator subscribes to, plus what every entity reads: the receiver (SRV's rights) sees them all
RECEIVER_KEYS = ["sim/*/TGT", "sim/GCS/DONE", "sim/*/NPS", "sim/ENV/UPD", "sim/SRV/TURN", "sim/SRV/OVER",
                 "sim/OBS/STATUS"]


@integration
def test_the_router_drops_every_forbidden_put(secured, kit):
    locator, identity = secured
    attackers = sorted({a for a, _, _ in FORBIDDEN_PUTS})
    writers = sorted(set(WRITER.values()))
    names = sorted({"SRV", *attackers, *writers})
    with sessions(locator, kit, identity, *names) as opened:
        s = dict(zip(names, opened))
        received: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()
        log: list[tuple[str, bytes]] = []
        subs = [s["SRV"].declare_subscriber(k, direct(lambda smp: received.put((str(smp.key_expr),
                                                                                smp.payload.to_bytes()))))
                for k in RECEIVER_KEYS]

        def await_markers(markers: set[bytes]) -> None:
            while markers:
                try:
                    key, payload = received.get(timeout=TIMEOUT)
                except queue.Empty:
                    raise AssertionError(f"markers {markers} never arrived; got {log}") from None
                log.append((key, payload))
                markers.discard(payload)

        # The receiver's subscriptions are known to the router once its token, declared after them (the
        # same session, the same control priority), has reached every sender.
        barrier = s["SRV"].liveliness().declare_token("sim/SRV/ALIVE/barrier")
        for who in names:
            await_token(s[who], "sim/SRV/ALIVE/barrier")
        # Positive control: each key's legitimate writer reaches the receiver.
        for key, w in WRITER.items():
            s[w].put(key, f"control {w} {key}".encode(), congestion_control=BLOCK)
        await_markers({f"control {w} {k}".encode() for k, w in WRITER.items()})
        # The attacks, each attacker's forbidden puts followed by its marker.
        for attacker in attackers:
            for a, key, _what in FORBIDDEN_PUTS:
                if a == attacker:
                    s[a].put(key, f"forbidden {a} {key}".encode(), congestion_control=BLOCK)
            s[attacker].put(MARKER[attacker], f"marker {attacker}".encode(), congestion_control=BLOCK)
        await_markers({f"marker {a}".encode() for a in attackers})
        what = {f"forbidden {a} {k}".encode(): w for a, k, w in FORBIDDEN_PUTS}
        leaked = [what[p] for _, p in log if p in what]
        assert not leaked, f"the router let through: {leaked}"
        for h in (*subs, barrier):
            h.undeclare()


@integration
def test_the_router_drops_a_foreign_queryable_and_presence(secured, kit):
    """D02, H01 and the GCS declare queryables on ENV/ASK and SRV/CONNECT and presence tokens under
    other names; only ENV's and SRV's own queryables answer, and the impostors' callbacks never run."""
    locator, identity = secured
    keys = Keys("sim")
    impostors = ["D02", "H01", "GCS"]
    names = ["ENV", "SRV", "D01", *impostors]
    with sessions(locator, kit, identity, *names) as opened:
        s = dict(zip(names, opened))
        called: list[str] = []
        handles = []

        def answer(text: bytes, who: str | None = None):
            def on_query(q: zenoh.Query) -> None:
                if who:
                    called.append(who)
                q.reply(q.key_expr, text)
                q.drop()
            return on_query

        seen: dict[str, threading.Event] = {n: threading.Event() for n in names}
        forged: list[str] = []

        def on_token(sample: zenoh.Sample) -> None:
            entity, session = keys.presence_of(str(sample.key_expr))
            if session.startswith("forged"):
                forged.append(str(sample.key_expr))
            elif session == "barrier":
                seen[entity].set()

        handles.append(s["D01"].liveliness().declare_subscriber(keys.any_alive, on_token, history=True))
        handles.append(s["ENV"].declare_queryable(keys.ask, answer(b"real ENV"), complete=True))
        handles.append(s["ENV"].declare_queryable(keys.ask, answer(b"real ENV, second"), complete=True))
        handles.append(s["SRV"].declare_queryable(keys.connect, answer(b"real SRV"), complete=True))
        for who in impostors:
            handles.append(s[who].declare_queryable(keys.ask, answer(f"fake ANS from {who}".encode(), who)))
            handles.append(s[who].declare_queryable(keys.connect, answer(f"fake WELCOME from {who}".encode(), who)))
            handles.append(s[who].liveliness().declare_token(keys.alive("ENV", f"forged{who}")))
            handles.append(s[who].liveliness().declare_token(keys.alive("SRV", f"forged{who}")))
        for who in names:  # the barrier: each one's own token, declared after everything above
            handles.append(s[who].liveliness().declare_token(keys.alive(who, "barrier")))
        for who in names:
            assert seen[who].wait(TIMEOUT), f"{who}'s own presence token never showed"
        consolidation = zenoh.QueryConsolidation(zenoh.ConsolidationMode.NONE)
        replies = s["D01"].get(keys.ask, timeout=TIMEOUT, consolidation=consolidation, target=zenoh.QueryTarget.ALL)
        ask = sorted(r.ok.payload.to_bytes() for r in replies if r.ok)
        assert ask == [b"real ENV", b"real ENV, second"], ask  # both legitimate ones: several answers do come
        connect = [r.ok.payload.to_bytes() for r in s["D01"].get(keys.connect, timeout=TIMEOUT,
                                                                 consolidation=consolidation,
                                                                 target=zenoh.QueryTarget.ALL) if r.ok]
        assert connect == [b"real SRV"], connect
        assert called == [], f"the router forwarded queries to impostors: {called}"
        assert forged == [], f"the router accepted presence tokens under other names: {forged}"
        for h in reversed(handles):
            h.undeclare()


# --------------------------------------------------------------------------- a whole game under attack


#: the forged TURN and STATUS are for turns 500+t and 600+t: an entity that got one would say so
FORGED_TURNS = (500, 600)


class Attacker:
    """Sessions with the credentials of principals that fly nothing in this game (D02, the swarm host
    H01) and try everything the ACL forbids them, at the moments it would hurt: a fake ENV/ASK and
    SRV/CONNECT queryable, forged presence, and on each TURN a target and a DONE for the GCS, a move for
    D01, an UPD for the environment, and a fake OVER, TURN and STATUS for the coordinator."""

    def __init__(self, locator: str, kit: Path, identity: str) -> None:
        self.keys = Keys("sim")
        self.d02 = open_session(locator, credentials(kit, "D02", identity))
        self.h01 = open_session(locator, credentials(kit, "H01", identity))
        self.sent: dict[str, int] = {}
        self.called: list[str] = []
        self.errors: list[BaseException] = []
        self._turns: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        k = self.keys
        fake = encode(Refused(turn=0, sender="SRV", text="go away"))
        self.handles = [
            self.d02.declare_queryable(k.ask, self._fake_answer("ASK"), complete=True),
            self.h01.declare_queryable(k.connect, lambda q: self._reply(q, "CONNECT", fake), complete=True),
            self.d02.liveliness().declare_token(k.alive("ENV", "forged1")),
            self.h01.liveliness().declare_token(k.alive("D01", "forged2")),
            # Zenoh runs callbacks on its own threads (which also run the embedded router, in this very
            # process): the callback only queues the TURN, the attacks go out from a thread of ours.
            self.d02.declare_subscriber(k.turn, lambda sample: self._turns.put(sample.payload.to_bytes())),
        ]
        self._thread = threading.Thread(target=self._attack, daemon=True)
        self._thread.start()

    def _reply(self, q: zenoh.Query, what: str, payload: bytes) -> None:
        self.called.append(what)
        q.reply(q.key_expr, payload)
        q.drop()

    def _fake_answer(self, what: str):
        def on_query(q: zenoh.Query) -> None:
            from schema import Ans, Ask

            ask = decode(q.payload.to_bytes(), Ask)
            kinds = bytes([CellKind.BUILDING] * len(ask.asked()))
            self._reply(q, what, encode(Ans(turn=ask.turn, sender="ENV", kinds=kinds)))
        return on_query

    def _put(self, session: zenoh.Session, key: str, msg) -> None:
        session.put(key, encode(msg), congestion_control=BLOCK)
        self.sent[msg.TAG] = self.sent.get(msg.TAG, 0) + 1

    def _attack(self) -> None:
        while (payload := self._turns.get()) is not None:
            self._on_turn(payload)

    def _on_turn(self, payload: bytes) -> None:
        try:
            turn = decode(payload, Turn)
            k, t = self.keys, turn.turn
            match turn.phase:
                case Phase.GCS:
                    self._put(self.d02, k.tgt("D01"), Target(turn=t, sender="GCS", drone="D01", pos=(0, 9, 0)))
                    self._put(self.d02, k.gcs_done, Done(turn=t, sender="GCS", phase=Phase.GCS, intent=Intent.QUIT,
                                                         count=1))
                case Phase.DRONES:
                    for order in turn.orders:
                        self._put(self.h01, k.nps(order.drone), Nps(turn=t, sender=order.drone, pos=order.pos))
                    # the next GCS phases, "answered ahead" (the scripted GCS does, so most are not announced)
                    self._put(self.d02, k.gcs_done, Done(turn=t + 1, sender="GCS", phase=Phase.GCS,
                                                         intent=Intent.QUIT))
                    if t == 2:  # an OVER now ends the game for whoever gets it; TURN and STATUS are
                        # for turns no process could mistake for real ones (FORGED_TURNS), so a leak shows
                        self._put(self.h01, k.over, Over(turn=t, sender="SRV", reason=EndReason.GCS_QUIT, text="fake"))
                        self._put(self.h01, k.turn_of(Phase.DRONES),
                                  Turn(turn=FORGED_TURNS[0] + t, sender="SRV", phase=Phase.DRONES))
                        self._put(self.h01, k.status, Status(turn=FORGED_TURNS[1] + t, sender="OBS", drones=(
                            DroneStatus(drone="D01", pos=(0, 0, 0), state=DroneState.DEAD),)))
                case Phase.ENV:
                    self._put(self.d02, k.upd, Upd(turn=t, sender="ENV", cells=()))
        except BaseException as exc:  # a bug in the test: reported by the test
            self.errors.append(exc)

    def close(self) -> None:
        self._turns.put(None)
        self._thread.join(timeout=TIMEOUT)
        for h in reversed(self.handles):
            h.undeclare()
        self.d02.close()
        self.h01.close()


def remote_gcs_config(kit: Path, identity: str, locator: str, tmp: Path) -> list[str]:
    """The ground station's flags from config/'s example client config: the router is reached by
    name (localhost, in the router certificate) over TLS, as from another host."""
    name = "gcs-remote-tls.json5" if identity == "usrpwd" else "gcs-remote-mtls.json5"
    port = locator.rsplit(":", 1)[1]
    text = (CONFIG / name).read_text()
    assert "tls/ROUTER_HOST:7447" in text and '"certs/' in text
    conf = tmp / name
    conf.write_text(text.replace("tls/ROUTER_HOST:7447", f"tls/localhost:{port}").replace('"certs/', f'"{kit}/'))
    flags = ["--config", str(conf)]
    return flags + (["--user", "GCS", "--password-file", str(kit / "GCS.password")] if identity == "usrpwd" else [])


def play(locator: str, kit: Path, identity: str, tmp: Path, *,
         attacked: bool) -> tuple[bytes, Cluster, Attacker | None]:
    tag = "attacked" if attacked else "clean"
    journal = tmp / f"{tag}.journal"
    run = tmp / tag
    run.mkdir()
    attacker = Attacker(locator, kit, identity) if attacked else None
    try:
        with Cluster(locator, run, root="sim") as c:
            srv = c.start("SRV", "coordinator", "--journal", str(journal), "--seed", "7", "--admit-deadline", "60",
                          "--max-turns", "60", "--phase-deadline", "30",  # a loaded machine must not make D01 hover
                          *credentials(kit, "SRV", identity))
            srv.expect("coordinator ready")
            c.start("ENV", "env", *credentials(kit, "ENV", identity))
            c.start("D01", "drone", "--id", "D01", "--autopilot", "seed", *credentials(kit, "D01", identity))
            gcs_locator = locator.replace("127.0.0.1", "localhost")
            c.start("GCS", "gcs", "--targets", "9,9,0",
                    *remote_gcs_config(kit, identity, locator, run), connect=gcs_locator)
            codes = c.wait_all()
            assert codes == {"SRV": 0, "ENV": 0, "D01": 0, "GCS": 0}, "\n".join(p.text for p in c.procs)
    finally:
        if attacker is not None:
            attacker.close()
    return journal.read_bytes(), c, attacker


@integration
@pytest.mark.parametrize("kind,identity", [(r, i) for r in ROUTERS for i in IDENTITIES],
                         ids=[f"{r}-{i}" for r in ROUTERS for i in IDENTITIES])
def test_an_attacked_game_has_the_journal_of_a_clean_one(kind, identity, kit, tmp_path):
    """The same game twice, each on a fresh router of this kind and identity: clean, then under attack.
    Every entity runs with its own credentials; the ground station joins by name over TLS with the
    example client config of config/."""
    with ROUTERS[kind](kit, identity, tmp_path) as locator:
        clean, _, _ = play(locator, kit, identity, tmp_path, attacked=False)
    with ROUTERS[kind](kit, identity, tmp_path) as locator:
        attacked, c, attacker = play(locator, kit, identity, tmp_path, attacked=True)
    assert not attacker.errors, attacker.errors
    assert set(attacker.sent) == {"TGT", "DONE", "NPS", "UPD", "OVER", "TURN", "STATUS"}, attacker.sent
    records = [json.loads(line) for line in clean.decode().splitlines()]
    assert records[-1]["reason"] == "ALL_REACHED" and records[-1]["turn"] >= 6, records[-1]
    assert attacked == clean
    # Nothing forbidden reached anyone. The coordinator, to which the forged TGT, DONE, NPS and UPD were
    # addressed, had nothing to reject (had one come, it would have been taken -- changing the journal --
    # or rejected as a second or late one). No entity saw a forged TURN or STATUS (they would reject those
    # turns, or act on them), nor the forged OVER (it would have left the game). No impostor was asked.
    # The ground station re-sends its phase's DONE until that turn's STATUS comes: a late one is refused as stale
    # (a forged DONE, a QUIT at the current or the next turn, would have ended the game: the journals are equal).
    srv = next(p for p in c.procs if p.name == "SRV")
    own = re.compile(r"rejected \S+/GCS/DONE: a message for turn \d+, before turn \d+ \(stale-turn\)$"
                     r"|rejected inputs: \{'stale-turn': \d+\}, from \{'GCS': \d+\}$")
    assert not [line for line in srv.err if "rejected" in line and not own.search(line)], srv.text
    forged = re.compile(rf"turn ({FORGED_TURNS[0] // 10}|{FORGED_TURNS[1] // 10})\d\b")  # 50x, 60x
    for p in c.procs:
        assert not [line for line in p.out + p.err if forged.search(line)], p.text
    assert attacker.called == [], attacker.called
    gcs = next(p for p in c.procs if p.name == "GCS")
    assert any("You are connected as GCS" in line for line in gcs.err), gcs.text
