"""Scenario files (scenarios/*.yaml): load, validate against the JSON Schema
(canbench/scenario.schema.json, the one source of truth for keys, types and units),
and report problems as file:line: field: message."""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jsonschema
import yaml

from . import rxqos
from .errors import ScenarioError
from .files import file_problem, is_file
from .wire import EXT_ID_MAX, id_key

SCHEMA_PATH = Path(__file__).with_name("scenario.schema.json")


class _LineLoader(yaml.SafeLoader):
    """YAML loader that remembers the line of every mapping key and sequence item."""


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> dict:
    first: dict[Any, int] = {}
    for key_node, _ in node.value:  # before merge keys (<<) are flattened in: an override is no duplicate
        if isinstance(key_node, yaml.ScalarNode) and key_node.tag != "tag:yaml.org,2002:merge":
            if key_node.value in first:  # YAML would keep the last silently: a whole `expect:` lost
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key '{key_node.value}' (first at line {first[key_node.value]})",
                    key_node.start_mark)
            first[key_node.value] = key_node.start_mark.line + 1
    mapping = loader.construct_mapping(node, deep=True)
    lines = {key_node.value: key_node.start_mark.line + 1 for key_node, _ in node.value
             if isinstance(key_node, yaml.ScalarNode)}
    return _Located(mapping, lines, node.start_mark.line + 1)


def _construct_sequence(loader: _LineLoader, node: yaml.SequenceNode) -> list:
    return _LocatedList(loader.construct_sequence(node, deep=True),
                        [item.start_mark.line + 1 for item in node.value], node.start_mark.line + 1)


class _Located(dict):
    def __init__(self, data: dict, key_lines: dict[str, int], line: int):
        super().__init__(data)
        self.key_lines, self.line = key_lines, line


class _LocatedList(list):
    def __init__(self, data: list, item_lines: list[int], line: int):
        super().__init__(data)
        self.item_lines, self.line = item_lines, line


class _AmbiguousNumber(yaml.constructor.ConstructorError):
    """A number YAML 1.1 (PyYAML) reads otherwise than YAML 1.2 and a user do."""


def _construct_int(loader: _LineLoader, node: yaml.ScalarNode) -> int:
    value = loader.construct_yaml_int(node)
    text = str(node.value).replace("_", "").lstrip("+-")
    if ":" in text:
        raise _AmbiguousNumber(None, None, f"{node.value} is {value} to YAML 1.1 (base 60), text to YAML 1.2: "
                               f"write {value}, or quote it", node.start_mark)
    if re.fullmatch(r"0[0-9]+", text) and int(text, 8) != int(text, 10):
        decimal = int(str(node.value).replace("_", ""), 10)
        raise _AmbiguousNumber(None, None, f"{node.value} is {value} to YAML 1.1 (a leading 0 is octal), "
                               f"{decimal} to YAML 1.2: write {decimal} or {value}", node.start_mark)
    return value


def _construct_float(loader: _LineLoader, node: yaml.ScalarNode) -> float:
    value = loader.construct_yaml_float(node)
    if math.isnan(value):  # it passes no minimum or maximum: a gate of it would judge nothing
        raise _AmbiguousNumber(None, None, f"{node.value} is not a number (NaN): no value of a scenario can be, "
                               "write a number", node.start_mark)
    if ":" in str(node.value):
        raise _AmbiguousNumber(None, None, f"{node.value} is {value:g} to YAML 1.1 (base 60), text to YAML 1.2: "
                               f"write {yaml_number(value)}, or quote it", node.start_mark)
    return value


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)
_LineLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)
_LineLoader.add_constructor("tag:yaml.org,2002:float", _construct_float)


def line_of(doc: Any, path: list) -> int:
    """The line of a key path of a parsed scenario (parse()), for problems found outside load()."""
    return _line_of(doc, path)


def _line_of(doc: Any, path: list) -> int:
    """The line of the deepest element of path that carries one."""
    line, node = getattr(doc, "line", 1), doc
    for part in path:
        if isinstance(node, _Located) and part in node.key_lines:
            line = node.key_lines[part]
        elif isinstance(node, _LocatedList) and isinstance(part, int) and part < len(node.item_lines):
            line = node.item_lines[part]
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            break
    return line


