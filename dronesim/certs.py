"""``dronesim certs``: a development certificate authority and the credentials of every process.

    dronesim certs certs/ --drones 4 --router-host sim.example.org --passwords

writes into ``certs/``:

* ``ca.pem`` / ``ca.key`` -- a self-signed CA ("dronesim development CA"); every process trusts
  ``ca.pem`` (``--tls-ca``); ``ca.key`` signs, keep it off the other hosts;
* ``router.pem`` / ``router.key`` -- the router's server certificate, CN ``router``, with subject
  alternative names ``localhost``, ``127.0.0.1``, ``::1`` and each ``--router-host`` (a DNS name or an
  IP address), so that a client connecting to ``tls/NAME:7447`` can verify it;
* ``SRV``, ``ENV``, ``GCS``, ``D01``..``Dnn`` and each swarm host ``Hnn`` (``--host H01``) ``.pem`` /
  ``.key`` -- client certificates whose common name is the entity id: with mutual TLS the router
  knows who is connecting, and the access-control rules (``python -m schema.acl --identity
  cert``) grant each name its keys;
* with ``--passwords``: ``<ID>.password`` (a random password per entity) and ``users.txt``, the
  router's ``user:password`` dictionary (``--users-file``) for ``--identity usrpwd``.

It runs the ``openssl`` command line tool (no Python dependency). Private keys and passwords are
written with mode 0600. Running it again keeps what exists (the CA, the
certificates, the passwords) and adds what is missing -- a new ``--router-host`` re-issues the router
certificate with its old names and the new one (delete ``router.pem`` to drop names); ``--force``
re-issues everything but the CA (``--force-ca`` too). This is a development kit: for a real deployment, use your own CA.
"""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import os
import re
import secrets
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from schema import UsageError, drone_id
from schema.keys import ROOT
from schema.messages import is_drone_id, is_host_id

#: Elliptic-curve keys (P-256): small, fast, and accepted by Zenoh's TLS (rustls).
NEW_KEY = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]


def openssl(*args: str, cwd: Path, check: bool = True) -> str:
    """Run the openssl command line tool and return its output (shown when it fails, if `check`). Files it
    creates are private to the user (umask 077); certificates are made world-readable afterwards."""
    exe = shutil.which("openssl")
    if exe is None:
        raise UsageError("dronesim certs needs the openssl command (Debian/Ubuntu: apt-get install openssl)")
    done = subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, preexec_fn=lambda: os.umask(0o077))
    if check and done.returncode != 0:
        raise UsageError(f"openssl {args[0]} failed: {done.stderr.strip() or done.stdout.strip()}")
    return done.stdout


def _san(name: str) -> str:
    try:
        return f"IP:{ipaddress.ip_address(name)}"
    except ValueError:
        if not re.fullmatch(r"[A-Za-z0-9*]([A-Za-z0-9.\-]*[A-Za-z0-9])?", name):
            raise UsageError(f"bad host name {name!r} for a certificate") from None
        return f"DNS:{name}"


