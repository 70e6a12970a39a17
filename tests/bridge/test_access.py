"""Access control and transport security with the real zenohd: only an
authorized identity may put commands on vehicle/can/**/tx; anyone
authenticated may read rx. Written as default deny + allow rules (zenohd's
priority is explicit deny > explicit allow > default). Identities by
user/password and by mTLS certificate common name; the certificates are
generated at run time into the test's temporary directory (no private key is
committed). A wrong or expired certificate is refused.

The router config here is the one docs/access-control.md explains."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
import zenoh
from conftest import Router, wait_for
from test_bridge_host import start_candump, stop_candump

from canbench import wire

COMMANDS = 50
IDENTITIES = ("bridge", "commander", "reader", "intruder")


def acl(subject_key: str) -> dict:
    """Default deny; the bridge may do its job, the commander may also put commands, everybody
    authenticated may read. subject_key: "usernames" or "cert_common_names"."""
    everything = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                  "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]
    read = ["declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query"]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": "bridge", "permission": "allow", "flows": ["ingress", "egress"], "messages": everything,
             "key_exprs": ["vehicle/can/**"]},
            {"id": "put-commands", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
             "key_exprs": ["vehicle/can/tx", "vehicle/can/*/tx"]},
            {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": read,
             "key_exprs": ["vehicle/can/**"]},
            {"id": "receive", "permission": "allow", "flows": ["egress"],
             "messages": ["put", "reply", "liveliness_token", "declare_subscriber", "declare_queryable"],
             "key_exprs": ["vehicle/can/**"]},
        ],
        "subjects": [{"id": name, subject_key: [name]} for name in IDENTITIES],
        "policies": [
            {"rules": ["bridge", "receive"], "subjects": ["bridge"]},
            {"rules": ["put-commands", "read", "receive"], "subjects": ["commander"]},
            {"rules": ["read", "receive"], "subjects": ["reader", "intruder"]},
        ],
    }


def client_config(endpoint: str, extra: dict) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    for key, value in extra.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


def run_access_scenario(bus, bridge, router: Router, creds: dict[str, dict], tmp_path: Path) -> None:
    """The bridge with its identity; commander and intruder each put COMMANDS frames; only the
    commander's reach the bus; the reader sees the bridge's rx traffic."""
    bridge_conf = tmp_path / "bridge-zenoh.json5"
    bridge_conf.write_text(json.dumps(_nest(creds["bridge"])))
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--zenoh-config", str(bridge_conf))
    sessions = {name: zenoh.open(client_config(router.endpoint, creds[name])) for name in ("commander", "intruder",
                                                                                            "reader")}
    try:
        bridge.wait_ready(sessions["reader"])
        rx: list[bytes] = []
        sub = sessions["reader"].declare_subscriber("vehicle/can/rx", lambda s: rx.append(s.payload.to_bytes()))
        dump, out = start_candump(bus, tmp_path / "can.log")
        for i in range(COMMANDS):
            sessions["intruder"].put("vehicle/can/tx", wire.encode(wire.Frame(0x666, 1, bytes([i]))))
            sessions["commander"].put("vehicle/can/tx", wire.encode(wire.Frame(0x100, 1, bytes([i]))))
        wait_for(lambda: bridge.stats(sessions["commander"])["buses"][0]["tx_frames"] >= COMMANDS,
                 "the commander's frames on the bus")
        bus.run(["cansend", "vcan0", "200#01"])
        wait_for(lambda: rx, "the reader receiving rx")
        on_bus = stop_candump(dump, out)
        assert on_bus == [f"vcan0 100#{i:02X}" for i in range(COMMANDS)] + ["vcan0 200#01"]
        assert bridge.stats(sessions["commander"])["buses"][0]["tx_samples"] == COMMANDS  # intruder's never arrived
        sub.undeclare()
    finally:
        for s in sessions.values():
            s.close()


def _nest(flat: dict) -> dict:
    """{"a/b": v} -> {"a": {"b": v}} for a JSON5 config file."""
    out: dict = {}
    for key, value in flat.items():
        node = out
        *parents, leaf = key.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


def test_usrpwd_only_the_commander_may_put_commands(bus, bridge, router, tmp_path):
    router.stop()
    passwords = {name: f"{name}-secret" for name in IDENTITIES}
    (tmp_path / "credentials.txt").write_text("".join(f"{n}:{p}\n" for n, p in passwords.items()))
    config = {"transport": {"auth": {"usrpwd": {"dictionary_file": str(tmp_path / "credentials.txt")}}},
              "access_control": acl("usernames")}
    (tmp_path / "router.json5").write_text(json.dumps(config))
    router.start("--config", str(tmp_path / "router.json5"))
    creds = {n: {"transport/auth/usrpwd/user": n, "transport/auth/usrpwd/password": p} for n, p in passwords.items()}
    run_access_scenario(bus, bridge, router, creds, tmp_path)
    # without credentials, no session at all
    with pytest.raises(zenoh.ZError):
        conf = client_config(router.endpoint, {"connect/timeout_ms": 2000})
        zenoh.open(conf).close()


# ---- mTLS ----

def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


def make_ca(d: Path, name: str) -> None:
    openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-days", "2",
            "-subj", f"/CN={name}", "-keyout", f"{name}.key", "-out", f"{name}.pem", cwd=d)


def make_cert(d: Path, ca: str, cn: str, expired: bool = False) -> None:
    """A certificate for cn signed by ca; SAN localhost/127.0.0.1 (the router's name check)."""
    openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-subj", f"/CN={cn}",
            "-keyout", f"{cn}.key", "-out", f"{cn}.csr", cwd=d)
    (d / f"{cn}.ext").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\n")
    if expired:  # valid for one day, a year ago
        (d / "index.txt").write_text("")
        (d / "ca.cnf").write_text(f"""[ca]\ndefault_ca=ca\n[ca]\ndir=.\ndatabase=index.txt\nnew_certs_dir=.
certificate={ca}.pem\nprivate_key={ca}.key\ndefault_md=sha256\npolicy=any\nserial=serial\n[any]\ncommonName=supplied\n""")
        (d / "serial").write_text("01\n")
        openssl("ca", "-batch", "-config", "ca.cnf", "-in", f"{cn}.csr", "-out", f"{cn}.pem", "-notext",
                "-startdate", "20250101000000Z", "-enddate", "20250102000000Z", "-extfile", f"{cn}.ext", cwd=d)
    else:
        openssl("x509", "-req", "-in", f"{cn}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key", "-CAcreateserial",
                "-days", "2", "-extfile", f"{cn}.ext", "-out", f"{cn}.pem", cwd=d)


