"""The bench's Zenoh identities and the router's access control, generated per run
(`canbench identities DIR`, scripts/bench-run) and never committed: a CA made for the run,
one mTLS certificate per identity (its common name is the ACL subject), each identity's
Zenoh config, and the routers' configs with a default-deny ACL (docs/access-control.md).

    DIR/<identity>/ca.pem cert.pem key.pem zenoh.json5   one directory per identity, mounted
                                                         read-only into its service only
    DIR/router/zenohd.json5, DIR/router2/zenohd.json5    the routers' configs

Identities (certificate common names): router, router2 (the far router), bridge,
orchestrator (the consumer: commands, stats, the run's coordination), capture (zn-capture:
subscribes), ecu (the run's coordination keys only), viewer (subscribes), and two that must
be refused: rogue-bridge (CN bridge, signed by another CA) and the anonymous client (no
certificate at all). --open writes the same files without TLS or ACL (plain tcp), for people
who point their own tools at the router.

Certificates: EC P-256 keys, two days' validity, made with openssl (Debian's, in the ECU and
orchestrator images); the CA's key is deleted once everything is signed."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

PORT = 7447
MOUNT = "/run/zenoh"  # where each service finds its identity (compose.yaml)
CAPTURE_MOUNT = "/run/zenoh-capture"  # the orchestrator's second identity, for zn-capture
IDENTITIES = ("router", "router2", "bridge", "orchestrator", "capture", "ecu", "viewer")
ROGUE = "rogue-bridge"  # CN "bridge", signed by a CA the router does not trust
ANONYMOUS = "anonymous"  # the CA's certificate only (it trusts the router), no certificate of its own
DEVICE_IDENTITY = "device"  # a device of your own (canbench.device): CN bridge, its files on the host
# its key lies on the host: a client's certificate only, never one a router's name would accept
CLIENT_ONLY = "extendedKeyUsage=clientAuth\n"
SAN = "subjectAltName=DNS:router,DNS:router2,DNS:localhost,IP:127.0.0.1\n"  # what clients dial
ALL = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
       "liveliness_query", "declare_liveliness_subscriber"]
RECEIVE = ["put", "reply", "query", "declare_subscriber", "declare_queryable", "liveliness_token"]
COORDINATION = "bench/runs/**"  # canbench.runkeys: ready/done/stop keys and tokens of a run
VIEWERS = "canbench/viewers/**"


def mount_of(identity: str) -> str:
    return CAPTURE_MOUNT if identity == "capture" else MOUNT


def _openssl(*args: str, cwd: Path) -> None:
    if not shutil.which("openssl"):
        raise RuntimeError("canbench identities: openssl not found (apt-get install openssl)")
    done = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"openssl {args[0]} failed: {done.stderr.strip()}")


def _ca(d: Path, name: str) -> None:
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-days", "2",
             "-subj", f"/CN={name}", "-keyout", f"{name}.key", "-out", f"{name}.pem", cwd=d)


def _cert(d: Path, ca: str, cn: str, out: str, extensions: str = SAN) -> None:
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-subj", f"/CN={cn}",
             "-keyout", f"{out}.key", "-out", f"{out}.csr", cwd=d)
    (d / "san.ext").write_text(extensions)
    _openssl("x509", "-req", "-in", f"{out}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key", "-set_serial",
             str(int.from_bytes(os.urandom(8), "big")), "-days", "2", "-extfile", "san.ext", "-out", f"{out}.pem",
             cwd=d)


def _install(work: Path, d: Path, ca: str, name: str, key_mode: int) -> None:
    """An identity's files into its directory d: the CA it trusts, its certificate and its key."""
    shutil.copy(work / f"{ca}.pem", d / "ca.pem")
    shutil.copy(work / f"{name}.pem", d / "cert.pem")
    shutil.copy(work / f"{name}.key", d / "key.pem")
    os.chmod(d / "key.pem", key_mode)


def _rule(rid: str, flows: list[str], messages: list[str], keys: list[str]) -> dict:
    return {"id": rid, "permission": "allow", "flows": flows, "messages": messages, "key_exprs": keys}


