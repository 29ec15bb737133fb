"""Zenoh access-control rules for a router, generated from the key table (`KEY_TABLE`), the one source
(what they grant, and the command line: docs/security.md).

Each key's one writer role (``KeySpec.writer``) and reader roles (``KeySpec.readers``) become a Zenoh
``access_control`` block with ``default_permission: "deny"`` and one subject and one policy per *principal*
(an authenticated process: SRV, ENV, GCS, each drone Dnn, each swarm host Hnn, named by its user name, its TLS
client certificate's common name, or both). A principal's grants on each kind of key are `_GRANTS`; discovery
(no payload: who listens where) is granted to all. Subjects never overlap (each has one distinct name): with
Zenoh, rules of overlapping subjects were seen not to hold.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import re
import sys
from collections.abc import Iterable, Mapping, Sequence

from .errors import UsageError
from .keys import KEY_TABLE, ROOT, Keys, KeySpec, size_limit
from .messages import drone_id, drone_list, is_drone_id, is_host_id
from .tuning import CONNECT_RATE, MAP_RATE, PUT_RATE, TGT_BUDGETED, TGT_RATE

#: The roles of the key table (``KeySpec.writer`` / ``KeySpec.readers``).
ROLES = ("SRV", "ENV", "GCS", "DRONE")
_PLACEHOLDER = re.compile(r"\{[a-z_]+\}")
#: The fields of a Zenoh ACL subject that name a principal, by `--identity`.
IDENTITIES = {"usrpwd": ("usernames",), "cert": ("cert_common_names",), "both": ("usernames", "cert_common_names")}
#: Zenoh's ACL message kinds (zenoh 1.x ``AclMessage``).
MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
            "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")
#: Declarations the router may announce to anyone (no payload: who listens where).
ANNOUNCEMENTS = ("declare_subscriber", "declare_queryable", "declare_liveliness_subscriber")
#: The shared example in config/: the drones it grants (D01..D16) and its key root.
EXAMPLE_DRONES = 16
EXAMPLE_ROOT = ROOT


@dataclasses.dataclass(frozen=True, slots=True)
class Principal:
    """An authenticated process: its entity id (user name / certificate CN), role, drones it flies."""

    name: str
    role: str
    drones: tuple[str, ...] = ()


def principals(drones: Iterable[str], hosts: Mapping[str, Sequence[str]] | None = None,
               spare_hosts: Iterable[str] = ()) -> list[Principal]:
    """SRV, ENV, GCS, every drone not flown by a host, every host with its drones, and every spare host with all
    the drones: a swarm host that may fly the game in place of the drone processes, which keep their own
    principals (docker/compose.yaml's `swarm` profile: the drone processes may read each other's credentials
    anyway, since each claims its id when it starts)."""
    hosts = dict(hosts or {})
    spare = list(dict.fromkeys(spare_hosts))
    for host in spare:
        if not is_host_id(host) or host in hosts:
            raise ValueError(f"bad spare swarm host {host!r}: expected H01, H02... not also a --host")
    hosted: dict[str, str] = {}
    for host, flown in hosts.items():
        if not is_host_id(host):
            raise ValueError(f"bad swarm host id {host!r}: expected H01, H02...")
        for d in flown:
            if not is_drone_id(d):
                raise ValueError(f"bad drone id {d!r} for host {host}")
            if d in hosted:
                raise ValueError(f"{d} is flown by both {hosted[d]} and {host}")
            hosted[d] = host
    drones = list(dict.fromkeys(drones))
    for d in drones:
        if not is_drone_id(d):
            raise ValueError(f"bad drone id {d!r}")
    return [Principal("SRV", "SRV"), Principal("ENV", "ENV"), Principal("GCS", "GCS"),
            *(Principal(d, "DRONE", (d,)) for d in drones if d not in hosted),
            *(Principal(h, "DRONE", tuple(flown)) for h, flown in sorted(hosts.items())),
            *(Principal(h, "DRONE", tuple(drones)) for h in spare)]


#: The roles each word of the key table's ``readers`` column stands for.
_READERS = {"all": ROLES, "entities": ROLES, "drones": ("DRONE",), **{role: (role,) for role in ROLES}}


def readers_of(spec: KeySpec) -> set[str]:
    """The roles that read a key, from its ``readers`` column ("all", "drones", "ENV, GCS"...)."""
    return {role for word in spec.readers.split(",") for role in _READERS[word.strip()]}


def _expand(template: str, p: Principal, *, own: bool) -> list[str]:
    """Concrete templates (relative to the root) for a principal: `own` keys name the principal
    (``{entity}``) or its drones (``{drone}``); the others, and any other placeholder (``{session}``),
    are wildcards."""
    if "{entity}" in template:
        out = [template.replace("{entity}", p.name if own else "*")]
    elif "{drone}" in template and own and p.role == "DRONE":
        out = [template.replace("{drone}", d) for d in p.drones]
    else:
        out = [template.replace("{drone}", "*")]
    return [_PLACEHOLDER.sub("*", t) for t in out]


#: A principal's grants on a key of each kind (``KeySpec.how``) as its writer, and as one of its readers: (flow
#: -- ingress: what the router takes from it --, messages, whether the key is expanded as its own, `_expand`).
_GRANTS: dict[str, tuple[list[tuple[str, tuple[str, ...], bool]], list[tuple[str, tuple[str, ...], bool]]]] = {
    "put": ([("ingress", ("put",), True)],
            [("ingress", ("declare_subscriber",), False), ("egress", ("put",), False)]),
    # A placeholder in a queryable's key names the *asker* (e.g. a per-entity admission key
    # SRV/CONNECT/{entity}): the owner serves them all, each asker may ask only as itself.
    "query": ([("ingress", ("declare_queryable", "reply"), False), ("egress", ("query",), False)],
              [("ingress", ("query",), True), ("egress", ("reply",), True)]),
    "liveliness": ([("ingress", ("liveliness_token",), True)],
                   [("ingress", ("declare_liveliness_subscriber", "liveliness_query"), False),
                    ("egress", ("liveliness_token",), False)]),
}


def grants(p: Principal, roots: Sequence[str]) -> dict[tuple[str, str], list[str]]:
    """(flow, message) -> key expressions this principal is allowed, derived from KEY_TABLE."""
    g: dict[tuple[str, str], dict[str, None]] = {}  # (each key once, in order)

    def add(flow: str, messages: Iterable[str], templates: Sequence[str]) -> None:
        for msg in messages:
            g.setdefault((flow, msg), {}).update(dict.fromkeys(f"{root}/{t}" for t in templates for root in roots))

    for spec in KEY_TABLE:
        mine = spec.writer == p.role or (spec.writer == "each entity" and "{entity}" in spec.template)
        reads = p.role in readers_of(spec)
        as_writer, as_reader = _GRANTS[spec.how]
        for flow, messages, own in (as_writer if mine else []) + (as_reader if reads else []):
            add(flow, messages, _expand(spec.template, p, own=own))
    add("egress", ANNOUNCEMENTS, ["**"])
    return {key: list(exprs) for key, exprs in g.items()}


def access_control(drones: Iterable[str], *, roots: Sequence[str] = (ROOT,), identity: str = "usrpwd",
                   hosts: Mapping[str, Sequence[str]] | None = None, spare_hosts: Iterable[str] = ()) -> dict:
    """The ``access_control`` block (a plain dict, JSON-able) for a router (`principals`: who is granted)."""
    if identity not in IDENTITIES:
        raise ValueError(f"identity must be one of {', '.join(IDENTITIES)}, not {identity!r}")
    roots = [Keys(r).root for r in roots]  # validates each root
    if not roots:
        raise ValueError("at least one key root is needed")
    rules_of = {p: [{"id": f"{p.name} {flow} {msg}", "permission": "allow", "flows": [flow], "messages": [msg],
                     "key_exprs": keys} for (flow, msg), keys in grants(p, roots).items()]
                for p in principals(drones, hosts, spare_hosts)}
    return {"enabled": True, "default_permission": "deny", "rules": [r for rules in rules_of.values() for r in rules],
            "subjects": [{"id": p.name, **{field: [p.name] for field in IDENTITIES[identity]}} for p in rules_of],
            "policies": [{"id": f"{p.name} policy", "rules": [r["id"] for r in rules], "subjects": [p.name]}
                         for p, rules in rules_of.items()]}


# --------------------------------------------------------------------------- evaluation


def _includes(outer: str, inner: str) -> bool:
    import zenoh

    return zenoh.KeyExpr(outer).includes(zenoh.KeyExpr(inner))


def allowed(acl: dict, subject: str, flow: str, message: str, key: str) -> bool:
    """What the router decides for `subject` (a subject id) -- Zenoh's rule: a message is allowed
    when an allow rule of one of the subject's policies has a key expression that includes its key
    (and no deny rule does; this generator writes none), else ``default_permission`` applies."""
    by_id = {r["id"]: r for r in acl["rules"]}
    verdict = acl["default_permission"] == "allow"
    for r in (by_id[rid] for pol in acl["policies"] if subject in pol["subjects"] for rid in pol["rules"]):
        if flow in r.get("flows", ["ingress", "egress"]) and message in r["messages"] and \
                any(_includes(k, key) for k in r["key_exprs"]):
            if r["permission"] == "deny":
                return False
            verdict = True
    return verdict


# --------------------------------------------------------------------------- configs


def parse_hosts(items: Iterable[str]) -> dict[str, tuple[str, ...]]:
    """``H01=D01-D08`` / ``H02=D09,D10`` -> {"H01": ("D01", ..., "D08"), ...}."""
    hosts: dict[str, tuple[str, ...]] = {}
    for item in items:
        host, _, spec = item.partition("=")
        if not spec:
            raise ValueError(f"bad --host {item!r}: expected Hnn=Dnn-Dmm or Hnn=Dnn,Dmm")
        hosts[host.strip()] = drone_list(spec)
    return hosts


def render(block: dict, header: str = "") -> str:
    """A JSON5 document holding the block (itself a valid partial zenoh config)."""
    return json5_document({"access_control": block}, header)


#: The queries a router budgets, by key template: queries a second from one session (`flood_filters`).
QUERY_RATES = {"SRV/CONNECT": CONNECT_RATE, "ENV/MAP": MAP_RATE}


def flood_filters(roots: Sequence[str], acl: dict | None = None) -> dict:
    """A router's `low_pass_filter` and `downsampling` blocks, from the key table: on what the router receives
    from each session, the payloads (a put's, a query's) above their key's message's largest valid size
    (`schema.keys.size_limit`) are dropped, and the puts on a key a drone or the ground station writes (NPS,
    MOVES; DONE, TGT) beyond `PUT_RATE` a second, each session on a budget of its own. With `acl` (an
    `access_control` block) the rate of puts is kept key by key for the keys it grants (a session's refused puts
    on another drone's key do not count against its own), and the TGT keys one by one for the drones it names, at
    `TGT_RATE` a second (what a station needs: a TGT a drone a turn); without, for all of a kind at once, but the
    TGT keys one by one for the drones D01 to `TGT_BUDGETED` (a station may send a TGT for every drone at once: one
    budget for all would drop them; dronesim's stations send none, their DONE carries the targets). And
    the CONNECT queries beyond `CONNECT_RATE` a second from one session (a process asks one at a time,
    `CONNECT_GAP` apart at least; a query dropped is ended at once, without a reply, and asked again), and the MAP
    queries beyond `MAP_RATE` a second from one session (a process asks once). The ASK queries have no router budget:
    a process sends a turn's ASKs together, which a budget of one query an interval would drop; the environment's
    queue bounds each sender's (network/transport.py `FairQueue`)."""
    import zenoh

    sizes: dict[tuple[str, int], list[str]] = {}
    budgeted: list[tuple[str, float]] = []  # (key expression, puts a second)
    queried: list[tuple[str, float]] = []  # (key expression, queries a second)
    granted = None if acl is None else sorted(  # every key expression `acl` lets some subject put on
        {k for rule in acl["rules"] if rule["permission"] == "allow" and "put" in rule["messages"]
         and "ingress" in rule["flows"] for k in rule["key_exprs"]})
    for spec in KEY_TABLE:
        if spec.message is None:
            continue
        exprs = [str(zenoh.KeyExpr.autocanonize(f"{root}/{_PLACEHOLDER.sub('*', spec.template)}")) for root in roots]
        sizes.setdefault((spec.how, size_limit(spec.message)), []).extend(exprs)
        if spec.template in QUERY_RATES:
            queried += [(k, QUERY_RATES[spec.template]) for k in exprs]
        if spec.how == "put" and spec.writer == "DRONE" or spec.template == "GCS/DONE":
            budgeted += [(k, PUT_RATE) for k in (exprs if granted is None else granted)
                         if any(_includes(x, k) for x in exprs)]
        elif spec.how == "put" and spec.writer == "GCS":  # TGT: a budget per drone
            drones = ([f"{root}/{drone_id(n)}" for root in roots for n in range(1, TGT_BUDGETED + 1)] if granted is None
                      else [k.rsplit("/", 1)[0] for k in granted if k.endswith("/NPS") and "*" not in k])
            budgeted += [(f"{d}/{spec.template.split('/', 1)[1]}", TGT_RATE) for d in drones]
    low_pass = [{"id": f"{how}-{limit}", "messages": [how], "flows": ["ingress"], "key_exprs": exprs,
                 "size_limit": limit} for (how, limit), exprs in sorted(sizes.items())]
    puts = {"id": "puts", "messages": ["put"], "flows": ["ingress"],
            "rules": [{"key_expr": expr, "freq": rate} for expr, rate in budgeted]}
    queries = {"id": "queries", "messages": ["query"], "flows": ["ingress"],
               "rules": [{"key_expr": expr, "freq": rate} for expr, rate in queried]}
    return {"low_pass_filter": low_pass, "downsampling": [puts, queries]}


def router_config(block: dict, *, listen: str = "tls/0.0.0.0:7447", certs: str = "certs", mtls: bool = False,
                  users: str | None = None, roots: Sequence[str] = (EXAMPLE_ROOT,)) -> dict:
    """A whole router config: TLS listener, optional mutual TLS and user/password dictionary, ACL and the
    flood filters (`flood_filters`) of the game's `roots`."""
    tls: dict = {"root_ca_certificate": f"{certs}/ca.pem", "listen_certificate": f"{certs}/router.pem",
                 "listen_private_key": f"{certs}/router.key", "enable_mtls": mtls}
    transport: dict = {"link": {"tls": tls}}
    if users:
        transport["auth"] = {"usrpwd": {"dictionary_file": users}}
    # The admin space is read by the router's own process (`dronesim router` prints its locators from
    # it); the ACL keeps every remote session out of it (nothing outside the roots is granted).
    return {"mode": "router", "listen": {"endpoints": [listen]}, "scouting": {"multicast": {"enabled": False}},
            "adminspace": {"enabled": True, "permissions": {"read": True, "write": False}},
            "transport": transport, "access_control": block, **flood_filters(roots, block)}


def client_config(entity: str, *, connect: str = "tls/ROUTER_HOST:7447", certs: str = "certs",
                  mtls: bool = False) -> dict:
    """A client's config: TLS towards the router, and with `mtls` this entity's certificate."""
    tls: dict = {"root_ca_certificate": f"{certs}/ca.pem"}
    if mtls:
        tls.update(connect_certificate=f"{certs}/{entity}.pem", connect_private_key=f"{certs}/{entity}.key",
                   enable_mtls=True)
    # No user/password here: zenoh refuses a user without its password, and a password never goes in a
    # file meant to be shared -- they come from --user and --password-file (or DRONESIM_PASSWORD).
    return {"mode": "client", "connect": {"endpoints": [connect]}, "scouting": {"multicast": {"enabled": False}},
            "transport": {"link": {"tls": tls}}}


def examples() -> dict[str, str]:
    """The files of config/ (regenerated by ``--write-examples``; a test checks they are current)."""
    drones = [drone_id(n) for n in range(1, EXAMPLE_DRONES + 1)]
    cmd = "python -m schema.acl --write-examples config/"
    gen = f"Generated from schema/keys.py KEY_TABLE by `{cmd}`: do not edit by hand."
    usrpwd = access_control(drones, roots=[EXAMPLE_ROOT], identity="usrpwd")
    cert = access_control(drones, roots=[EXAMPLE_ROOT], identity="cert")
    return {
        "router-acl-usrpwd.json5": render(usrpwd, f"""
{gen}
Access control for root '{EXAMPLE_ROOT}', D01..D{EXAMPLE_DRONES:02d}, principals named by user (user/password auth).
Use: dronesim router --config config/router-tls-usrpwd.json5, or add it to a router's config with --acl.
Other games: python -m schema.acl --drones N --root ROOT [--host H01=D01-D08] --identity usrpwd"""),
        "router-acl-cert.json5": render(cert, f"""
{gen}
Access control for root '{EXAMPLE_ROOT}', D01..D{EXAMPLE_DRONES:02d}, principals named by their TLS client
certificate's CN.
Other games: python -m schema.acl --drones N --root ROOT [--host H01=D01-D08] --identity cert"""),
        "router-tls-usrpwd.json5": json5_document(router_config(usrpwd, users="certs/users.txt"), f"""
{gen}
A router: TLS on port 7447 (server certificate certs/router.pem), every process authenticated by
user/password (certs/users.txt, from `dronesim certs certs --passwords`), and the ACL of
router-acl-usrpwd.json5. Paths are relative to the router's working directory.
Run: dronesim router --config config/router-tls-usrpwd.json5   (or: zenohd -c config/router-tls-usrpwd.json5)"""),
        "router-mtls.json5": json5_document(router_config(cert, mtls=True), f"""
{gen}
A router: mutual TLS on port 7447 -- every process presents a certificate signed by certs/ca.pem,
and its common name (SRV, ENV, GCS, D01...) is its identity for the ACL of router-acl-cert.json5.
Run: dronesim router --config config/router-mtls.json5   (or: zenohd -c config/router-mtls.json5)"""),
        "gcs-remote-tls.json5": json5_document(client_config("GCS"), """
A remote ground station joining over TLS with user/password (the router runs router-tls-usrpwd.json5).
Replace ROUTER_HOST (it must be a name in the router certificate: dronesim certs --router-host NAME).
Run: dronesim gcs --config config/gcs-remote-tls.json5 --user GCS --password-file certs/GCS.password
(the password comes from the file or DRONESIM_PASSWORD, never from this config nor a flag).
Same without a config file: dronesim gcs -m client -e tls/ROUTER_HOST:7447 --tls-ca certs/ca.pem --user GCS
     --password-file certs/GCS.password"""),
        "gcs-remote-mtls.json5": json5_document(client_config("GCS", mtls=True), """
A remote ground station joining over mutual TLS (the router runs router-mtls.json5); its identity is
its certificate (CN=GCS). Replace ROUTER_HOST.
Run: dronesim gcs --config config/gcs-remote-mtls.json5
Same without a config file: dronesim gcs -m client -e tls/ROUTER_HOST:7447 --tls-ca certs/ca.pem
     --tls-cert certs/GCS.pem --tls-key certs/GCS.key"""),
    }


def json5_document(conf: dict, header: str) -> str:
    """`conf` as a JSON5 document (a Zenoh config file) under a comment `header`."""
    lines = [f"// {line}".rstrip() for line in header.strip().splitlines()]
    return "\n".join([*lines, json.dumps(conf, indent=2), ""])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m schema.acl",
                                description="Zenoh access_control rules generated from the key table.")
    p.add_argument("--drones", type=int, default=1, help="grant drones D01..Dnn (default 1)")
    p.add_argument("--root", action="append", default=[], help=f"key root (repeatable; default {ROOT})")
    p.add_argument("--identity", choices=IDENTITIES, default="usrpwd",
                   help="match principals by user name, TLS certificate CN, or both (default usrpwd)")
    p.add_argument("--host", action="append", default=[], metavar="Hnn=Dnn-Dmm",
                   help="a swarm host flying these drones (they are granted to it, not to themselves)")
    p.add_argument("--router-config", action="store_true",
                   help="print a whole router config (TLS listener, auth, ACL) instead of the ACL alone")
    p.add_argument("--listen", default="tls/0.0.0.0:7447", help="with --router-config: the listener")
    p.add_argument("--certs", default="certs", help="with --router-config: the folder of `dronesim certs`")
    p.add_argument("--write-examples", metavar="DIR", help="regenerate the example configs into DIR and exit")
    args = p.parse_args(argv)
    if args.write_examples:
        out = pathlib.Path(args.write_examples)
        out.mkdir(parents=True, exist_ok=True)
        for name, text in examples().items():
            (out / name).write_text(text)
            print(f"wrote {out / name}")
        return 0
    try:
        hosts = parse_hosts(args.host)
        block = access_control([drone_id(n) for n in range(1, args.drones + 1)], roots=args.root or [ROOT],
                               identity=args.identity, hosts=hosts)
    except (ValueError, UsageError) as err:
        print(f"acl: {err}", file=sys.stderr)
        return 2
    conf = {"access_control": block}
    if args.router_config:
        fields = IDENTITIES[args.identity]
        users = f"{args.certs}/users.txt" if "usernames" in fields else None
        conf = router_config(block, listen=args.listen, certs=args.certs, roots=args.root or [ROOT],
                             mtls="cert_common_names" in fields, users=users)
    sys.stdout.write(json5_document(conf, "Generated by: python -m schema.acl " + " ".join(argv or sys.argv[1:])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