def tls_creds(d: Path, cn: str, ca: str = "ca") -> dict:
    return {"transport/link/tls/root_ca_certificate": str(d / f"{ca}.pem"),
            "transport/link/tls/connect_certificate": str(d / f"{cn}.pem"),
            "transport/link/tls/connect_private_key": str(d / f"{cn}.key"),
            "transport/link/tls/enable_mtls": True}


def test_mtls_identity_by_certificate_and_bad_certificates_refused(bus, bridge, router, tmp_path):
    d = tmp_path / "pki"
    d.mkdir()
    make_ca(d, "ca")
    make_ca(d, "rogue-ca")
    for cn in ("router", *IDENTITIES):
        make_cert(d, "ca", cn)
    make_cert(d, "rogue-ca", "impostor")
    make_cert(d, "ca", "expired", expired=True)
    router.stop()
    router.endpoint = router.endpoint.replace("tcp/", "tls/")
    config = {"transport": {"link": {"tls": {"root_ca_certificate": str(d / "ca.pem"),
                                             "listen_certificate": str(d / "router.pem"),
                                             "listen_private_key": str(d / "router.key"),
                                             "enable_mtls": True}}},
              "access_control": acl("cert_common_names")}
    (tmp_path / "router.json5").write_text(json.dumps(config))
    router.start("--config", str(tmp_path / "router.json5"))
    run_access_scenario(bus, bridge, router, {n: tls_creds(d, n) for n in IDENTITIES}, tmp_path)
    for cn in ("impostor", "expired"):  # signed by another CA; expired: no session
        with pytest.raises(zenoh.ZError):
            zenoh.open(client_config(router.endpoint, {**tls_creds(d, cn), "connect/timeout_ms": 2000})).close()