@dataclass(frozen=True)
class Message:
    """A generated periodic message (periodic ECUs, generated commands)."""
    can_id: int
    cycle_ms: float
    dlc: int = 8
    extended: bool = False
    remote: bool = False


@dataclass(frozen=True)
class Ecu:
    name: str
    bus: str
    role: str = "replay"
    trace: Path | None = None
    speed: float = 1.0
    loops: int = 1
    start_offset_s: float = 0.0
    id_remap: dict[int, int] = field(default_factory=dict)
    echo_ids: frozenset[int] = frozenset()
    answer_id_offset: int = 1
    messages: tuple[Message, ...] = ()
    run_s: float = 0.0
    dbc_node: str = ""     # restbus: the DBC node it stands in for
    restbus: tuple = ()    # restbus: its messages (canbench.restbus.MessagePlan), from the bus's DBC
    left_out: tuple = ()   # restbus: messages of its node it cannot send (CAN FD), each "Name (why)"
    rules: tuple = ()      # responder: canbench.restbus.Rule
    interface: str | None = None  # the trace's interface it replays (a trace of several); None: the trace's only one

    def answer(self, can_id: int, data: bytes) -> tuple[int, bytes]:
        """The echo role's answer to a request (canfdtest style)."""
        return can_id + self.answer_id_offset, bytes((b + 1) & 0xFF for b in data)


@dataclass(frozen=True)
class Commands:
    """Frames the consumer puts on a bus's tx key: a trace or generated messages."""
    bus: str
    trace: Path | None = None
    speed: float = 1.0
    messages: tuple[Message, ...] = ()
    run_s: float = 0.0
    start_offset_s: float = 0.0
    interface: str | None = None  # the trace's interface it puts (a trace of several)
    message: str = ""  # commands in signals: the DBC message
    signal_plan: Any = None  # canbench.restbus.MessagePlan of message
    schedule: tuple = ()  # (at_s, signal values, line) per entry; empty: every cycle for run_s


@dataclass(frozen=True)
class Fault:
    at_s: float
    action: str
    duration_s: float = 1.0
    target: str = ""     # ecu_kill: the ECU
    bus: str = ""        # can_flood: the bus (default: the first)
    can_id: int = 0x7F0  # can_flood: the flood's identifier
    max_frames: int = 1_000_000  # can_flood: stops at this count even if duration_s has not passed
    step: int = 0        # its index in the scenario's faults list (a repeated step expands to several)


@dataclass(frozen=True)
class Scenario:
    path: Path
    name: str
    description: str
    duration_s: float
    buses: list[dict]
    ecus: list[Ecu]
    bridge: dict
    expect: dict
    raw: dict
    commands: list[Commands] = field(default_factory=list)
    consumer: str = "router"
    dbc: Path | None = None
    faults: list[Fault] = field(default_factory=list)
    bus_dbcs: dict[str, Path] = field(default_factory=dict)  # bus -> its DBC (buses[].dbc, else dbc)
    signal_gates: tuple = ()  # expect.signals, checked against the DBCs (canbench.signals.Gate)

    @property
    def bus_names(self) -> list[str]:
        return [b["name"] for b in self.buses]

    @property
    def echoes(self) -> list[Ecu]:
        return [e for e in self.ecus if e.role in ("echo", "responder")]  # answer until told to stop

    @property
    def tx_max_age_ms(self) -> int:
        """The bridge's command deadline (bridge.tx_max_age_ms, the schema's default when absent; 0 = off)."""
        return int(self.bridge.get("tx_max_age_ms", schema()["properties"]["bridge"]["properties"]["tx_max_age_ms"]
                                   ["default"]))

    def stamp_ages_ms(self) -> list[float]:
        """Per commands entry (in order): how long before its put its source time is (stamp_age_ms)."""
        return [float(spec.get("stamp_age_ms", 0)) for spec in (self.raw.get("commands") or [])]


def schema() -> dict:
    return json.loads(SCHEMA_PATH.read_text())