class Kit:
    """The certificate folder: loads or creates the CA, then issues certificates signed by it."""

    def __init__(self, folder: str | Path, *, days: int = 825, force_ca: bool = False) -> None:
        self.dir = Path(folder).resolve()
        self.dir.mkdir(parents=True, exist_ok=True)
        self.days = days
        self.written: list[Path] = []
        self.new_ca = force_ca or not ((self.dir / "ca.pem").exists() and (self.dir / "ca.key").exists())
        if self.new_ca:  # (what an earlier CA signed is re-issued: `make`)
            openssl("req", "-x509", "-new", *NEW_KEY, "-keyout", "ca.key", "-out", "ca.pem",
                    "-days", str(max(days, 3650)), "-sha256", "-subj", "/CN=dronesim development CA",
                    "-addext", "basicConstraints=critical,CA:TRUE,pathlen:0",
                    "-addext", "keyUsage=critical,keyCertSign,cRLSign,digitalSignature",
                    "-addext", "subjectKeyIdentifier=hash", cwd=self.dir)
            (self.dir / "ca.pem").chmod(0o644)
            self.written += [self.dir / "ca.pem", self.dir / "ca.key"]

    def issue(self, common_name: str, *, names: Sequence[str] = (), server: bool = False, force: bool = False) -> Path:
        """``<common_name>.pem`` / ``.key`` signed by the CA (kept if it exists, unless `force`)."""
        if not re.fullmatch(r"[A-Za-z0-9_\-]+", common_name):
            raise UsageError(f"bad common name {common_name!r}")
        pem, key = self.dir / f"{common_name}.pem", self.dir / f"{common_name}.key"
        wanted = [_san(n) for n in dict.fromkeys(names or [common_name.lower()])]
        if pem.exists() and key.exists():
            had = self.names_of(pem)
            if not force and set(wanted) <= had:
                return pem
            wanted += sorted(had - set(wanted))  # a re-issued certificate keeps the names it had
        ext = "".join(f"{line}\n" for line in (
            "basicConstraints=critical,CA:FALSE", "keyUsage=critical,digitalSignature,keyAgreement",
            f"extendedKeyUsage={'serverAuth,clientAuth' if server else 'clientAuth'}",
            f"subjectAltName={','.join(wanted)}", "subjectKeyIdentifier=hash", "authorityKeyIdentifier=keyid"))
        with tempfile.TemporaryDirectory(dir=self.dir) as tmp:
            (Path(tmp) / "ext.cnf").write_text(ext)
            openssl("req", "-new", *NEW_KEY, "-keyout", key.name, "-out", f"{tmp}/{common_name}.csr",
                    "-subj", f"/CN={common_name}", cwd=self.dir)
            openssl("x509", "-req", "-in", f"{tmp}/{common_name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                    "-set_serial", f"0x{secrets.token_hex(16)}", "-days", str(self.days), "-sha256",
                    "-extfile", f"{tmp}/ext.cnf", "-out", pem.name, cwd=self.dir)
        pem.chmod(0o644)
        self.written += [pem, key]
        return pem

    def names_of(self, pem: Path) -> set[str]:
        """The subject alternative names of a certificate, as ``DNS:x`` / ``IP:y`` (normalised)."""
        text = openssl("x509", "-in", str(pem), "-noout", "-ext", "subjectAltName", cwd=self.dir, check=False)
        found = re.findall(r"(DNS|IP Address):([^,\s]+)", text)
        return {_san(value) if kind == "IP Address" else f"DNS:{value}" for kind, value in found}

    def password(self, entity: str, *, force: bool = False) -> Path:
        """``<entity>.password``: a random password (kept if it exists, unless `force`)."""
        path = self.dir / f"{entity}.password"
        if force or not path.exists():
            self._write(path, secrets.token_urlsafe(24) + "\n")
        return path

    def users(self) -> Path:
        """``users.txt``: the router's ``user:password`` dictionary, from every ``<ID>.password`` here."""
        lines = [f"{p.stem}:{p.read_text().splitlines()[0]}" for p in sorted(self.dir.glob("*.password"))]
        return self._write(self.dir / "users.txt", "\n".join(lines) + "\n")

    def _write(self, path: Path, text: str) -> Path:
        """`text` into `path`, readable by the user alone (mode 0600), in one step."""
        self.written.append(write_private(path, text))
        return path


def write_private(path: Path, text: str, mode: int = 0o600) -> Path:
    """`text` into `path` with `mode` (by default readable by the user alone), in one step: a reader sees the old
    file or the new one, never a part."""
    tmp = path.with_name(path.name + ".tmp")
    with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600), "w", encoding="utf-8") as f:
        f.write(text)
    tmp.chmod(mode)
    os.replace(tmp, path)
    return path


def entities(drones: Iterable[str] = (), hosts: Iterable[str] = ()) -> list[str]:
    """SRV, ENV, GCS, the drones and the swarm hosts, checked."""
    out = ["SRV", "ENV", "GCS"]
    for ids, valid, bad in ((drones, is_drone_id, "bad drone id {!r}"),
                            (hosts, is_host_id, "bad swarm host id {!r}: expected H01, H02...")):
        for e in ids:
            if not valid(e):
                raise UsageError(bad.format(e))
            out.append(e)
    return list(dict.fromkeys(out))


def make(folder: str | Path, *, drones: Iterable[str] = (), hosts: Iterable[str] = (),
         router_hosts: Iterable[str] = (), passwords: bool = False, days: int = 825, force: bool = False,
         force_ca: bool = False) -> Kit:
    """The whole kit: CA, router certificate, one client certificate (and password) per entity."""
    kit = Kit(folder, days=days, force_ca=force_ca)
    force = force or kit.new_ca
    kit.issue("router", names=["localhost", "127.0.0.1", "::1", *router_hosts], server=True, force=force)
    for e in entities(drones, hosts):
        kit.issue(e, force=force)
        if passwords:
            kit.password(e, force=force)
    if passwords:
        kit.users()
    return kit