def acl(prefix: str = "vehicle/can", ros2_keys: tuple[str, ...] = (), ros2_domains: tuple[int, ...] = (),
        upstream: bool = False) -> dict:
    """The routers' access control: default deny, allow rules only (zenohd: explicit deny >
    explicit allow > default, so a deny could not be relaxed per subject). Ingress is what a
    subject may send into the router, egress what the router forwards to it.
    upstream: router2's ACL, where the bench router's face is trusted like a router."""
    p = prefix
    rx, tx, bridges = [f"{p}/rx", f"{p}/*/rx"], [f"{p}/tx", f"{p}/*/tx"], [f"{p}/bridges/**"]
    # rmw_zenoh's liveliness tokens: the viewer subscribes to all of them (@ros2_lv/*/**, which a
    # rule for one domain would not include), so the whole prefix when the bridge has ROS 2 output
    ros_lv = ["@ros2_lv/**"] if ros2_domains else []
    ros = list(ros2_keys)
    rules = [
        # the bridge: publishes rx (and its ROS 2 topic), takes tx, its token and stats queryable
        _rule("bridge-publish", ["ingress"], ["put"], rx + ros),
        _rule("bridge-commands", ["ingress"], ["declare_subscriber"], tx),
        _rule("bridge-announce", ["ingress"], ["liveliness_token", "declare_queryable", "reply"], bridges + ros_lv),
        _rule("bridge-receive", ["egress"], ["put", "query"], tx + bridges),
        _rule("bridge-see", ["egress"], ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
              [f"{p}/**"] + ros + ros_lv),
        # the consumer: puts commands, reads everything the bridge offers, queries stats
        _rule("put-commands", ["ingress"], ["put"], tx),
        _rule("read", ["ingress"], ["declare_subscriber", "query", "declare_liveliness_subscriber",
                                    "liveliness_query"], [f"{p}/**"] + ros + ros_lv),
        _rule("receive", ["egress"], RECEIVE, [f"{p}/**"] + ros + ros_lv),
        # zn-capture: subscribes, and declares its ready token under the run's keys
        _rule("subscribe", ["ingress"], ["declare_subscriber"], [f"{p}/**"]),
        _rule("capture-ready", ["ingress"], ["liveliness_token"], ["bench/runs/*/capture/zenoh"]),
        # the run's coordination (orchestrator and ECUs): ready/done/stop keys and tokens
        _rule("coordinate", ["ingress", "egress"], ALL, [COORDINATION]),
        # the viewer's own token and stats queryable
        _rule("viewer-announce", ["ingress", "egress"], ["liveliness_token", "declare_queryable", "reply", "query",
                                                         "declare_liveliness_subscriber", "liveliness_query"],
              [VIEWERS]),
        # routers (the far router's link to the bench router): everything of the bench
        _rule("route", ["ingress", "egress"], ALL, [f"{p}/**", COORDINATION, VIEWERS] + ros + ros_lv),
    ]
    subjects = ["bridge", "orchestrator", "capture", "ecu", "viewer", "router2"] + (["router"] if upstream else [])
    policies = [
        {"id": "bridge", "rules": ["bridge-publish", "bridge-commands", "bridge-announce", "bridge-receive",
                                   "bridge-see"], "subjects": ["bridge"]},
        {"id": "consumer", "rules": ["put-commands", "read", "receive", "coordinate", "viewer-announce"],
         "subjects": ["orchestrator"]},
        {"id": "capture", "rules": ["subscribe", "capture-ready", "receive"], "subjects": ["capture"]},
        {"id": "ecu", "rules": ["coordinate"], "subjects": ["ecu"]},
        {"id": "viewer", "rules": ["read", "receive", "viewer-announce"], "subjects": ["viewer"]},
        {"id": "routers", "rules": ["route"], "subjects": ["router2"] + (["router"] if upstream else [])},
    ]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": [{"id": s, "cert_common_names": [s]} for s in subjects], "policies": policies}


def _tls(identity: str, listen: bool = False, connect: bool = True) -> dict:
    m = mount_of(identity)
    tls: dict = {"root_ca_certificate": f"{m}/ca.pem", "enable_mtls": True}
    if connect:
        tls |= {"connect_certificate": f"{m}/cert.pem", "connect_private_key": f"{m}/key.pem"}
    if listen:
        tls |= {"listen_certificate": f"{m}/cert.pem", "listen_private_key": f"{m}/key.pem"}
    return {"transport": {"link": {"tls": tls}}}


def router_config(secure: bool, far: bool = False, **acl_args) -> dict:
    """zenohd's config: explicit endpoints, never multicast scouting; secure: mTLS + ACL."""
    scheme = "tls" if secure else "tcp"
    conf: dict = {"mode": "router", "listen": {"endpoints": [f"{scheme}/0.0.0.0:{PORT}"]},
                  "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": True}},
                  "adminspace": {"enabled": True, "permissions": {"read": True, "write": False}}}
    if far:
        conf["connect"] = {"endpoints": [f"{scheme}/router:{PORT}"]}
    if secure:
        conf |= _tls("router2" if far else "router", listen=True, connect=far)
        conf["access_control"] = acl(upstream=far, **acl_args)
    return conf