def parse(path: str | Path) -> Any:
    """The scenario's YAML document, every mapping and list knowing its lines."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise ScenarioError(str(path), None, f"cannot read: {e.strerror}") from None
    try:
        doc = yaml.load(text, Loader=_LineLoader)
    except _AmbiguousNumber as e:
        raise ScenarioError(str(path), e.problem_mark.line + 1 if e.problem_mark else None, str(e.problem)) from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        # one line: the mark says where, as every problem is said
        said = "; ".join(part for part in (getattr(e, "context", None), getattr(e, "problem", None)) if part)
        raise ScenarioError(str(path), mark.line + 1 if mark else None,
                            f"not valid YAML: {said or str(e).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise ScenarioError(str(path), 1, "a scenario is a mapping of keys (name, ecus, expect, ...)")
    if _values_over(doc, MAX_VALUES):
        if _values_over(doc, MAX_VALUES, each_once=True):  # as written: no alias to blame
            raise ScenarioError(str(path), None, f"more than {MAX_VALUES} values: a scenario this large "
                                "(a schedule of many entries) belongs in a trace or signal trace file")
        raise ScenarioError(str(path), None, f"more than {MAX_VALUES} values once its aliases (*name) are "
                            "expanded: nested aliases multiply (a scenario needs far fewer)")
    return doc


# A scenario's values as its readers see them, aliases expanded: nine aliases of nine aliases ... of
# a short list are a few lines of YAML and 387 million values (a minute and 6 GiB to say it is wrong)
MAX_VALUES = 1_000_000


def _values_over(doc: Any, limit: int, each_once: bool = False) -> bool:
    """Whether the document holds more than `limit` values, each alias counted as often as it is used
    (each_once: as written, an aliased mapping or list once)."""
    count, stack, seen = 0, [doc], set()
    while stack:
        node = stack.pop()
        count += 1
        if count > limit:
            return True
        if each_once and isinstance(node, (dict, list)):
            if id(node) in seen:
                continue
            seen.add(id(node))
        if isinstance(node, dict):
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)
    return False


MAX_SAID = 300  # characters of a schema message (it holds the value: a long list would be a page)


def _key_problems(path: Path, doc: Any) -> list[ScenarioError]:
    """Mapping keys YAML read as something other than text (an id written 440 or 0x647 is a number
    to it, yes a boolean): every key of a scenario is a name or an id, so each is a problem at its
    line, said before the schema (whose patterns cannot look at a number) is asked."""
    problems: list[ScenarioError] = []
    stack: list[tuple[Any, list]] = [(doc, [])]
    while stack:
        node, at = stack.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            if isinstance(node, dict) and not isinstance(key, str):
                where = ".".join(str(p) for p in at) or "(top level)"
                problems.append(ScenarioError(str(path), _line_of(doc, [*at, key]), (
                    f"{where}: YAML reads the key as {_yaml_kind(key)}, not text: quote it as "
                    "written (an id such as 440 or 0x647 is a number to YAML unquoted: '440', '0x647')")))
            stack.append((value, [*at, key]))
    return sorted(problems, key=lambda e: e.line or 0)


def _yaml_kind(value: Any) -> str:
    if isinstance(value, bool):
        return f"the boolean {str(value).lower()}"
    if isinstance(value, int | float):
        return f"the number {value:g}" if isinstance(value, float) else f"the number {value}"
    return "nothing (null)" if value is None else f"a {type(value).__name__}"


def schema_problems(path: Path, doc: Any) -> list[ScenarioError]:
    keys = _key_problems(path, doc)
    if keys:
        return keys
    problems = []
    for error in jsonschema.Draft202012Validator(schema()).iter_errors(doc):
        where = ".".join(str(p) for p in error.absolute_path) or "(top level)"
        line_path = list(error.absolute_path)
        if error.validator == "additionalProperties" and isinstance(error.instance, dict):
            # point at the unknown key itself, not at the mapping that holds it
            allowed = set(error.schema.get("properties", {}))
            line_path += [k for k in error.instance if k not in allowed][:1]
        if "propertyNames" in error.schema_path and isinstance(error.instance, str):
            line_path.append(error.instance)  # the key whose name is wrong
        hint = ""
        wanted = error.validator_value if isinstance(error.validator_value, list) else [error.validator_value]
        if error.validator == "type" and {"number", "integer"} & set(wanted) and text_number(error.instance):
            hint = f" (YAML reads {error.instance!r} as text: write {text_number(error.instance)})"
        elif isinstance(error.instance, bool) and error.validator in ("type", "oneOf") and "boolean" not in wanted:
            hint = " (YAML 1.1 reads yes, no, on and off as true and false: quote a name meant as text)"
        message = error.message if len(error.message) <= MAX_SAID else (
            f"{error.message[:MAX_SAID // 2]} ... {error.message[-MAX_SAID // 2:]}")  # the value cut, the reason kept
        problems.append(ScenarioError(str(path), _line_of(doc, line_path), f"{where}: {message}{hint}"))
    return problems


# the words PyYAML (YAML 1.1) reads as booleans, in any of its cases: a value-table name On is true
YAML_BOOLS = {True: ("yes", "on", "true"), False: ("no", "off", "false")}


def text_number(value: Any) -> str | None:
    """For text a user means as a number, how to write that number so YAML 1.1 (PyYAML) reads it
    as one: '12' quoted, 1e3 and -2E-5 (no dot), 0o17 (YAML 1.2's octal) are text to it; else None.
    Not resolved as numbers by the loader: an unquoted hex id such as 1E3 would become 1000.0."""
    if not isinstance(value, str) or not re.search("[0-9]", value):
        return None
    text = value.strip()
    if re.fullmatch(r"[-+]?[0-9][0-9_]*", text):
        return str(int(text.replace("_", "")))  # 010 too: decimal, as a user and YAML 1.2 mean it
    if re.fullmatch(r"[-+]?[0-9]+[eE][-+]?[0-9]+", text):  # the user's own form, with the dot YAML 1.1 needs
        mantissa, exponent = re.split("[eE]", text)
        return f"{mantissa}.0e{exponent if exponent[0] in '+-' else '+' + exponent}"
    try:
        number: int | float = int(text, 0)  # 0x10, 0o17, 0b101
    except ValueError:
        try:
            number = float(text)  # 12.5, 1e3, 1_000.5
        except ValueError:
            return None
    return yaml_number(number) if math.isfinite(number) else None


def yaml_number(number: int | float) -> str:
    """A number as YAML 1.1 reads it back: 1e+20 needs its dot (1.0e+20)."""
    if isinstance(number, int):
        return str(number)
    text = repr(float(number))
    mantissa, e, exponent = text.partition("e")
    return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text


def problems_error(problems: list[ScenarioError]) -> ScenarioError:
    """One error for several problems: the first names file:line, then one line per further problem."""
    first, rest = problems[0], problems[1:]
    message = str(first).removeprefix(f"{first.path}:{first.line}: " if first.line else f"{first.path}: ")
    error = ScenarioError(first.path, first.line, "\n".join([message, *map(str, rest)]))
    error.problems = problems  # type: ignore[attr-defined]
    return error


def load(path: str | Path) -> Scenario:
    """The scenario, or a ScenarioError naming every problem (file:line each, in line order)."""
    return build(Path(path), parse(path))


def build(path: Path, doc: Any) -> Scenario:
    """The scenario of a parsed document (parse's) of the file at path, or load's ScenarioError."""
    problems = schema_problems(path, doc)
    sc = None
    try:
        sc = _build(path, doc, problems)
    except (KeyError, TypeError, ValueError, AttributeError, IndexError):
        if not problems:  # a shape the schema let through: still a bad input, never a traceback
            raise
    if problems or sc is None:
        problems.sort(key=lambda p: p.line or 0)
        raise problems_error(problems)
    return sc


def interface_name(value: Any) -> str | None:
    """A replay's `interface:` as a trace names it: 'can1', or an ASC/BLF channel given as 2, '2'
    or 2.0 (YAML and JSON Schema take 2.0 for an integer)."""
    if value is None:
        return None
    return str(int(value)) if isinstance(value, float) and value.is_integer() else str(value)


def _build(path: Path, doc: Any, problems: list[ScenarioError]) -> Scenario | None:
    """The scenario model and its cross-field checks; problems appended, never raised. Parts that
    the schema already refused are skipped (the checks below rely on the schema's shape)."""
    buses = {b["name"] for b in doc.get("buses", []) if isinstance(b, dict) and "name" in b}

    def fail(where: list, message: str) -> None:
        problems.append(ScenarioError(str(path), _line_of(doc, where), f"{'.'.join(map(str, where))}: {message}"))

    def trace_of(spec: dict, where: list) -> Path | None:
        if "trace" not in spec:
            return None
        shown = path.parent / spec["trace"]  # as the user wrote it, relative to the scenario
        if (problem := file_problem(shown)) is not None:
            fail([*where, "trace"], problem)
        return shown.resolve()

    def interface_of(spec: dict, where: list) -> str | None:
        if "interface" in spec and "trace" not in spec:
            fail([*where, "interface"], "names an interface of a trace: give the trace")
        return interface_name(spec.get("interface"))

    def messages_of(spec: dict) -> tuple[Message, ...]:
        return tuple(Message(int(m["id"], 16), m["cycle_ms"], m.get("dlc", 8), m.get("extended", False),
                             m.get("remote", False)) for m in spec.get("messages", []))

    def items(key: str) -> list[tuple[int, dict]]:
        """The list's mappings (anything else the schema refused already)."""
        return [(i, spec) for i, spec in enumerate(doc.get(key, []) or []) if isinstance(spec, dict)]

    ecus: list[Ecu] = []
    for i, spec in items("ecus"):
        try:
            if spec["bus"] not in buses:
                fail(["ecus", i, "bus"], f"'{spec['bus']}' is not one of the buses {sorted(buses)}")
            role = spec.get("role", "replay")
            trace = trace_of(spec, ["ecus", i])
            needs = {"replay": ["trace"], "echo": ["echo_ids"], "periodic": ["messages", "run_s"],
                     "restbus": ["dbc_node", "run_s"], "responder": ["rules"]}[role]
            for key in needs:
                if key not in spec:
                    fail(["ecus", i], f"role {role} needs {key}")
            remap = {int(k, 16): int(v, 16) for k, v in spec.get("id_remap", {}).items()}
            for key, target in spec.get("id_remap", {}).items():
                if int(target, 16) > EXT_ID_MAX:  # the schema's 8 hex digits hold more than 29 bits
                    fail(["ecus", i, "id_remap", key], f"{target} is above 1FFFFFFF, the largest CAN id")
            ecus.append(Ecu(spec["name"], spec["bus"], role, trace, spec.get("speed", 1.0), spec.get("loops", 1),
                            spec.get("start_offset_s", 0.0), remap,
                            frozenset(int(x, 16) for x in spec.get("echo_ids", [])),
                            spec.get("answer_id_offset", 1), messages_of(spec), spec.get("run_s", 0.0),
                            interface=interface_of(spec, ["ecus", i])))
        except (KeyError, TypeError, ValueError, AttributeError):
            continue  # refused by the schema already
    names = [e.name for e in ecus]
    if len(set(names)) != len(names):
        fail(["ecus"], "names must be unique")
    commands: list[Commands] = []
    for i, spec in items("commands"):
        try:
            if spec["bus"] not in buses:
                fail(["commands", i, "bus"], f"'{spec['bus']}' is not one of the buses {sorted(buses)}")
            if sum(k in spec for k in ("trace", "messages", "message")) != 1:
                fail(["commands", i], "give either trace or messages (with run_s), or message (signals or schedule)")
            elif "message" in spec and ("schedule" in spec) == ("run_s" in spec):
                fail(["commands", i], "a message is put every cycle for run_s or at its schedule's times: give one")
            elif "messages" in spec and "run_s" not in spec:
                fail(["commands", i], "messages need run_s")
            commands.append(Commands(spec["bus"], trace_of(spec, ["commands", i]), spec.get("speed", 1.0),
                                     messages_of(spec), spec.get("run_s", 0.0), spec.get("start_offset_s", 0.0),
                                     interface_of(spec, ["commands", i])))
        except (KeyError, TypeError, ValueError, AttributeError):
            continue
    bridge = dict(doc.get("bridge", {}))
    if isinstance(bridge.get("rx_qos"), str):  # what the schema cannot see: overlaps, id limits, classes
        try:
            rxqos.parse(bridge["rx_qos"], rxqos.base_of(bridge))
        except (rxqos.QosTableError, TypeError, ValueError) as e:
            fail(["bridge", "rx_qos"], str(e))
    consumer = doc.get("topology", {}).get("consumer", "router")
    if consumer == "bridge" and bridge.get("mode", "client") == "client":
        fail(["topology", "consumer"], "a consumer can connect to the bridge only in bridge.mode peer or router")
    first_bus = next(iter(b["name"] for b in doc.get("buses", []) if isinstance(b, dict) and "name" in b), "")
    faults = []
    for i, spec in items("faults"):
        try:
            if (spec["action"] == "ecu_kill") != ("target" in spec):
                fail(["faults", i], "ecu_kill needs target (an ECU name); other actions take none")
            if "target" in spec and spec["target"] not in names:
                fail(["faults", i, "target"], f"'{spec['target']}' is not one of the ECUs {sorted(names)}")
            if "bus" in spec and spec["bus"] not in buses:
                fail(["faults", i, "bus"], f"'{spec['bus']}' is not one of the buses {sorted(buses)}")
            if spec["action"] != "can_flood" and ({"bus", "id", "max_frames"} & set(spec)):
                fail(["faults", i], "bus, id and max_frames belong to can_flood only")
            if "every_s" in spec and spec["every_s"] <= spec.get("duration_s", 1.0):
                fail(["faults", i, "every_s"], "must be longer than duration_s (steps would overlap)")
                continue
            # a repeated step (soak): at at_s, at_s + every_s, ... up to until_s (default: duration_s)
            until = spec.get("until_s", doc["duration_s"]) if "every_s" in spec else spec["at_s"]
            at = spec["at_s"]
            while at <= until:
                faults.append(Fault(at, spec["action"], spec.get("duration_s", 1.0), spec.get("target", ""),
                                    spec.get("bus", first_bus), int(spec.get("id", "7F0"), 16),
                                    spec.get("max_frames", 1_000_000), i))
                at += spec.get("every_s", float("inf"))
        except (KeyError, TypeError, ValueError, AttributeError):
            continue
    # flood frames are told from the bridge's writes by their id (standard): it must be the flood's alone
    senders: list[Ecu | Commands] = [*ecus, *commands]
    used_ids = {m.can_id for x in senders for m in x.messages if not m.extended}
    flagged = set()
    for f in faults:
        if f.action == "can_flood" and f.can_id in used_ids and f.step not in flagged:
            flagged.add(f.step)
            fail(["faults", f.step], f"can_flood id {f.can_id:03X} is sent by an ECU or a command too; "
                 "give the flood an id of its own")
    _cycle_id_problems(doc, fail)
    dbc = None
    if "dbc" in doc:
        shown = path.parent / str(doc["dbc"])
        if (problem := file_problem(shown)) is not None:
            fail(["dbc"], problem)
        dbc = shown.resolve()
    bus_dbcs, gates = _signal_parts(path, doc, dbc, fail)
    ecus, commands = _restbus_parts(path, doc, bus_dbcs, ecus, commands, problems, fail)
    if problems:
        return None
    return Scenario(path, doc["name"], doc.get("description", ""), doc["duration_s"], doc["buses"], ecus,
                    bridge, dict(doc.get("expect", {})), doc, commands, consumer, dbc, faults, bus_dbcs, gates)


def _cycle_id_problems(doc: Any, fail) -> None:
    """Two keys of expect.cycle_time.ids that name one id ('123' and '0123'; '00000123' is the 29-bit
    id, another): the second is a problem at its line, not a silent override of the first."""
    expect = doc.get("expect")
    cycle = expect.get("cycle_time") if isinstance(expect, dict) else None
    ids = cycle.get("ids") if isinstance(cycle, dict) else None
    said: dict[str, str] = {}
    for key in ids if isinstance(ids, dict) else ():
        try:
            first = said.setdefault(id_key(key), key)
        except (TypeError, ValueError):
            continue  # not a hex id: the schema says so
        if first != key:
            fail(["expect", "cycle_time", "ids", key], f"the same id as {first} ({id_key(key)}): an 11-bit id is "
                 "at most 7FF, a 29-bit one is written with 8 digits (00000123)")


def _signal_parts(path: Path, doc: Any, dbc: Path | None, fail) -> tuple[dict[str, Path], tuple]:
    """Per bus its DBC (buses[].dbc, relative to the scenario, else the top-level dbc), each
    loaded with cantools here so a DBC it cannot read is a problem at its line; then
    expect.signals and cycle_time.from_dbc against them (canbench.signals)."""
    from . import signals
    from .dbc import load_dbc, load_error_text, strict_problem
    bus_dbcs: dict[str, Path] = {}
    where_of: dict[Path, list] = {}
    top = dbc if dbc is not None and is_file(dbc) else None  # the top-level DBC (a missing one: said at its line)
    if top is not None:
        where_of[top] = ["dbc"]
    for i, spec in enumerate(doc.get("buses", []) or []):
        if not isinstance(spec, dict) or "name" not in spec:
            continue
        if isinstance(spec.get("dbc"), str):
            shown = path.parent / spec["dbc"]
            if (problem := file_problem(shown)) is not None:
                fail(["buses", i, "dbc"], problem)
                continue
            bus_dbcs[spec["name"]] = shown.resolve()
            where_of.setdefault(shown.resolve(), ["buses", i, "dbc"])
        elif top is not None:
            bus_dbcs[spec["name"]] = top
    strict = doc.get("dbc_strict", True) is not False
    for file, where in where_of.items():
        try:
            db = load_dbc(file)
        except Exception as e:  # noqa: BLE001 - cantools' parse errors name what it could not read
            fail(where, load_error_text(e, file.name, file))
            continue
        if strict and (why := strict_problem(db)):
            fail(where, f"strict reading refuses {file.name}: {why}; if the DBC is meant as written, "
                        "set dbc_strict: false (each such message is then read signal by signal, and not sent)")
    cycle = (doc.get("expect") or {}).get("cycle_time") if isinstance(doc.get("expect"), dict) else None
    if isinstance(cycle, dict) and cycle.get("from_dbc") and not bus_dbcs:
        fail(["expect", "cycle_time", "from_dbc"], "needs a DBC: give the scenario a dbc, or a bus (buses[].dbc)")
    return bus_dbcs, signals.gates(doc, bus_dbcs, fail)


def _restbus_parts(path: Path, doc: Any, bus_dbcs: dict[str, Path], ecus: list[Ecu], commands: list[Commands],
                   problems: list[ScenarioError], fail) -> tuple[list[Ecu], list[Commands]]:
    """Restbus and responder ECUs, commands in signals and expect.responses, read against their
    bus's DBC (canbench.restbus, canbench.responses): an unknown node, message or signal, a bad
    value, or a bad line of a signal trace (its own file:line) is a problem."""
    import dataclasses

    from . import responses, restbus
    from .dbc import load_dbc

    def fail_file(file: Path, line: int, message: str) -> None:
        problems.append(ScenarioError(str(file), line or None, message))

    def db_of(bus: str, where: list):
        if bus not in bus_dbcs:
            fail(where, "needs a DBC: give the scenario a dbc, or its bus one (buses[].dbc)")
            return None
        try:
            return load_dbc(bus_dbcs[bus])
        except Exception:  # noqa: BLE001 - reported where the DBC is named
            return None

    specs = [s for s in doc.get("ecus", []) or [] if isinstance(s, dict)]
    out_ecus = []
    for e in ecus:
        i, spec = next((i, s) for i, s in enumerate(specs) if s.get("name") == e.name)
        where = ["ecus", i]
        if e.role == "restbus" and "dbc_node" in spec:
            db = db_of(e.bus, [*where, "role"])
            if db is not None:
                plans, left_out = restbus.restbus_plans(db, spec, where, path.parent, fail, fail_file)
                e = dataclasses.replace(e, dbc_node=spec["dbc_node"], restbus=plans, left_out=left_out)
        elif e.role == "responder" and "rules" in spec:
            db = db_of(e.bus, [*where, "role"])
            if db is not None:
                e = dataclasses.replace(e, rules=restbus.responder_rules(db, spec["rules"], [*where, "rules"],
                                                                         path.parent, fail, fail_file))
        out_ecus.append(e)
    cspecs = [(i, s) for i, s in enumerate(doc.get("commands", []) or []) if isinstance(s, dict)]
    if len(cspecs) != len(commands):  # one was refused already: its place is unknown
        return out_ecus, commands
    out_commands = []
    for c, (i, spec) in zip(commands, cspecs, strict=False):
        if "message" in spec:
            db = db_of(c.bus, ["commands", i, "message"])
            if db is not None:
                plan, schedule = restbus.command_plan(db, spec, ["commands", i], path.parent, fail, fail_file)
                c = dataclasses.replace(c, message=spec["message"], signal_plan=plan, schedule=schedule)
        out_commands.append(c)
    responses.rules(doc, bus_dbcs, load_dbc, fail)  # expect.responses: read again by the analysis
    return out_ecus, out_commands