#: The shares of a game's credentials (`GameCredentials.hand_out`): a folder per role, named here, holding the CA's
#: certificate and the passwords of that role's entities -- the drones' one every drone's and swarm host's (a drone
#: replica of docker/compose.yaml claims its id when it starts).
SHARES = ("SRV", "ENV", "GCS", "drones")
#: Where the router of `router.json5` (`game_credentials`) listens: zenohd in docker/compose.yaml.
ZENOHD_LISTEN = "tls/0.0.0.0:7447"


def share_of(entity: str) -> str:
    """The share (`SHARES`) holding `entity`'s password."""
    return "drones" if is_drone_id(entity) or is_host_id(entity) else entity


@dataclasses.dataclass(frozen=True, slots=True)
class GameCredentials:
    """One game's credentials in `folder` (`game_credentials`): what each process and the router are given."""

    folder: Path

    def flags(self, entity: str) -> list[str]:
        """The flags of a process authenticating as `entity` (every `dronesim` role takes them)."""
        return ["--tls-ca", str(self.folder / "ca.pem"), "--user", entity,
                "--password-file", str(self.folder / f"{entity}.password")]

    def router_flags(self) -> list[str]:
        """The router's: its TLS certificate, the users it authenticates, the game's access control."""
        f = self.folder
        return ["--tls-ca", str(f / "ca.pem"), "--tls-cert", str(f / "router.pem"), "--tls-key", str(f / "router.key"),
                "--users-file", str(f / "users.txt"), "--acl", str(f / "acl.json5")]

    def hand_out(self, out: str | Path) -> list[Path]:
        """Each role's share of the credentials in `out`/SHARE (`SHARES`): the CA's certificate and the passwords of
        the role's entities, nothing else (no other role's password, no key). A password no longer in the kit
        is removed from its share. The folders written."""
        out = Path(out)
        ca = (self.folder / "ca.pem").read_text()
        passwords = {p.stem: p.read_text() for p in sorted(self.folder.glob("*.password"))}
        written = []
        for share in SHARES:
            folder = out / share
            folder.mkdir(parents=True, exist_ok=True)
            write_private(folder / "ca.pem", ca, 0o644)
            mine = {e: text for e, text in passwords.items() if share_of(e) == share}
            for entity, text in mine.items():
                write_private(folder / f"{entity}.password", text)
            for stale in folder.glob("*.password"):
                if stale.stem not in mine:
                    stale.unlink()
            written.append(folder)
        return written


def game_credentials(folder: str | Path, *, drones: Sequence[str], hosts: Mapping[str, Sequence[str]] | None = None,
                     spare_hosts: Sequence[str] = (), roots: Sequence[str] = (ROOT,), router_hosts: Iterable[str] = (),
                     listen: str = ZENOHD_LISTEN) -> GameCredentials:
    """A game's credentials, made at its start (`dronesim up`, the cluster's `credentials` service): a CA, the
    router's TLS certificate (for localhost and `router_hosts`), a random password per entity (SRV, ENV, GCS, each
    drone that no swarm host flies, each host and spare host: `schema.acl.principals`), the router's users.txt, the
    game's access control (`acl.json5`, generated from the key table: `schema.acl`) and a whole router config using
    them (`router.json5`, for ``zenohd -c``: TLS on `listen`, user/password, the access control, the flood filters).
    No client certificate: processes authenticate by user/password over TLS. What exists is kept (the CA, the router's
    certificate unless it lacks a name, every password): made again in the same folder, the credentials are the
    same, and a process holding them still gets in."""
    from schema.acl import access_control, json5_document, render, router_config

    hosts = {h: tuple(ds) for h, ds in (hosts or {}).items()}
    try:
        block = access_control(drones, roots=roots, identity="usrpwd", hosts=hosts, spare_hosts=spare_hosts)
    except ValueError as err:
        raise UsageError(str(err)) from None
    kit = Kit(folder)
    kit.issue("router", names=["localhost", "127.0.0.1", "::1", *router_hosts], server=True, force=kit.new_ca)
    hosted = {d for ds in hosts.values() for d in ds}
    for e in entities([d for d in drones if d not in hosted], [*hosts, *spare_hosts]):
        kit.password(e)
    kit.users()
    kit._write(kit.dir / "acl.json5", render(block, "The game's access control: generated by dronesim certs --game"))
    conf = router_config(block, listen=listen, certs=str(kit.dir), users=str(kit.dir / "users.txt"), roots=roots)
    header = "The game's router (zenohd -c FILE): TLS, user/password and access control, by dronesim certs --game"
    kit._write(kit.dir / "router.json5", json5_document(conf, header))
    return GameCredentials(kit.dir)


