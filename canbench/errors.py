"""The bench's exceptions: one base, a few specific children. Messages carry
the file:line (or log path) a user needs next."""
from __future__ import annotations


class BenchError(Exception):
    """Base of every error the bench reports as one line (exit code 2 for input errors)."""

    exit_code = 1


class InputError(BenchError):
    """A scenario, trace or option the bench cannot use; always names file:line."""

    exit_code = 2

    def __init__(self, path: str, line: int | None, message: str):
        where = f"{path}:{line}" if line else str(path)
        super().__init__(f"{where}: {message}")
        self.path, self.line = path, line


class ScenarioError(InputError):
    """The scenario file is malformed or inconsistent."""


class TraceError(InputError):
    """A CAN trace is malformed, empty, unordered or names an unknown interface."""


class NotClassicFrame(TraceError):
    """A whole frame a CAN 2.0 replay cannot send (kind: 'error frame', 'CAN FD frame'): a
    scenario's trace refuses it, a recording's summary and scaffold leave it out and count it."""

    def __init__(self, path: str, line: int | None, message: str, kind: str):
        super().__init__(path, line, message)
        self.kind = kind


class RunError(BenchError):
    """The bench itself failed while running (a container, the router, a timeout)."""
