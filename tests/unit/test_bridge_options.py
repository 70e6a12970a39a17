"""One list of bridge options: the bridge's option table (firmware/host/zn_config_parse.c: flag and
environment variable of each option) is the source. The scenario schema's bridge keys are its flags
(with _ for -) and name its variables (x-env, which compose sets), and every Kconfig option is
one of its variables with the flag its help names (or a build-time setting). Read-only parsing of
the C table and Kconfig: a new option added in one place and not the others fails here."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from canbench import compose, scenario

pytestmark = pytest.mark.unit
REPO = Path(__file__).resolve().parents[2]
OPTION_TABLE = REPO / "firmware" / "host" / "zn_config_parse.c"
KCONFIG = REPO / "firmware" / "components" / "zenoh-node" / "Kconfig"
BUILD_TIME = {"ZENOH_TASK_STACK_BYTES"}  # sizes a task at build time: no runtime option


def c_options(text: str) -> dict[str, str]:
    """flag -> environment variable, from the option table's { OPT_X, "flag", "ENV", ... } rows."""
    rows = re.findall(r'\{\s*OPT_\w+\s*,\s*"([a-z0-9-]+)"\s*,\s*(?:"([A-Z0-9_]+)"|NULL)', text)
    assert len(rows) >= 10, f"{OPTION_TABLE}: option table not found"
    return {flag: env for flag, env in rows if env}


def kconfig_options(text: str) -> dict[str, tuple[str, str] | None]:
    """config name -> (variable, flag) its help names ("On Linux: VAR / --flag"), or None."""
    out: dict[str, tuple[str, str] | None] = {}
    for block in re.split(r"^config ", text, flags=re.M)[1:]:
        name = block.split()[0]
        m = re.search(r"On Linux:\s*([A-Z0-9_]+)\s*/\s*--([a-z0-9-]+)", " ".join(block.split()))
        out[name] = (m.group(1), m.group(2)) if m else None
    return out


OPTIONS = c_options(OPTION_TABLE.read_text())


def test_schema_bridge_keys_are_bridge_flags_with_their_variables():
    keys = scenario.schema()["properties"]["bridge"]["properties"]
    assert keys, "the schema has no bridge keys"
    for key in keys:
        flag = key.replace("_", "-")
        assert flag in OPTIONS, f"scenario bridge key {key}: the bridge has no --{flag}"
        assert compose.BRIDGE_ENV[key] == OPTIONS[flag], f"{key}: x-env {compose.BRIDGE_ENV[key]}, --{flag} reads " \
                                                         f"{OPTIONS[flag]}"


def test_compose_sets_only_variables_the_bridge_reads():
    path = REPO / "scenarios" / "smoke.yaml"
    services = compose.compose_override(scenario.load(path), "/scenarios/smoke.yaml")["services"]
    unknown = set(services["bridge"]["environment"]) - set(OPTIONS.values())
    assert not unknown, f"compose sets {sorted(unknown)}, which the bridge does not read"


def test_every_kconfig_option_is_a_bridge_option():
    for name, linux in kconfig_options(KCONFIG.read_text()).items():
        if name in BUILD_TIME:
            assert linux is None, f"{name} is a build-time setting but its help names {linux}"
            continue
        assert linux is not None, f"Kconfig {name}: its help names no 'On Linux: VAR / --flag'"
        env, flag = linux
        assert env == name, f"Kconfig {name}: its help names variable {env}"
        assert OPTIONS.get(flag) == name, f"Kconfig {name}: the bridge's --{flag} reads {OPTIONS.get(flag)}"


def test_the_parsers_see_a_disagreement():
    """The checks above can fail: a renamed variable no longer matches."""
    assert c_options(OPTION_TABLE.read_text().replace('"ZENOH_NODE_MODE"', '"ZENOH_MODE"'))["mode"] != \
        compose.BRIDGE_ENV["mode"]
    broken = KCONFIG.read_text().replace("On Linux: ZENOH_NODE_MODE / --mode", "")
    assert kconfig_options(broken)["ZENOH_NODE_MODE"] is None
