"""Whether a path a user wrote (a scenario's trace or DBC, a command line's file) names a file,
with the OS's refusal said rather than raised: Path.is_file raises OSError for a name it cannot
even look up (a component over 255 bytes), where a user needs one line at their file:line."""
from __future__ import annotations

from pathlib import Path


def file_problem(path: Path, what: str = "file", named: bool = True) -> str | None:
    """None when path is a regular file; else 'no such <what> <path>', or 'cannot look up <what>
    <path>: <the OS's reason>' (named=False: without the path, for an error that names it)."""
    shown = f" {path}" if named else ""
    try:
        if path.is_file():
            return None
    except OSError as e:
        return f"cannot look up {what}{shown}: {e.strerror or e}"
    return f"no such {what}{shown}"


def is_file(path: Path) -> bool:
    """Path.is_file, False for a name the OS cannot look up (file_problem says why)."""
    return file_problem(path) is None