def cli(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="dronesim certs", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder", help="where to write the kit (created if missing), e.g. certs/")
    p.add_argument("--drones", type=int, default=1, help="certificates for D01..Dnn (default 1)")
    p.add_argument("--host", action="append", default=[], metavar="Hnn", help="a swarm host's certificate (repeatable)")
    p.add_argument("--router-host", action="append", default=[], metavar="NAME",
                   help="a DNS name or IP address the router is reached at, besides localhost (repeatable)")
    p.add_argument("--passwords", action="store_true",
                   help="also a random password per entity and the router's users.txt dictionary")
    p.add_argument("--days", type=int, default=825, help="validity of the certificates (default 825 days)")
    p.add_argument("--force", action="store_true", help="re-issue the certificates and passwords that exist")
    p.add_argument("--force-ca", action="store_true", help="also a new CA (every process must then get it)")
    p.add_argument("--game", action="store_true",
                   help="one game's credentials instead (what `dronesim up` makes at its start): the router's "
                        "certificate, a password per entity, users.txt and the game's access control acl.json5 "
                        "(with --drones, --fly, --root, --router-host); no client certificates")
    p.add_argument("--fly", action="append", default=[], metavar="Hnn=Dnn-Dmm",
                   help="with --game: a swarm host and the drones it flies (repeatable)")
    p.add_argument("--spare-host", action="append", default=[], metavar="Hnn",
                   help="with --game: a swarm host that may fly every drone in place of the drone processes, which "
                        "keep their own credentials (docker/compose.yaml's swarm profile; repeatable)")
    p.add_argument("--root", action="append", default=[], help=f"with --game: the game's key root (default {ROOT})")
    p.add_argument("--by-role", metavar="DIR",
                   help="with --game: also each role's share in DIR/SRV, DIR/ENV, DIR/GCS and DIR/drones (the drones "
                        "and swarm hosts): ca.pem and the role's passwords alone (docker/compose.yaml mounts each "
                        "share in its role's containers only)")
    args = p.parse_args(argv)
    try:
        if args.drones < 0 or args.days < 1:
            raise UsageError("--drones must be >= 0 and --days >= 1")
        if not args.game and (args.fly or args.spare_host or args.root or args.by_role):
            raise UsageError("--fly, --spare-host, --root and --by-role go with --game")
        if args.game:
            from schema.acl import parse_hosts

            try:
                hosts = parse_hosts(args.fly)
            except ValueError as err:
                raise UsageError(str(err)) from None
            creds = game_credentials(args.folder, drones=[drone_id(n) for n in range(1, args.drones + 1)],
                                     hosts=hosts, spare_hosts=args.spare_host, roots=args.root or [ROOT],
                                     router_hosts=args.router_host)
            print(f"router: dronesim router {' '.join(creds.router_flags())}")
            print(f"   or: zenohd -c {creds.folder / 'router.json5'}")
            print(f"each process: {' '.join(creds.flags('ENTITY'))} (a remote ground station: ca.pem and "
                  "GCS.password)")
            if args.by_role:
                print(f"each role's share: {' '.join(str(f) for f in creds.hand_out(args.by_role))}")
            return 0
        kit = make(args.folder, drones=[drone_id(n) for n in range(1, args.drones + 1)], hosts=args.host,
                   router_hosts=args.router_host, passwords=args.passwords, days=args.days, force=args.force,
                   force_ca=args.force_ca)
    except UsageError as err:
        print(f"dronesim certs: {err}", file=sys.stderr)
        return 2
    for path in kit.written:
        print(f"wrote {path}")
    if not kit.written:
        print(f"{kit.dir}: everything already there (--force to re-issue)")
    print(f"CA: {kit.dir / 'ca.pem'} (give it to every process: --tls-ca); keep {kit.dir / 'ca.key'} here")
    return 0


if __name__ == "__main__":
    sys.exit(cli())