def bridge_acl(prefix: str = "vehicle/can") -> dict:
    """The bridge's own ACL, for its listener (topology consumer: bridge): the consumer and the
    capture as on the router; the router's face (the bridge's link to it) may do the bridge's job."""
    router_acl = acl(prefix)
    router_acl["subjects"].append({"id": "router", "cert_common_names": ["router"]})
    router_acl["policies"].append({"id": "router", "rules": ["route"], "subjects": ["router"]})
    return router_acl


def device_config(secure: bool, host_dir: str, endpoint: str, mode: str = "client") -> dict:
    """The Zenoh config of a device of your own (canbench.device): connected to the router on
    loopback in the scenario's mode (bridge.mode), its identity's files where the host holds
    them, no multicast, no listener (a peer's default would be every interface)."""
    conf: dict = {"mode": mode, "connect": {"endpoints": [endpoint]}, "listen": {"endpoints": []},
                  "scouting": {"multicast": {"enabled": False}}}
    if secure:
        conf["transport"] = {"link": {"tls": {
            "root_ca_certificate": f"{host_dir}/ca.pem", "enable_mtls": True,
            "connect_certificate": f"{host_dir}/cert.pem", "connect_private_key": f"{host_dir}/key.pem"}}}
    return conf


def generate(out: Path, secure: bool = True, prefix: str = "vehicle/can", ros2_keys: tuple[str, ...] = (),
             ros2_domains: tuple[int, ...] = (), bridge_listens: bool = False,
             device: tuple[str, str] | None = None, device_mode: str = "client") -> list[str]:
    """Writes every identity's directory under out (which must not exist or be empty); returns
    the identities written. Files are 0644 (certificates, configs) and 0640 (keys): every bench
    service runs as the bench's user and sees only its own directory.
    device: (the host's path of out, the router's endpoint on loopback) for a device of your own:
    DEVICE_IDENTITY/ with a client certificate of CN bridge (the ACL's bridge) and its config, in
    device_mode (the scenario's bridge.mode)."""
    out.mkdir(parents=True, exist_ok=True)
    if any(out.iterdir()):
        raise RuntimeError(f"canbench identities: {out} is not empty (identities are made once per run)")
    acl_args = {"prefix": prefix, "ros2_keys": ros2_keys, "ros2_domains": ros2_domains}
    names = [*IDENTITIES, ROGUE, ANONYMOUS]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if secure:
            _ca(work, "ca")
            _ca(work, "rogue-ca")
            for name in IDENTITIES:
                _cert(work, "ca", name, name)
            _cert(work, "rogue-ca", "bridge", ROGUE)
            if device:
                _cert(work, "ca", "bridge", DEVICE_IDENTITY, CLIENT_ONLY)
        if device:
            d = out / DEVICE_IDENTITY
            d.mkdir()
            if secure:
                _install(work, d, "ca", DEVICE_IDENTITY, 0o600)
            host_dir, endpoint = device
            device_conf = device_config(secure, f"{host_dir}/{DEVICE_IDENTITY}", endpoint, device_mode)
            (d / "zenoh.json5").write_text(json.dumps(device_conf, indent=1) + "\n")
        for name in names:
            d = out / name
            d.mkdir()
            conf: dict = {}
            if secure and name == ANONYMOUS:
                shutil.copy(work / "ca.pem", d / "ca.pem")
                conf = {"transport": {"link": {"tls": {"root_ca_certificate": f"{MOUNT}/ca.pem"}}}}
            elif secure:
                _install(work, d, "rogue-ca" if name == ROGUE else "ca", name, 0o640)
                identity = "bridge" if name == ROGUE else name
                conf = _tls(identity, listen=identity == "bridge" and bridge_listens)
                if identity == "bridge" and bridge_listens:
                    conf["access_control"] = bridge_acl(prefix)
            if name in ("bridge", ROGUE) and not bridge_listens:
                # a peer listens on tcp/[::]:<any port> by default, beside the router and without
                # any ACL: the bridge listens only where the scenario says (ZENOH_LISTEN)
                conf["listen"] = {"endpoints": []}
            (d / "zenoh.json5").write_text(json.dumps(conf, indent=1) + "\n")
        for far, name in ((False, "router"), (True, "router2")):
            (out / name / "zenohd.json5").write_text(json.dumps(router_config(secure, far, **acl_args), indent=1)
                                                     + "\n")
    for d in [out, *out.iterdir()]:
        os.chmod(d, 0o755)
    return names + ([DEVICE_IDENTITY] if device else [])

